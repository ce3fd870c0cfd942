"""UV-space views of a mesh: chart structure, how much of the texture the charts use, and what
the GeoScaler network reads of the mesh besides its texture.

* Charts: UV-connected faces.
* Geometry maps: the normalised 3D position and normal of the surface point under every texel
  centre, rasterised into UV space, so convolutions over the texture see the geometry.
* The vertex graph: the mesh's 3D points (vertices welded across UV seams) joined by the edges
  of its faces, weighted by their Euclidean length, on which GeoCoding filters.
* UV rasters: for every texel centre of a texture, the face covering it and its barycentrics,
  to interpolate per-vertex values over the faces back onto the texture plane.

Only square textures are handled by the network's maps (the rasteriser's grid is square).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh
from geoscaler.render.cameras import sample_extent
from geoscaler.render.raster import GBuffer, rasterize
from geoscaler.render.texture import build_mip_chain, mip_sizes


def uv_corner_ids(mesh: TexturedMesh) -> np.ndarray:
    """``(V,)`` int64 id of each vertex's UV-space corner: vertices with the same 3D point and
    the same UV share one, so meshes stored with one vertex per face corner still join up."""
    keys = np.concatenate([mesh.vertex_to_point[:, None].astype(np.float64), mesh.uvs], axis=1)
    _, corner_id = np.unique(keys, axis=0, return_inverse=True)
    return corner_id.reshape(-1)


def tiled_face_uvs(mesh: TexturedMesh, faces: np.ndarray) -> np.ndarray:
    """``(F, 3, 2)`` float64 UVs of ``faces``, each face shifted by whole tiles so its centroid
    lies in ``[0, 1)^2`` (repeat addressing)."""
    corner_uvs = mesh.uvs[faces].astype(np.float64)
    return corner_uvs - np.floor(corner_uvs.mean(axis=1, keepdims=True))


def chart_labels(mesh: TexturedMesh) -> np.ndarray:
    """``(F,)`` int64 UV chart of every face: faces joined through shared UV-space corners
    (:func:`uv_corner_ids`)."""
    return _joined(uv_corner_ids(mesh)[mesh.faces])


def _joined(corner_ids: np.ndarray) -> np.ndarray:
    """``(F,)`` int64 compact label of the faces ``(F, 3)`` joined through shared corner ids:
    the components of the bipartite graph face <-> corner, numbered by their first face."""
    num_faces = len(corner_ids)
    if num_faces == 0:
        return np.zeros(0, np.int64)
    _, corners = np.unique(corner_ids, return_inverse=True)
    rows = np.repeat(np.arange(num_faces), 3)
    cols = num_faces + corners.reshape(-1)
    size = num_faces + int(corners.max()) + 1
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(size, size))
    _, labels = connected_components(graph, directed=False)
    _, charts = np.unique(labels[:num_faces], return_inverse=True)
    return charts.astype(np.int64)


def cut_charts(mesh: TexturedMesh, charts: np.ndarray, longest: np.ndarray) -> np.ndarray:
    """``(F,)`` int64 compact chart labels where every chart whose UV bounding box is longer
    than ``longest[chart]`` (UV units; ``inf``: never cut) is cut into pieces no longer than
    that, as far as its faces allow.

    A piece too long is halved across its longer side at the middle of its box (each face
    goes to the side of its UV centroid), and each half's connected parts are cut again; so
    cuts run along face edges and every piece is connected. A piece whose faces all lie on
    one side (one long face) stays whole. ``charts`` is ``(F,)`` (:func:`chart_labels`);
    pieces are numbered in the order of their first face.
    """
    corner_ids = uv_corner_ids(mesh)[mesh.faces]  # (F, 3)
    corners = mesh.corner_uvs().astype(np.float64)  # (F, 3, 2)
    low, high, centroid = corners.min(axis=1), corners.max(axis=1), corners.mean(axis=1)
    labels = np.array(charts, np.int64)
    fresh = int(labels.max(initial=-1)) + 1
    for chart in np.unique(charts[np.isfinite(longest[charts])]):
        stack, kept_label = [np.flatnonzero(charts == chart)], False
        while stack:
            faces = stack.pop()
            box_low, box_high = low[faces].min(axis=0), high[faces].max(axis=0)
            axis = int(np.argmax(box_high - box_low))
            middle = (box_low[axis] + box_high[axis]) / 2
            side = centroid[faces, axis] < middle
            if box_high[axis] - box_low[axis] > longest[chart] and 0 < side.sum() < len(faces):
                for half in (faces[side], faces[~side]):
                    parts = _joined(corner_ids[half])
                    order = np.argsort(parts, kind="stable")
                    stack.extend(np.split(half[order], np.cumsum(np.bincount(parts))[:-1]))
                continue
            if kept_label:
                labels[faces], fresh = fresh, fresh + 1
            kept_label = True
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    return np.argsort(np.argsort(first))[inverse.reshape(-1)].astype(np.int64)


def rasterize_uv(mesh: TexturedMesh, resolution: int, material: int | None = None) -> GBuffer:
    """Rasterise the faces into UV space at ``resolution x resolution`` texels.

    Each face is shifted by whole tiles so its centroid lies in [0, 1)^2 (repeat addressing);
    row 0 is the top of the texture image, as everywhere.

    Args:
        material: only the faces of this material (all faces when None).
    """
    faces = mesh.faces if material is None else mesh.faces[mesh.face_material == material]
    corner_uvs = tiled_face_uvs(mesh, faces)  # (F, 3, 2)
    clip = np.concatenate(
        [corner_uvs * 2 - 1, np.zeros_like(corner_uvs[..., :1]), np.ones_like(corner_uvs[..., :1])],
        axis=2,
    ).reshape(-1, 4)
    corners = torch.arange(len(clip)).view(-1, 3)
    return rasterize(torch.from_numpy(clip), corners, resolution)


# Channels of the network input: sRGB texture, position, normal, coverage mask.
INPUT_CHANNELS = 10


@dataclass
class UVRaster:
    """The faces of one material rasterised over a ``size x size`` texel grid.

    Attributes:
        size: texels per side.
        texels: ``(N,)`` int64 flat index ``row * size + col`` of each covered texel centre
            (row 0 is the top of the texture).
        corners: ``(N, 3)`` int64 mesh vertex index of each corner of the covering face.
        weights: ``(N, 3)`` float32 barycentric weight of each corner.
    """

    size: int
    texels: torch.Tensor
    corners: torch.Tensor
    weights: torch.Tensor

    def interpolate(self, corner_values: torch.Tensor) -> torch.Tensor:
        """Interpolate per-vertex values over the faces into the texture plane.

        Args:
            corner_values: ``(V, C)`` one row per mesh vertex (or per point after indexing).

        Returns:
            ``(C, size, size)``, zero at texels no face covers.
        """
        corners = corner_values.index_select(0, self.corners.view(-1))
        values = (corners.view(*self.corners.shape, -1) * self.weights[..., None]).sum(1)  # (N, C)
        plane = corner_values.new_zeros(self.size * self.size, corner_values.shape[1])
        plane = plane.index_copy(0, self.texels, values)
        return plane.T.reshape(-1, self.size, self.size)


def uv_raster(
    mesh: TexturedMesh, material: int, size: int, device: torch.device | str = "cpu"
) -> UVRaster:
    """Rasterise the faces of ``material`` over a ``size x size`` texel grid."""
    faces = torch.from_numpy(np.asarray(mesh.faces[mesh.face_material == material], np.int64))
    gbuffer = rasterize_uv(mesh, size, material)
    weights, _, _ = gbuffer.barycentrics()
    tri_ids = gbuffer.tri_ids.long()
    return UVRaster(
        size,
        gbuffer.pixels.long().to(device),
        faces[tri_ids].to(device),
        weights.T.contiguous().to(device),
    )


def geometry_maps(raster: UVRaster, mesh: TexturedMesh) -> torch.Tensor:
    """``(7, size, size)`` position (3), unit normal (3) and coverage (1) under each texel.

    Positions are in the protocol's unit scene; uncovered texels are zero in every channel.
    """
    device = raster.texels.device
    positions = torch.from_numpy(mesh.normalized_positions()).to(device)
    normals = torch.from_numpy(np.asarray(mesh.normals, np.float32)).to(device)
    maps = raster.interpolate(torch.cat([positions, normals], dim=1))
    maps[3:6] = maps[3:6] / maps[3:6].norm(dim=0, keepdim=True).clamp_min(1e-12)
    coverage = torch.zeros(raster.size * raster.size, device=device)
    coverage[raster.texels] = 1.0
    return torch.cat([maps, coverage.view(1, raster.size, raster.size)])


def check_square(mesh: TexturedMesh) -> None:
    """Raise a clear error for what the network does not handle: non-square textures, and
    one base-colour image shown by several materials (it makes one texture per material)."""
    seen: dict[int, str] = {}
    for material in mesh.materials:
        texture = material.base_color_texture
        if texture is not None and texture.shape[0] != texture.shape[1]:
            raise GeoscalerError(
                f"material {material.name!r}: texture is {texture.shape[1]}x{texture.shape[0]}; "
                "the geoscaler network handles square textures only: use --method direct"
            )
        if texture is not None and id(texture) in seen:
            raise GeoscalerError(
                f"materials {seen[id(texture)]!r} and {material.name!r} show one base-colour "
                "image; the geoscaler network makes one texture per material: use --method "
                "direct, which keeps the image shared"
            )
        if texture is not None:
            seen[id(texture)] = material.name


@dataclass
class MeshGraph:
    """The mesh's points and edges, and how its (UV-split) vertices map onto the points.

    Attributes:
        vertex_to_point: ``(V,)`` int64 point of every mesh vertex.
        vertex_used: ``(V,)`` bool, the vertex is a corner of some face.
        num_points: ``P``.
        sources, targets: ``(E,)`` int64 directed edges ``j -> i`` (both directions stored).
        lengths: ``(E,)`` float32 Euclidean length ``e_ij`` in the protocol's unit scene.
    """

    vertex_to_point: torch.Tensor
    vertex_used: torch.Tensor
    num_points: int
    sources: torch.Tensor
    targets: torch.Tensor
    lengths: torch.Tensor

    def neighbour_sum(self, features: torch.Tensor) -> torch.Tensor:
        """``(P, C)``: ``sum_{j in N(i)} e_ij f_j`` for every point ``i`` (0 when isolated)."""
        messages = features.index_select(0, self.sources) * self.lengths[:, None]
        return features.new_zeros(features.shape).index_add(0, self.targets, messages)

    def pool_vertices(self, vertex_features: torch.Tensor) -> torch.Tensor:
        """``(P, C)`` mean over the used vertices of each point of ``(V, C)`` features.

        A point that appears at several UV positions (a seam) averages its samples; a point
        with no used vertex gets zeros.
        """
        used = self.vertex_used.to(vertex_features.dtype)[:, None]
        sums = vertex_features.new_zeros(self.num_points, vertex_features.shape[1])
        sums = sums.index_add(0, self.vertex_to_point, vertex_features * used)
        counts = used.new_zeros(self.num_points, 1).index_add(0, self.vertex_to_point, used)
        return sums / counts.clamp_min(1)


def mesh_graph(mesh: TexturedMesh, device: torch.device | str = "cpu") -> MeshGraph:
    """The graph GeoCoding filters on: welded points, face edges, Euclidean edge lengths.

    Meshes stored with one vertex per face corner are welded through ``vertex_to_point``;
    degenerate edges (both ends on one point) and repeated edges are dropped.
    """
    vertex_to_point = np.asarray(mesh.vertex_to_point, np.int64)
    num_points = int(vertex_to_point.max()) + 1 if len(vertex_to_point) else 0
    corners = vertex_to_point[np.asarray(mesh.faces, np.int64)]  # (F, 3) points
    pairs = np.concatenate([corners[:, [0, 1]], corners[:, [1, 2]], corners[:, [2, 0]]])
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    directed = np.concatenate([pairs, pairs[:, ::-1]])
    positions = mesh.normalized_positions().astype(np.float64)
    point_position = np.zeros((num_points, 3))
    point_position[vertex_to_point] = positions
    lengths = np.linalg.norm(
        point_position[directed[:, 0]] - point_position[directed[:, 1]], axis=1
    )
    used = np.zeros(len(vertex_to_point), bool)
    used[np.asarray(mesh.faces).reshape(-1)] = True

    def tensor(array: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(array)).to(device=device, dtype=dtype)

    return MeshGraph(
        tensor(vertex_to_point, torch.int64),
        tensor(used, torch.bool),
        num_points,
        tensor(directed[:, 0], torch.int64),
        tensor(directed[:, 1], torch.int64),
        tensor(lengths, torch.float32),
    )


def vertex_materials(mesh: TexturedMesh) -> np.ndarray:
    """``(V,)`` int64 material of the first face using each vertex (-1 for unused ones)."""
    faces = np.asarray(mesh.faces, np.int64)
    first_face = np.full(len(mesh.uvs), len(faces), np.int64)
    np.minimum.at(first_face, faces.reshape(-1), np.repeat(np.arange(len(faces)), 3))
    used = first_face < len(faces)
    materials = np.full(len(mesh.uvs), -1, np.int64)
    materials[used] = np.asarray(mesh.face_material, np.int64)[first_face[used]]
    return materials


# ------------------------------------------------------------------ texels the renderer can read

GRAZING_STRETCH = 8.0
"""How far an oblique view may stretch a texel footprint beyond a frontal one's: 1 / cos of the
angle between view ray and surface normal, 8 up to 82.8 degrees. Lookups at more grazing angles
may read coarser levels than :func:`face_max_levels` allows for."""
_LARGE_LAYOUT = 1 << 26
"""(face, texel cell) pairs beyond which a layout counts as reaching every texel."""
_PAIRS_PER_CHUNK = 1 << 19
"""(Face, cell) pairs tested at once: about 200 bytes each in flight (float64 normals, centres
and sides), so ~100 MB, below what a training step of a 2048 x 2048 map holds."""


def face_max_levels(
    mesh: TexturedMesh, faces: np.ndarray, size: tuple[int, int], sample_extent: float
) -> np.ndarray:
    """The coarsest mip level a trilinear lookup on each face can read, or -1 for a face of
    zero area, which no view shows.

    A lookup's level of detail is log2 of the larger singular value of the screen-to-texel
    Jacobian. On a face it is at most ``sigma * sample_extent * GRAZING_STRETCH``, where
    ``sigma`` is the face's larger stretch in texels per scene unit; trilinear filtering reads
    the level below that bound and the next.

    Args:
        mesh: the mesh (positions in the protocol's unit scene).
        faces: ``(F, 3)`` int vertex indices.
        size: ``(h, w)`` texels of level 0.
        sample_extent: the largest scene size of one screen sample on a surface facing the
            camera (the farthest depth times the sample's angular size).

    Returns:
        ``(F,)`` int64 levels in ``[-1, num_levels - 1]``.
    """
    bound = face_lod_bounds(mesh, faces, size, sample_extent * GRAZING_STRETCH)
    num_levels = len(mip_sizes(*size))
    levels = np.clip(np.floor(np.nan_to_num(bound, neginf=0.0)) + 1, 0, num_levels - 1)
    return np.where(np.isfinite(bound), levels.astype(np.int64), -1)


def face_lod_bounds(
    mesh: TexturedMesh, faces: np.ndarray, size: tuple[int, int], sample_extent: float
) -> np.ndarray:
    """``(F,)`` float64 the largest level of detail a lookup on each face has where one screen
    sample spans ``sample_extent`` scene units on it (log2 of the face's larger stretch in
    texels of level 0 per scene unit, times that extent), ``-inf`` for a face of zero area."""
    height, width = size
    positions = mesh.normalized_positions().astype(np.float64)[faces]  # (F, 3, 3)
    edge1, edge2 = positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0]
    length1 = np.linalg.norm(edge1, axis=1)
    normal = np.cross(edge1, edge2)
    area2 = np.linalg.norm(normal, axis=1)  # twice the area
    visible = area2 > 1e-12 * np.maximum(length1, 1e-30) ** 2
    # The edges in an orthonormal frame of the face's plane: P = [[l1, e2.a], [0, e2.b]].
    p00 = np.where(visible, length1, 1.0)
    p01 = np.einsum("ij,ij->i", edge2, edge1) / p00
    p11 = np.where(visible, area2 / p00, 1.0)
    uvs = tiled_face_uvs(mesh, faces)
    texels = np.stack([uvs[..., 0] * width, (1.0 - uvs[..., 1]) * height], axis=-1)
    t1, t2 = texels[:, 1] - texels[:, 0], texels[:, 2] - texels[:, 0]
    # J = T P^-1 with T = [t1 t2]; P^-1 = [[1/p00, -p01/(p00 p11)], [0, 1/p11]].
    j_col0 = t1 / p00[:, None]
    j_col1 = (t2 - t1 * (p01 / p00)[:, None]) / p11[:, None]
    frobenius = (j_col0**2).sum(1) + (j_col1**2).sum(1)
    det = j_col0[:, 0] * j_col1[:, 1] - j_col0[:, 1] * j_col1[:, 0]
    gap = np.sqrt(np.maximum(frobenius**2 - 4 * det**2, 0.0))
    sigma = np.sqrt(np.maximum(0.5 * (frobenius + gap), 1e-30))
    return np.where(visible, np.log2(sigma * sample_extent), -np.inf)


def reachable_texels(
    mesh: TexturedMesh, material: int, size: tuple[int, int], sample_extent: float
) -> torch.Tensor:
    """``(h, w)`` bool: level-0 texels of a ``size`` texture of ``material`` that a lookup can
    read, directly or through a coarser level, from any view whose samples are at most
    ``sample_extent`` scene units wide (:func:`face_max_levels`).

    Only the UV layout and the geometry decide it, never the views that happen to be cached:
    at each level every texel cell a face touches, and its bilinear neighbours, are reachable.
    A layout too large to rasterise cell by cell (faces that overlap many times) counts as
    reaching every texel.
    """
    faces = np.asarray(mesh.faces, np.int64)[np.asarray(mesh.face_material) == material]
    max_levels = face_max_levels(mesh, faces, size, sample_extent)
    uvs = tiled_face_uvs(mesh, faces)
    level_masks = []
    for level, (h, w) in enumerate(mip_sizes(*size)):
        chosen = max_levels >= level
        corners = np.stack(
            [uvs[chosen][..., 0] * w, (1.0 - uvs[chosen][..., 1]) * h], axis=-1
        )  # (F', 3, 2) in texel cells of this level
        cells = _touched_cells(corners, h, w)
        if cells is None:
            return torch.ones(size, dtype=torch.bool)
        level_masks.append(_dilate_wrapped(cells))
    ones = torch.ones(*size, 1, dtype=torch.float64, requires_grad=True)
    chain = build_mip_chain(ones)
    read = sum((lvl[..., 0] * m).sum() for lvl, m in zip(chain, level_masks, strict=True))
    (grad,) = torch.autograd.grad(read, ones)
    return grad[..., 0] > 0


def reachable_masks(
    mesh: TexturedMesh,
    sizes: Sequence[tuple[int, int] | None],
    farthest: float,
    samples_per_side: int,
) -> list[torch.Tensor | None]:
    """Per material the ``(h, w)`` bool texels (:func:`reachable_texels`) that views from at
    most ``farthest`` from the origin, ``samples_per_side`` samples wide, can read: a surface
    point is at most the unit scene's radius farther. The other texels are gutters.

    Materials that show one base-colour image (the same array) get the union of their masks:
    a texel another material reads is not a gutter of the shared texture."""
    extent = sample_extent(farthest + 1.0, samples_per_side)
    masks = [
        None if size is None else reachable_texels(mesh, index, size, extent)
        for index, size in enumerate(sizes)
    ]
    textures = [material.base_color_texture for material in mesh.materials]
    for i, mask in enumerate(masks):
        for j in range(len(masks)):
            shared = textures[i] is not None and textures[j] is textures[i]
            if j != i and shared and mask is not None and masks[j] is not None:
                masks[i] = masks[i] | masks[j]
    return masks


def _touched_cells(corners: np.ndarray, height: int, width: int) -> torch.Tensor | None:
    """``(height, width)`` bool: texel cells that some triangle overlaps (repeat addressing),
    by a separating-axis test of every cell in each triangle's bounding box; None when that
    is more than :data:`_LARGE_LAYOUT` pairs.

    Args:
        corners: ``(F, 3, 2)`` float64 corners in cells (x right, y down; cell (i, j) spans
            ``[j, j + 1) x [i, i + 1)``).
    """
    mask = np.zeros(height * width, bool)
    low = np.floor(corners.min(axis=1)).astype(np.int64)  # (F, 2)
    high = np.floor(corners.max(axis=1)).astype(np.int64)
    span = np.minimum(high - low + 1, [width, height])  # a span past a tile covers it all
    counts = span[:, 0] * span[:, 1]
    if counts.sum() > _LARGE_LAYOUT:
        return None
    # Inward edge normals (x, y) of each triangle, zero for degenerate ones (bounding box only).
    edges = np.roll(corners, -1, axis=1) - corners  # (F, 3, 2)
    signed = edges[:, 0, 0] * -edges[:, 2, 1] + edges[:, 0, 1] * edges[:, 2, 0]
    orientation = np.sign(signed)[:, None]
    normals = np.stack([-edges[..., 1], edges[..., 0]], axis=-1) * orientation[..., None]
    offsets = np.einsum("fkc,fkc->fk", normals, corners)  # n . p_k
    reach = 0.5 * np.abs(normals).sum(-1)  # how far a cell's corners extend along n
    for faces, rank in _pair_chunks(counts):
        x = low[faces, 0] + rank % span[faces, 0]
        y = low[faces, 1] + rank // span[faces, 0]
        centres = np.stack([x + 0.5, y + 0.5], axis=-1)[:, None]  # (n, 1, 2)
        side = (normals[faces] * centres).sum(-1) - offsets[faces] + reach[faces]
        inside = (side >= 0).all(axis=1)
        mask[np.mod(y[inside], height) * width + np.mod(x[inside], width)] = True
    return torch.from_numpy(mask.reshape(height, width))


def _pair_chunks(counts: np.ndarray):
    """Yield ``(faces, rank)``: for each (face, cell-of-its-box) pair, the face and the cell's
    rank within the box, at most :data:`_PAIRS_PER_CHUNK` pairs at a time."""
    ends = np.cumsum(counts)
    first = 0
    while first < len(counts):
        limit = (ends[first - 1] if first else 0) + _PAIRS_PER_CHUNK
        last = max(int(np.searchsorted(ends, limit, side="right")), first + 1)
        part = counts[first:last]
        faces = np.repeat(np.arange(first, last), part)
        starts = np.cumsum(part) - part
        rank = np.arange(int(part.sum())) - np.repeat(starts, part)
        yield faces, rank
        first = last


def _dilate_wrapped(mask: torch.Tensor) -> torch.Tensor:
    """``(h, w)`` float: ``mask`` grown by one cell (bilinear neighbours), wrapping around."""
    grid = mask.to(torch.float64)[None, None]
    padded = torch.nn.functional.pad(grid, (1, 1, 1, 1), mode="circular")
    return torch.nn.functional.max_pool2d(padded, 3, stride=1)[0, 0]


# ------------------------------------------------------------------------------ coverage


COVERAGE_WORK = 20_000_000
"""Most (face, texel row) spans :func:`uv_coverage` walks: about a second of numpy work."""
_CHUNK = 1_000_000


def uv_coverage(mesh: TexturedMesh, material: int = 0, resolution: int = 512) -> float | None:
    """Fraction of the texture's area covered by at least one face of ``material``.

    Texel centres of a ``resolution x resolution`` grid inside a face count, with repeat
    addressing (UVs outside ``[0, 1]`` wrap). The cost grows with the texel rows the faces
    span, not with their area: each face is walked row by row, or column by column when it is
    taller than wide, into a per-row difference array. Identical faces count once, and a face
    that contains a whole texture repeat (an inscribed circle of radius at least
    ``sqrt(2) / 2``) covers everything. When the faces span more rows than
    :data:`COVERAGE_WORK` allows, the grid is halved (the figure is then measured on the
    coarser grid), down to 64 texels; beyond that the coverage is not measured (None).

    Returns
    -------
    float or None
        In ``[0, 1]``; 0 for a material without faces.
    """
    faces = mesh.faces[mesh.face_material == material]
    corners = np.asarray(mesh.uvs, dtype=np.float64)[faces]  # (F, 3, 2)
    corners = corners - np.floor(corners.mean(axis=1, keepdims=True))
    corners = np.unique(corners.reshape(-1, 6), axis=0).reshape(-1, 3, 2)
    if not len(corners):
        return 0.0
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).sum(axis=1)
    side, other = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    doubled_area = np.abs(side[:, 0] * other[:, 1] - side[:, 1] * other[:, 0])
    if (doubled_area >= edges * np.sqrt(0.5)).any():  # inradius = 2 area / perimeter
        return 1.0
    extent = corners.max(axis=1) - corners.min(axis=1)  # (F, 2) in repeats
    by_columns = extent[:, 1] > extent[:, 0]
    work = float(np.minimum(extent[:, 0], extent[:, 1]).sum()) + len(corners) / resolution
    while work * resolution > COVERAGE_WORK:
        if resolution <= 64:
            return None
        resolution //= 2
    texels = corners * resolution
    texels[..., 1] = resolution - texels[..., 1]  # row 0 at the top, as everywhere
    covered = _row_coverage(texels[~by_columns], resolution)
    covered |= _row_coverage(texels[by_columns][..., ::-1], resolution).T
    return float(covered.mean())


def _row_coverage(corners: np.ndarray, size: int) -> np.ndarray:
    """``(size, size)`` bool: texel centres ``(col + 0.5, row + 0.5)`` inside any triangle of
    ``(F, 3, 2)`` ``(x, y)`` texel coordinates, wrapped onto the grid, walked row by row."""
    lo = np.ceil(corners[..., 1].min(axis=1) - 0.5).astype(np.int64)
    hi = np.floor(corners[..., 1].max(axis=1) - 0.5).astype(np.int64)
    rows = np.maximum(hi - lo + 1, 0)
    ends = np.cumsum(rows)
    counts = np.zeros(size * (size + 1), dtype=np.int64)  # + at a span's start, - at its end
    for first in range(0, int(ends[-1]) if len(ends) else 0, _CHUNK):
        pair = np.arange(first, min(first + _CHUNK, int(ends[-1])))
        face = np.searchsorted(ends, pair, side="right")
        row = lo[face] + pair - (ends[face] - rows[face])
        left, right = _spans(corners[face], row + 0.5)
        keep = np.isfinite(left) & np.isfinite(right)
        col0 = np.ceil(left[keep] - 0.5).astype(np.int64)
        length = np.floor(right[keep] - 0.5).astype(np.int64) + 1 - col0
        row, col0 = np.mod(row[keep], size), np.mod(col0, size)
        end = col0 + np.clip(length, 0, size)  # beyond size: wraps to the row's start
        flat = row * (size + 1)
        wrapped = end > size
        opened = np.concatenate([flat + col0, flat[wrapped]])
        closed = np.concatenate([flat + np.minimum(end, size), flat[wrapped] + end[wrapped] - size])
        counts += np.bincount(opened, minlength=counts.size) - np.bincount(
            closed, minlength=counts.size
        )
    return np.cumsum(counts.reshape(size, size + 1), axis=1)[:, :size] > 0


def _spans(corners: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left and right x of ``(N, 3, 2)`` triangles at heights ``(N,)``: where the edges that
    straddle ``y`` cross it (left > right where none does)."""
    a, b = corners, np.roll(corners, -1, axis=1)
    dy = b[..., 1] - a[..., 1]
    with np.errstate(divide="ignore", invalid="ignore"):  # dy = 0: masked out below
        t = (y[:, None] - a[..., 1]) / dy
        x = a[..., 0] + t * (b[..., 0] - a[..., 0])
    crossing = (dy != 0) & (t >= 0) & (t <= 1)
    left = np.where(crossing, x, np.inf).min(axis=1)
    right = np.where(crossing, x, -np.inf).max(axis=1)
    return left, right
