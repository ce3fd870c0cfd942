"""The paper's renderer: a SoftRas-style soft rasteriser in plain PyTorch (CPU and CUDA alike).

The GeoScaler paper trains through PyTorch3D's ``SoftRasterizer`` and a Phong shader under white
ambient light: a surface point shows its base-colour texture sample (bilinear, level 0, no mip
chain) times the base-colour factor. :class:`SoftRenderer` renders that way, as an option for
training; evaluation stays with the exact renderer (:mod:`geoscaler.render.renderer`), as a GPU
shows it.

Each sample ``p`` of the (supersampled) grid, in normalised device coordinates, looks at the
triangles whose screen distance to it is below the blur radius ``r`` (a squared distance, as in
PyTorch3D) and keeps the ``K`` nearest in depth (``faces_per_pixel``). With ``d_j`` the signed
squared distance from ``p`` to triangle ``j`` in NDC (negative inside) and ``z_j`` its view
depth at its perspective-correct barycentrics clipped to the triangle (PyTorch3D clips them
whenever the blur radius is positive), PyTorch3D's ``softmax_rgb_blend`` gives::

    p_j   = sigmoid(-d_j / sigma)                     coverage probability
    zi_j  = (zfar - z_j) / (zfar - znear)             normalised inverse depth
    m     = max(max_j zi_j, eps)
    w_j   = p_j exp((zi_j - m) / gamma)
    delta = max(exp((eps - m) / gamma), eps)          background weight, eps = 1e-10
    c(p)  = (sum_j w_j c_j + delta * background) / (sum_j w_j + delta)
    alpha = 1 - prod_j (1 - p_j)                      soft coverage

where ``c_j`` is the texture at the UV interpolated with triangle ``j``'s clipped barycentrics.
The background is black, colours are blended in linear light, the samples of a pixel are
box-averaged (the evaluation's supersampling, as the exact renderer does) and the image is
encoded to sRGB. The weights depend on geometry and camera only, so a view's
:class:`SoftFragments` are found once; shading them is differentiable w.r.t. texels and UVs.

Defaults (:class:`SoftSettings`), PyTorch3D's usual values: ``sigma = gamma = 1e-4``, blur radius
``log(1 / 1e-4 - 1) sigma = 9.2e-4`` (where ``p_j`` falls to 1e-4: 0.030 NDC, 7.8 pixels of a
512-pixel image), ``K = 8``, depth normalised over ``(znear, zfar) = (1, 100)``, the defaults
of PyTorch3D's cameras. Because the background's weight is only ``eps``, a sample within the
blur radius of the mesh shows its colour nearly in full: the colour silhouette grows by the blur
distance and the soft one is ``alpha``, as in PyTorch3D.

Bounded memory: triangle screen boxes (grown by the blur distance) are binned into tiles of
``TILE x TILE`` samples, tiles evaluated in chunks of at most ``CHUNK_ENTRIES`` (tile, triangle,
sample) triples, and each sample keeps at most ``K`` candidates.

Unlike PyTorch3D, on purpose: texels are addressed as a GPU does (centres at ``(i + 0.5) /
size``, repeat), not as ``TexturesUV`` (``align_corners=True``, border), which would misplace a
shipped texture by up to half a texel; triangles the exact rasteriser drops are dropped too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from geoscaler.color import linear_to_srgb, texture_to_linear
from geoscaler.mesh import TexturedMesh
from geoscaler.protocol import PROTOCOL_EVALUATION, Evaluation
from geoscaler.render.cameras import Camera
from geoscaler.render.devices import mesh_tensors, resolve_device, tensor_bytes
from geoscaler.render.texture import MipLayout, MipTexture, gather
from geoscaler.resize.filters import reference_textures

SIGMA = 1e-4
"""PyTorch3D's usual ``BlendParams.sigma``: the width of the edge sigmoid, in squared NDC."""
GAMMA = 1e-4
"""PyTorch3D's usual ``BlendParams.gamma``: the temperature of the softmax over depth."""
FACES_PER_PIXEL = 8
"""Candidates kept per sample (``faces_per_pixel``), the nearest in depth."""
EDGE_PROBABILITY = 1e-4
"""The blur radius is where a triangle's probability falls to this: ``log(1 / 1e-4 - 1) sigma``."""
PYTORCH3D_DEPTH_RANGE = (1.0, 100.0)
"""``(znear, zfar)`` of PyTorch3D's ``FoVPerspectiveCameras`` by default, which its soft
shaders normalise depth with."""
EPS = 1e-10
"""``softmax_rgb_blend``'s epsilon (floor of the background weight)."""
TILE = 8
"""Samples per side of a tile."""
CHUNK_ENTRIES = 1 << 20
"""(tile, triangle, sample) triples evaluated at once: about 30 tensors this long at the peak."""


@dataclass(frozen=True)
class SoftSettings:
    """Parameters of the soft rasteriser and blend (PyTorch3D's usual values by default).

    Attributes:
        sigma: edge sharpness, squared NDC units (PyTorch3D ``BlendParams.sigma``).
        gamma: depth softmax temperature (``BlendParams.gamma``).
        faces_per_pixel: candidates kept per sample, nearest in depth.
        blur_radius: squared NDC distance beyond which a triangle is not a candidate
            (None: ``log(1 / EDGE_PROBABILITY - 1) * sigma``, where its probability is 1e-4).
        depth_range: ``(znear, zfar)`` of the depth normalisation: PyTorch3D's cameras'
            defaults; None: each camera's own planes (at 2.4 a 27 times sharper softmax, where
            nearer neighbours within the blur radius outweigh the triangle a sample is in).
        supersample: samples per pixel side (None: the evaluation's, as the exact renderer;
            PyTorch3D has none; 1 is 4 times cheaper than 2 x 2).
    """

    sigma: float = SIGMA
    gamma: float = GAMMA
    faces_per_pixel: int = FACES_PER_PIXEL
    blur_radius: float | None = None
    depth_range: tuple[float, float] | None = PYTORCH3D_DEPTH_RANGE
    supersample: int | None = None

    def __post_init__(self) -> None:
        near, far = self.depth_range or (0, 1)
        if not (self.sigma > 0 and self.gamma > 0 and self.faces_per_pixel >= 1 and far > near):
            raise ValueError(f"sigma, gamma, faces_per_pixel, zfar - znear must be > 0: {self}")
        if (self.blur_radius or 0) < 0 or (self.supersample or 1) < 1:
            raise ValueError(f"blur_radius must be >= 0 and supersample >= 1: {self}")

    @property
    def radius(self) -> float:
        """The blur radius in squared NDC units."""
        if self.blur_radius is not None:
            return self.blur_radius
        return math.log(1.0 / EDGE_PROBABILITY - 1.0) * self.sigma


@dataclass
class SoftFragments:
    """The soft visibility of one view: per sample, its candidate triangles and blend weights.

    Only entries of nonzero weight are kept (the rest add nothing to any image).

    Attributes:
        resolution: samples per side.
        sample: ``(E,)`` int32 flat sample index ``row * resolution + col`` of each entry.
        face: ``(E,)`` int32 triangle of each entry.
        weight: ``(E,)`` blend weight ``w_j / (sum_k w_k + delta)``.
        bary: ``(3, E)`` perspective-correct barycentrics clipped to the triangle.
        covered: ``(N,)`` int32 samples with any candidate, ascending.
        alpha: ``(N,)`` their soft coverage ``1 - prod_j (1 - p_j)``.
    """

    resolution: int
    sample: torch.Tensor
    face: torch.Tensor
    weight: torch.Tensor
    bary: torch.Tensor
    covered: torch.Tensor
    alpha: torch.Tensor

    @property
    def num_entries(self) -> int:
        return int(self.sample.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes held by the tensors."""
        return tensor_bytes(self._tensors())

    def _tensors(self) -> tuple[torch.Tensor, ...]:
        return self.sample, self.face, self.weight, self.bary, self.covered, self.alpha

    def coverage(self) -> torch.Tensor:
        """``(resolution, resolution)`` soft coverage (alpha) of every sample."""
        dense = self.alpha.new_zeros(self.resolution**2)
        dense[self.covered.long()] = self.alpha
        return dense.view(self.resolution, self.resolution)


def _setup(clip: torch.Tensor, faces: torch.Tensor):
    """The triangles that can be drawn (in front of the eye, inside the depth range, of nonzero
    screen area: the exact rasteriser's rule) and their constants, float64.

    Every quantity the per-sample test needs is affine in the sample position ``p`` (NDC), so a
    triangle holds it as rows ``(alpha, beta, gamma)`` of ``alpha p_x + beta p_y + gamma``:

    - rows 0-2: ``q_k = l_k / w_k``, the screen barycentrics over the view depth (perspective-
      correct barycentrics are ``q / sum q``, and ``q_k > 0`` for all k is "inside");
    - rows 3-5: ``s_k = (p - v_k) . e_k`` along edge k (corner k to corner k + 1);
    - rows 6-8: ``|v_k|^2 - 2 p . v_k``, which ``|p|^2`` completes to ``|p - v_k|^2``.

    Returns:
        ``(ids, coef, edge, w, ndc_x, ndc_y)``: ``(T,)`` face ids, ``(T, 9, 3)`` rows,
        ``(T, 3, 3)`` rows of the signed distances to the edge lines (positive inside; for
        culling), ``(T, 3)`` corner view depths and NDC corners.
    """
    corners = clip.to(torch.float64)[faces]  # (F, 3, 4)
    x, y, z, w = corners.unbind(-1)
    safe_w = torch.where(w > 0, w, torch.ones_like(w))
    nx, ny, nz = x / safe_w, y / safe_w, z / safe_w
    area2 = (nx[:, 1] - nx[:, 0]) * (ny[:, 2] - ny[:, 0]) - (nx[:, 2] - nx[:, 0]) * (
        ny[:, 1] - ny[:, 0]
    )
    valid = (w > 0).all(1) & (nz >= -1).all(1) & (nz <= 1).all(1) & (area2.abs() > 1e-14)
    ids = torch.nonzero(valid).squeeze(1)
    nx, ny, w, area2 = nx[ids], ny[ids], w[ids], area2[ids, None]
    nxt, prv = [1, 2, 0], [2, 0, 1]
    # l_k: the signed area of (p, corner k + 1, corner k + 2) over the triangle's
    lam = torch.stack(
        [
            (ny[:, nxt] - ny[:, prv]) / area2,
            (nx[:, prv] - nx[:, nxt]) / area2,
            (nx[:, nxt] * ny[:, prv] - nx[:, prv] * ny[:, nxt]) / area2,
        ],
        dim=-1,
    )  # (T, 3, 3)
    ex, ey = nx[:, nxt] - nx, ny[:, nxt] - ny
    along = torch.stack([ex, ey, -(nx * ex + ny * ey)], dim=-1)
    corner = torch.stack([-2 * nx, -2 * ny, nx * nx + ny * ny], dim=-1)
    coef = torch.cat([lam / w[..., None], along, corner], dim=1)
    height = area2.abs() / (ex * ex + ey * ey).sqrt()[:, nxt]  # of corner k over its edge
    return ids, coef, lam * height[..., None], w, nx, ny


def _expand(counts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For items with ``counts[i]`` elements each: ``(item, position within item)`` per element."""
    item = torch.repeat_interleave(torch.arange(len(counts), device=counts.device), counts)
    first = torch.cumsum(counts, 0) - counts
    return item, torch.arange(len(item), device=counts.device) - first[item]


def _bin(edge, nx, ny, resolution: int, radius: float, tile: int):
    """``(pair_triangle, tile_start, tile_count)``: the triangles that may reach each tile,
    pairs sorted by tile (triangles ascending within).

    A triangle meets the tiles of its screen box grown by the blur distance ``sqrt(radius)``,
    less those that lie wholly beyond that distance outside one of its edge lines."""
    step = 2.0 / resolution
    grow = math.sqrt(radius) + 1e-6
    col_lo = torch.ceil((nx.min(1).values - grow + 1.0) / step - 0.5).clamp(0, resolution)
    col_hi = torch.floor((nx.max(1).values + grow + 1.0) / step - 0.5).clamp(-1, resolution - 1)
    row_lo = torch.ceil((1.0 - ny.max(1).values - grow) / step - 0.5).clamp(0, resolution)
    row_hi = torch.floor((1.0 - ny.min(1).values + grow) / step - 0.5).clamp(-1, resolution - 1)
    tiles = -(-resolution // tile)
    tx0, tx1 = (col_lo // tile).long(), (col_hi // tile).long()
    ty0, ty1 = (row_lo // tile).long(), (row_hi // tile).long()
    ntx = (tx1 - tx0 + 1).clamp_min(0) * (col_hi >= col_lo)
    nty = (ty1 - ty0 + 1).clamp_min(0) * (row_hi >= row_lo)
    tri, k = _expand(ntx * nty)
    tx, ty = tx0[tri] + k % ntx[tri], ty0[tri] + k // ntx[tri]
    # the tile's sample centres span [x0, x0 + span] x [y0 - span, y0]
    x0 = ((tx * tile).to(torch.float64) + 0.5) * step - 1.0
    y0 = 1.0 - ((ty * tile).to(torch.float64) + 0.5) * step
    span = (tile - 1) * step
    a, b, c = edge[tri].unbind(-1)  # (P, 3) each
    reach = c + torch.maximum(a * x0[:, None], a * (x0[:, None] + span))
    reach += torch.maximum(b * y0[:, None], b * (y0[:, None] - span))
    keep = torch.nonzero((reach > -grow).all(1)).squeeze(1)
    tri, tile_id = tri[keep], (ty * tiles + tx)[keep]
    order = torch.argsort(tile_id, stable=True)
    counts = torch.bincount(tile_id, minlength=tiles * tiles)
    return tri[order], torch.cumsum(counts, 0) - counts, counts


def _chunks(counts: list[int], per_tile: int, budget: int):
    """Consecutive runs of tiles (sorted by ascending candidate count) whose padded size
    ``tiles * largest count * per_tile`` stays within ``budget`` (at least one tile)."""
    start = 0
    while start < len(counts):
        stop = start + 1
        while stop < len(counts) and (stop + 1 - start) * counts[stop] * per_tile <= budget:
            stop += 1
        yield start, stop
        start = stop


def soft_rasterize(
    clip: torch.Tensor,
    faces: torch.Tensor,
    resolution: int,
    depth_range: tuple[float, float],
    settings: SoftSettings = SoftSettings(),
    dtype: torch.dtype = torch.float32,
    tile: int = TILE,
    chunk_entries: int = CHUNK_ENTRIES,
) -> SoftFragments:
    """Soft visibility of triangles on a ``resolution x resolution`` grid (no face culling).

    Args:
        clip: ``(V, 4)`` clip-space positions (``w`` is the view depth, as in OpenGL).
        faces: ``(F, 3)`` vertex indices.
        resolution: samples per side; sample centres at half-integers, row 0 at the top.
        depth_range: ``(znear, zfar)`` of the depth normalisation.
        settings: sigma, gamma, K, blur radius.
        dtype: float type of the evaluation and of the fragments (float64 for gradcheck).
        tile, chunk_entries: tile side and working-set bound (results do not depend on them).
    """
    device = clip.device
    ids, coef, edge, corner_w, nx, ny = _setup(clip, faces.to(device=device, dtype=torch.long))
    pair_tri, tile_start, tile_count = _bin(edge, nx, ny, resolution, settings.radius, tile)
    tiles, step = -(-resolution // tile), 2.0 / resolution
    # sample offsets from the tile's first sample centre (the same for every tile)
    local = torch.arange(tile * tile, device=device)
    lx, ly = (local % tile).to(torch.float64) * step, (local // tile).to(torch.float64) * -step
    grid = torch.stack([lx, ly, torch.ones_like(lx)]).to(dtype)  # (3, S)
    len2 = coef[:, 3:6, :2].square().sum(-1)  # (T, 3) squared edge lengths
    per_edge = torch.stack([corner_w, len2, 1.0 / len2], dim=1).to(dtype)  # (T, 3, 3)
    order = torch.nonzero(tile_count).squeeze(1)
    order = order[torch.argsort(tile_count[order], stable=True)]
    counts = tile_count[order].tolist()
    parts: list[tuple[torch.Tensor, ...]] = []
    covered: list[tuple[torch.Tensor, torch.Tensor]] = []
    for start, stop in _chunks(counts, tile * tile, chunk_entries):
        chunk = order[start:stop]
        slot = torch.arange(counts[stop - 1], device=device)
        real = slot < tile_count[chunk][:, None]  # (G, M)
        tri = pair_tri[torch.where(real, tile_start[chunk][:, None] + slot, 0)]  # (G, M)
        col = (chunk % tiles)[:, None] * tile + local % tile  # (G, S)
        row = (chunk // tiles)[:, None] * tile + local // tile
        first = [(c[:, 0].to(torch.float64) + 0.5) * step for c in (col, row)]
        origin = first[0] - 1.0, 1.0 - first[1]  # NDC of each tile's first sample
        signed, inside, q, total, depth = _candidates(coef[tri], per_edge[tri], origin, grid)
        valid = (inside | (signed < settings.radius)) & (total > 0) & real[..., None]
        valid &= ((col < resolution) & (row < resolution))[:, None]
        key = torch.where(valid, depth, math.inf)
        k = min(settings.faces_per_pixel, len(slot))
        key, pick = torch.topk(key, k, dim=1, largest=False)  # (G, k, S) nearest in depth
        bary = q.gather(2, pick[:, None].expand(-1, 3, -1, -1)) / total.gather(1, pick)[:, None]
        weight, alpha = _blend(signed.gather(1, pick), key, settings, depth_range)
        face = tri[..., None].expand(-1, -1, pick.shape[-1]).gather(1, pick)
        sample = (row * resolution + col)[:, None].expand_as(weight)
        hit = torch.nonzero(weight > 0, as_tuple=True)
        g, j, p = hit
        parts.append((sample[hit], face[hit], weight[hit], bary[g, :, j, p].T))
        any_hit = torch.nonzero(torch.isfinite(key).any(dim=1), as_tuple=True)
        covered.append((sample[:, 0][any_hit], alpha[any_hit]))
    return _fragments(resolution, ids, parts, covered, dtype, device)


def _candidates(rows, per_edge, origin, grid):
    """Every (tile, candidate, sample) of a chunk: ``(signed, inside, q, total, depth)``.

    Args:
        rows: ``(G, M, 9, 3)`` float64 rows of :func:`_setup` of each tile's candidates.
        per_edge: ``(G, M, 3, 3)``: corner depths ``w``, squared edge lengths and inverses.
        origin: ``(x, y)``, each ``(G,)`` float64: NDC of each tile's first sample.
        grid: ``(3, S)`` sample offsets ``p' = (x', y', 1)`` from it.

    Returns:
        ``(G, M, S)`` signed squared distance (negative inside) and inside; ``(G, 3, M, S)``
        clipped ``q`` (``max(q_k, 0)``; the clipped barycentrics are ``q / total``); ``(G, M,
        S)`` ``total`` and view depth ``sum_k q_k w_k / total``.
    """
    ox, oy = (o[:, None, None] for o in origin)
    alpha, beta, gamma = rows.unbind(-1)  # moved to the tile's origin o (p = o + p'):
    gamma = gamma + alpha * ox + beta * oy
    # rows 6-8 take |p|^2 = |p'|^2 + 2 o . p' + |o|^2 in, less the |p'|^2 added below
    gamma[..., 6:] += ox * ox + oy * oy
    alpha, beta = alpha.clone(), beta.clone()
    alpha[..., 6:] += 2 * ox
    beta[..., 6:] += 2 * oy
    rows = torch.stack([alpha, beta, gamma], dim=-1).to(grid.dtype)
    count, width = rows.shape[:2]
    values = (rows.transpose(1, 2).reshape(-1, 3) @ grid).view(count, 9, width, -1)
    q, s, dist = values[:, 0:3], values[:, 3:6], values[:, 6:9]
    w, len2, inv_len2 = (v.transpose(1, 2)[..., None] for v in per_edge.unbind(2))
    inside = q.amin(dim=1) > 0
    q = q.clamp_(min=0.0)
    total = q.sum(dim=1)
    depth = (q * w).sum(dim=1) / total
    t = (s * inv_len2).clamp_(0.0, 1.0)  # the nearest point of each edge: v_k + t e_k
    dist += grid[0] * grid[0] + grid[1] * grid[1]
    d2 = torch.addcmul(dist, t, t * len2 - 2.0 * s).amin(dim=1).clamp_(min=0.0)
    return torch.where(inside, -d2, d2), inside, q, total, depth


def _blend(signed, depth, settings: SoftSettings, depth_range: tuple[float, float]):
    """PyTorch3D's ``softmax_rgb_blend`` weights over the ``(G, k, S)`` candidates kept
    (``depth`` +inf: an empty slot): ``(weight, alpha)``, ``(G, k, S)`` and ``(G, S)``."""
    znear, zfar = depth_range
    mask = torch.isfinite(depth)
    prob = torch.where(mask, torch.sigmoid(-signed / settings.sigma), 0.0)
    alpha = 1.0 - torch.prod(1.0 - prob, dim=1)
    z_inv = torch.where(mask, (zfar - depth) / (zfar - znear), 0.0)
    z_max = z_inv.max(dim=1, keepdim=True).values.clamp(min=EPS)
    num = prob * torch.exp((z_inv - z_max) / settings.gamma)
    delta = torch.exp((EPS - z_max) / settings.gamma).clamp(min=EPS)
    return num / (num.sum(dim=1, keepdim=True) + delta), alpha


def _fragments(resolution, ids, parts, covered, dtype, device) -> SoftFragments:
    """The chunks' entries and coverage joined, ordered by sample."""
    empty_i = torch.zeros(0, dtype=torch.long, device=device)
    empty_f = torch.zeros(0, dtype=dtype, device=device)
    if not parts:
        parts = [(empty_i, empty_i, empty_f, empty_f.view(3, 0))]
        covered = [(empty_i, empty_f)]
    sample, face, weight, bary = (torch.cat(t, dim=-1) for t in zip(*parts, strict=True))
    by_sample = torch.argsort(sample, stable=True)  # pixel order: local index_add
    cov_sample, cov_alpha = (torch.cat(t) for t in zip(*covered, strict=True))
    by_covered = torch.argsort(cov_sample)
    return SoftFragments(
        resolution=resolution,
        sample=sample[by_sample].to(torch.int32),
        face=ids[face[by_sample]].to(torch.int32),
        weight=weight[by_sample],
        bary=bary[:, by_sample].contiguous(),
        covered=cov_sample[by_covered].to(torch.int32),
        alpha=cov_alpha[by_covered],
    )


def interpolate(fragments: SoftFragments, faces: torch.Tensor, values: torch.Tensor):
    """``(C, E)`` per-vertex ``(V, C)`` values at every entry (clipped barycentrics)."""
    corners = values.index_select(0, faces.index_select(0, fragments.face).reshape(-1))
    corners = corners.view(-1, 3, values.shape[1]).permute(1, 2, 0)  # (3, C, E)
    bary = fragments.bary.to(values.dtype)[:, None]
    return (corners * bary).sum(0)


def bilinear(texture: torch.Tensor | MipTexture, u: torch.Tensor, v: torch.Tensor):
    """``(C, N)`` bilinear samples of level 0 of ``texture`` (a ``(h, w, C)`` linear tensor or
    a :class:`MipTexture`, whose finer levels are not read): GPU texel centres, repeat."""
    level = torch.zeros(u.shape, dtype=torch.int32, device=u.device)
    if isinstance(texture, MipTexture):
        return texture.bilinear(u, v, level)
    layout = MipLayout(texture.shape[0], texture.shape[1], texture.device)
    texels = texture.reshape(-1, texture.shape[2]).T
    return gather(texels, *layout.bilinear_taps(u, v, level))


Texture = torch.Tensor | MipTexture | None
"""A material's texture for :class:`SoftRenderer`: ``(h, w, 3)`` linear (level 0 is read), a
mip chain (its level 0 is read), or None (the factor alone)."""


class SoftRenderer:
    """Renders one mesh, normalised per the protocol, through the soft rasteriser.

    The same cameras, image size and supersampling as :class:`geoscaler.render.renderer.Renderer`
    (``evaluation``); :meth:`rasterize` and :meth:`render` mirror its methods, so a
    :class:`geoscaler.render.views.ViewSet` caches soft views as it caches exact ones.

    Args:
        mesh: the mesh; its geometry is fixed for the renderer's lifetime.
        device: where tensors live (None or "auto": CUDA when available).
        evaluation: image size and supersampling.
        settings: sigma, gamma, K, blur radius, depth range.
        reference: returns the reference textures, one per material (default: the protocol's
            reference maps at the evaluation's ``reference_max_size``,
            :func:`geoscaler.resize.filters.reference_textures`, in linear light).
        dtype: float type of the fragments.
    """

    def __init__(
        self,
        mesh: TexturedMesh,
        device: torch.device | str | None = None,
        evaluation: Evaluation = PROTOCOL_EVALUATION,
        settings: SoftSettings = SoftSettings(),
        reference: Callable[[], Sequence[Texture]] | None = None,
        dtype: torch.dtype = torch.float32,
    ):
        self.device = resolve_device(device)
        self.evaluation, self.settings, self.dtype = evaluation, settings, dtype
        self.image_size = evaluation.image_size
        self.supersample = settings.supersample or evaluation.supersample
        self.mesh = mesh
        tensors = mesh_tensors(mesh, self.device)
        self.positions, self.faces, self.uvs = tensors.positions, tensors.faces, tensors.uvs
        self.face_material, self.factors = tensors.face_material, tensors.factors
        self._reference_source = reference
        self._reference: list[Texture] | None = None

    @property
    def resolution(self) -> int:
        """Samples per side."""
        return self.image_size * self.supersample

    def reference_textures(self) -> list[Texture]:
        """The textures of the original, one per material, made once (read only)."""
        if self._reference is None:
            if self._reference_source is not None:
                self._reference = list(self._reference_source())
            else:
                maps = reference_textures(self.mesh, self.evaluation.reference_max_size)
                self._reference = [
                    None if t is None else texture_to_linear(t, self.device) for t in maps
                ]
        return self._reference

    def rasterize(self, camera: Camera) -> SoftFragments:
        """The soft fragments of one camera (geometry only; no gradient)."""
        clip_matrix = torch.from_numpy(camera.clip_matrix()).to(self.device, torch.float64)
        homogeneous = torch.nn.functional.pad(self.positions.to(torch.float64), (0, 1), value=1.0)
        depth_range = self.settings.depth_range or camera.near_far()
        with torch.no_grad():
            return soft_rasterize(
                homogeneous @ clip_matrix.T,
                self.faces,
                self.resolution,
                depth_range,
                self.settings,
                self.dtype,
            )

    def shade(
        self,
        fragments: SoftFragments,
        textures: Sequence[Texture],
        uvs: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``(3, E)`` linear colour of every entry (texture sample x factor), unweighted."""
        uvs = self.uvs if uvs is None else uvs
        u, v = interpolate(fragments, self.faces, uvs)
        if len(textures) == 1:
            colour = self.factors[0][:, None].to(u.dtype)
            if textures[0] is None:
                return colour.expand(3, u.shape[0])
            return colour * bilinear(textures[0], u, v)
        material = self.face_material.index_select(0, fragments.face)
        colours = self.factors.T.index_select(1, material).to(u.dtype)
        for index, texture in enumerate(textures):
            hit = torch.nonzero(material == index).squeeze(1)
            if texture is not None and len(hit):
                texel = bilinear(texture, u.index_select(0, hit), v.index_select(0, hit))
                colours = colours.index_copy(1, hit, colours[:, hit] * texel)
        return colours

    def pixel_of_entry(self, fragments: SoftFragments) -> torch.Tensor:
        """``(E,)`` int64 flat output pixel of each entry."""
        sample = fragments.sample.long()
        row = sample // (self.resolution * self.supersample)
        col = sample % self.resolution // self.supersample
        return row * self.image_size + col

    def resolve(self, fragments: SoftFragments, colours: torch.Tensor) -> torch.Tensor:
        """``(image_size, image_size, C)``: the blend of every sample (background black),
        box-averaged over each pixel's samples."""
        pixel = self.pixel_of_entry(fragments)
        weighted = colours * (fragments.weight.to(colours.dtype) / self.supersample**2)
        image = torch.stack(
            [row.new_zeros(self.image_size**2).index_add(0, pixel, row) for row in weighted]
        )
        side = self.image_size
        return image.view(-1, side, side).permute(1, 2, 0)

    def pixel_taps(
        self, fragments: SoftFragments, layouts: Sequence[MipLayout | None]
    ) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None]:
        """Per material, a render with the mesh's UVs as fixed taps of texels into pixels.

        With fixed UVs every pixel is a fixed weighted sum of level-0 texels (blend weight x
        bilinear weight / samples per pixel): the entries' taps, summed per (pixel, texel)
        (on spot 6 times fewer). ``layouts``: per material the candidate's (None: untextured).

        Returns:
            Per material ``(pixel, texel, weight)``, each ``(T,)``: int32 flat output pixel,
            int32 index into the flat mip chain (level 0), weight; None: untextured or unseen.
        """
        u, v = interpolate(fragments, self.faces, self.uvs)
        material = self.face_material.index_select(0, fragments.face)
        pixel = self.pixel_of_entry(fragments)
        weight = fragments.weight / self.supersample**2
        taps: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None] = []
        for index, layout in enumerate(layouts):
            hit = torch.nonzero(material == index).squeeze(1)
            if layout is None or len(hit) == 0:
                taps.append(None)
                continue
            level = torch.zeros(len(hit), dtype=torch.int32, device=self.device)
            texel, bilinear_weight = layout.bilinear_taps(u[hit], v[hit], level)
            key = (pixel[hit] * layout.num_texels + texel).reshape(-1)
            keys, inverse = torch.unique(key, return_inverse=True)
            summed = weight.new_zeros(len(keys))
            summed.index_add_(0, inverse, (bilinear_weight * weight[hit]).reshape(-1))
            pixels, texels = keys // layout.num_texels, keys % layout.num_texels
            taps.append((pixels.to(torch.int32), texels.to(torch.int32), summed))
        return taps

    def untextured(self, fragments: SoftFragments, plain: Sequence[bool]) -> torch.Tensor:
        """``(3, pixels)`` linear colour the entries of the ``plain`` materials add (their
        factor alone)."""
        material = self.face_material.index_select(0, fragments.face)
        hit = torch.nonzero(torch.tensor(plain, device=self.device)[material]).squeeze(1)
        colours = self.factors.T.index_select(1, material[hit])
        weight = fragments.weight[hit].to(colours.dtype) / self.supersample**2
        image = colours.new_zeros(3, self.image_size**2)
        return image.index_add(1, self.pixel_of_entry(fragments)[hit], colours * weight)

    def foreground(self, fragments: SoftFragments) -> torch.Tensor:
        """``(image_size, image_size)`` bool: pixels a triangle reaches (elsewhere every
        render is the black background)."""
        mask = torch.zeros(self.image_size**2, dtype=torch.bool, device=self.device)
        mask[self.pixel_of_entry(fragments)] = True
        return mask.view(self.image_size, self.image_size)

    def coverage(self, fragments: SoftFragments) -> torch.Tensor:
        """``(image_size, image_size)`` soft coverage (alpha), box-averaged per pixel."""
        side, ss = self.image_size, self.supersample
        return fragments.coverage().view(side, ss, side, ss).mean(dim=(1, 3))

    def render(
        self,
        view: Camera | SoftFragments,
        textures: Sequence[Texture],
        uvs: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``(image_size, image_size, 3)`` sRGB-encoded image in [0, 1], differentiable w.r.t.
        the textures and ``uvs`` (``(V, 2)``; None: the mesh's own)."""
        fragments = self.rasterize(view) if isinstance(view, Camera) else view
        return linear_to_srgb(self.resolve(fragments, self.shade(fragments, textures, uvs)))
