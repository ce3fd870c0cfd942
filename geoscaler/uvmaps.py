"""UV-space views of a mesh: chart structure and how much of the texture the charts use."""

from __future__ import annotations

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from geoscaler.mesh import TexturedMesh
from geoscaler.raster import GBuffer, rasterize


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
    corner_id = uv_corner_ids(mesh)[mesh.faces]  # (F, 3)
    num_faces = len(mesh.faces)
    # Bipartite graph face <-> corner; components of it are the charts.
    rows = np.repeat(np.arange(num_faces), 3)
    cols = num_faces + corner_id.reshape(-1)
    size = num_faces + int(corner_id.max()) + 1 if num_faces else 0
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(size, size))
    _, labels = connected_components(graph, directed=False)
    _, charts = np.unique(labels[:num_faces], return_inverse=True)
    return charts.astype(np.int64)


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


def uv_coverage(mesh: TexturedMesh, material: int = 0, resolution: int = 512) -> float:
    """Fraction of the texture's area covered by at least one face of ``material``."""
    gbuffer = rasterize_uv(mesh, resolution, material)
    return gbuffer.num_samples / resolution**2
