"""A vectorised triangle rasteriser in plain PyTorch (CPU and CUDA alike).

Geometry is fixed during optimisation, so visibility is too: each camera is rasterised once into
a :class:`GBuffer` that stores only which triangle every covered sample sees. Everything else --
perspective-correct barycentrics and their screen-space derivatives -- follows exactly from the
sample position and the triangle's homogeneous matrix (2D homogeneous rasterisation, Olano and
Greer 1997), so the cache stays small and the values are exact.

For a triangle with clip-space vertices ``(x_k, y_k, z_k, w_k)`` let ``M = [x; y; w]`` be the
3 x 3 matrix with one column per vertex and ``A = M^-1``. At the sample with normalised device
coordinates ``p = (s_x, s_y, 1)``, ``b' = A p`` are the perspective-correct barycentrics divided
by the clip ``w`` there: the sample is inside when all ``b'_k >= 0``, its barycentrics are
``b = b' / sum(b')`` and its depth is ``z_ndc = sum_k z_k b'_k`` (because ``sum_k w_k b'_k = 1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from geoscaler.render.devices import tensor_bytes

_DEPTH_LEVELS = 2**31 - 1
_TRIANGLE_BITS = 31
_EMPTY = torch.iinfo(torch.int64).max
# Candidate (triangle, sample) pairs tested per chunk: bounds peak memory to a few hundred MB.
_PAIRS_PER_CHUNK = 1 << 22


@dataclass
class GBuffer:
    """Visibility of one view, sampled on a ``resolution x resolution`` grid.

    Attributes:
        resolution: samples per side (twice the image size under 2 x 2 supersampling).
        pixels: ``(N,)`` int32 flat sample index ``row * resolution + col`` of each covered
            sample, ascending; row 0 is the top of the image.
        tri_ids: ``(N,)`` int32 index of the triangle each covered sample sees.
        tri_matrices: ``(9, F)`` float32 per-triangle ``A = [x; y; w]^-1``, row-major, one
            column per triangle (zero for triangles that cannot be seen).
    """

    resolution: int
    pixels: torch.Tensor
    tri_ids: torch.Tensor
    tri_matrices: torch.Tensor

    @property
    def num_samples(self) -> int:
        """Number of covered samples ``N``."""
        return int(self.pixels.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes held by the cached tensors."""
        return tensor_bytes(self._tensors())

    def _tensors(self) -> tuple[torch.Tensor, ...]:
        return self.pixels, self.tri_ids, self.tri_matrices

    def to(self, device: torch.device | str) -> GBuffer:
        """A copy on ``device``."""
        return GBuffer(self.resolution, *(t.to(device) for t in self._tensors()))

    def coverage(self) -> torch.Tensor:
        """``(resolution, resolution)`` bool mask of covered samples."""
        mask = torch.zeros(self.resolution**2, dtype=torch.bool, device=self.pixels.device)
        mask[self.pixels.long()] = True
        return mask.view(self.resolution, self.resolution)

    def sample_ndc(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(N,)`` float32 normalised device coordinates ``(s_x, s_y)`` of the covered samples."""
        pixels = self.pixels.int()
        return _ndc(pixels % self.resolution, pixels // self.resolution, self.resolution)

    def interpolate(
        self, corner_values: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Perspective-correct interpolation of per-corner values, with screen derivatives.

        With ``b' = A p`` the value at a sample is ``sum_c a_c b'_c / sum_c b'_c``. Both sums
        are affine in ``p``, so each attribute folds into one plane per triangle,
        ``P = a^T A``, and the samples need only ``value = (P p) / (S p)`` where ``S`` is the
        plane of the constant 1; the derivative along ``s_x`` is
        ``(P_0 - value S_0) / (S p)``.

        Args:
            corner_values: ``(K, F, 3)`` values of K attributes at the corners of every
                triangle (may require grad; any float dtype).

        Returns:
            ``(values, d_dx, d_dy)``, each ``(K, N)``: the attributes at the covered samples
            and their derivatives per sample step right (x, columns) and down (y, rows).
        """
        a = self.tri_matrices.view(3, 3, -1)  # (corner, column of p, triangle)
        planes = torch.einsum("kfc,cjf->kjf", corner_values, a.to(corner_values.dtype))
        table = torch.cat([a.sum(0).to(planes.dtype)[None], planes])  # (1 + K, 3, F)
        at = table.flatten(0, 1).index_select(1, self.tri_ids).view(len(table), 3, -1)
        sx, sy = self.sample_ndc()
        affine = at[:, 0] * sx + at[:, 1] * sy + at[:, 2]  # (1 + K, N)
        scale = 1.0 / affine[0]
        values = affine[1:] * scale
        step = 2.0 / self.resolution
        d_dx = (at[1:, 0] - values * at[0, 0]) * (scale * step)
        d_dy = (at[1:, 1] - values * at[0, 1]) * (scale * -step)
        return values, d_dx, d_dy

    def barycentrics(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Perspective-correct barycentrics and derivatives: :meth:`interpolate` of the corners.

        Returns:
            ``(b, db_dx, db_dy)``, each ``(3, N)`` float32: the weights of the triangle's
            three corners and their derivatives per sample step right and down.
        """
        num_triangles = self.tri_matrices.shape[1]
        corners = torch.eye(3, device=self.tri_matrices.device)[:, None, :]
        return self.interpolate(corners.expand(3, num_triangles, 3))


def _ndc(cols: torch.Tensor, rows: torch.Tensor, resolution: int):
    """Sample centres (half-integers) in normalised device coordinates; rows grow downwards."""
    step = 2.0 / resolution
    sx = (cols.to(torch.float32) + 0.5) * step - 1.0
    sy = 1.0 - (rows.to(torch.float32) + 0.5) * step
    return sx, sy


def _triangle_setup(clip: torch.Tensor, faces: torch.Tensor, resolution: int):
    """Per-triangle homogeneous matrices, depth planes and sample-row ranges.

    Triangles behind the camera, crossing the near or far plane, or of zero screen area are
    dropped (protocol cameras never clip a normalised mesh).

    Returns:
        ``(a, depth_plane, row0, rows)``: ``(F, 3, 3)`` float64 ``A`` (zero when dropped),
        ``(F, 3)`` float64 coefficients of the affine ``z_ndc = c0 s_x + c1 s_y + c2``, and
        ``(F,)`` int64 first sample row and number of rows to visit (0 when dropped).
    """
    corners = clip.to(torch.float64)[faces]  # (F, 3, 4)
    x, y, z, w = corners.unbind(-1)
    ndc_x, ndc_y, ndc_z = x / w, y / w, z / w
    area = (ndc_x[:, 1] - ndc_x[:, 0]) * (ndc_y[:, 2] - ndc_y[:, 0]) - (
        ndc_x[:, 2] - ndc_x[:, 0]
    ) * (ndc_y[:, 1] - ndc_y[:, 0])
    valid = (w > 0).all(1) & (ndc_z >= -1).all(1) & (ndc_z <= 1).all(1) & (area.abs() > 1e-14)

    matrix = torch.stack([x, y, w], dim=1)  # rows x, y, w; one column per vertex
    matrix[~valid] = torch.eye(3, dtype=matrix.dtype, device=matrix.device)
    a = torch.linalg.inv(matrix)
    a[~valid] = 0.0
    depth_plane = (z[:, None, :] @ a).squeeze(1)

    py = (1.0 - ndc_y) * (resolution / 2) - 0.5
    row0 = torch.ceil(py.min(1).values).clamp(0, resolution).long()
    row1 = torch.floor(py.max(1).values).clamp(-1, resolution - 1).long()
    rows = (row1 - row0 + 1).clamp_min(0) * valid
    return a, depth_plane, row0, rows


def _expand(counts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For items with ``counts[i]`` elements each: ``(item, position within item)`` per element."""
    item = torch.repeat_interleave(torch.arange(len(counts), device=counts.device), counts)
    first = torch.cumsum(counts, 0) - counts
    return item, torch.arange(len(item), device=counts.device) - first[item]


def _row_spans(a: torch.Tensor, row0: torch.Tensor, rows: torch.Tensor, resolution: int):
    """The run of sample columns each triangle covers on each of its sample rows.

    On a row ``s_y`` is fixed, so each ``b'_k = alpha_k s_x + beta_k`` is affine in ``s_x`` and
    the samples inside the triangle form one interval. Its ends are widened by a hair so that
    rounding never opens a crack between neighbours; the depth test settles shared samples.

    Returns:
        ``(tri, row, col0, cols)``, each ``(T,)`` int64 over the (triangle, row) pairs.
    """
    tri, offset = _expand(rows)
    row = row0[tri] + offset
    step = 2.0 / resolution
    sy = 1.0 - (row.to(torch.float64) + 0.5) * step
    coeffs = a[tri]
    alpha = coeffs[..., 0]
    beta = coeffs[..., 1] * sy[:, None] + coeffs[..., 2]
    root = -beta / torch.where(alpha == 0, torch.ones_like(alpha), alpha)
    inf = torch.full_like(root, float("inf"))
    lower = torch.where(alpha > 0, root, -inf).max(1).values
    upper = torch.where(alpha < 0, root, inf).min(1).values
    upper = torch.where(((alpha == 0) & (beta < 0)).any(1), -inf[:, 0], upper)
    hair = 1e-7
    col0 = torch.ceil((lower + 1.0) / step - 0.5 - hair).clamp(0, resolution)
    col1 = torch.floor((upper + 1.0) / step - 0.5 + hair).clamp(-1, resolution - 1)
    cols = (col1 - col0 + 1).clamp_min(0)
    return tri, row, col0.long(), cols.long()


def _chunks(counts: torch.Tensor, budget: int):
    """Consecutive index ranges of ``counts`` whose sums are about ``budget`` (at least one)."""
    ends = torch.cumsum(counts, 0)
    start, total = 0, len(counts)
    while start < total:
        done = int(ends[start - 1]) if start else 0
        stop = int(torch.searchsorted(ends, done + budget, right=True))
        stop = min(max(stop, start + 1), total)
        yield start, stop
        start = stop


def rasterize(clip: torch.Tensor, faces: torch.Tensor, resolution: int) -> GBuffer:
    """Rasterise triangles with a depth test, GL-style sample centres, no face culling.

    Args:
        clip: ``(V, 4)`` clip-space vertex positions (any float dtype, any device).
        faces: ``(F, 3)`` integer vertex indices.
        resolution: samples per side of the square grid.

    Returns:
        The :class:`GBuffer` of the nearest triangle at each covered sample. Ties in depth go
        to the lower triangle index, so results are deterministic.
    """
    if resolution < 1:
        raise ValueError(f"resolution must be positive, got {resolution}")
    device = clip.device
    faces = faces.to(device=device, dtype=torch.long)
    a, depth_plane, row0, rows = _triangle_setup(clip, faces, resolution)
    tri, row, col0, cols = _row_spans(a, row0, rows, resolution)

    # Depth is affine in screen space: z = z_row + dz_dx * s_x along each span.
    step = 2.0 / resolution
    sy = 1.0 - (row.to(torch.float64) + 0.5) * step
    plane = depth_plane[tri]
    z_row = (plane[:, 1] * sy + plane[:, 2]).to(torch.float32)
    dz_dx = plane[:, 0].to(torch.float32)
    span_base = row * resolution + col0

    nearest = torch.full((resolution * resolution,), _EMPTY, dtype=torch.int64, device=device)
    for start, stop in _chunks(cols, _PAIRS_PER_CHUNK):
        span, offset = _expand(cols[start:stop])
        span += start
        sx = ((col0[span] + offset).to(torch.float32) + 0.5) * step - 1.0
        depth = (z_row[span] + dz_dx[span] * sx).clamp(-1.0, 1.0)
        key = ((depth + 1.0) * (_DEPTH_LEVELS / 2)).long() << _TRIANGLE_BITS
        key |= tri[span]
        nearest.scatter_reduce_(0, span_base[span] + offset, key, "amin")

    pixels = torch.nonzero(nearest != _EMPTY).squeeze(1)
    tri_ids = nearest[pixels] & ((1 << _TRIANGLE_BITS) - 1)
    return GBuffer(
        resolution=resolution,
        pixels=pixels.to(torch.int32),
        tri_ids=tri_ids.to(torch.int32),
        tri_matrices=a.to(torch.float32).reshape(-1, 9).T.contiguous(),
    )
