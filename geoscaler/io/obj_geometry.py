"""The geometry of an OBJ file, read by trimesh: its triangles, placed, grouped by material.

The one module that imports trimesh (about 0.8 s), and only :func:`geoscaler.io.obj.load_obj`
imports it, when an OBJ is read: glTF jobs and every other command do without. trimesh reads
through a resolver that never writes and serves only the material names it needs.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from typing import Any

import numpy as np
import trimesh

from geoscaler.errors import GeoscalerError

from .assemble import Part


def obj_parts(data: bytes, names_only: str, material_of: Callable[[Any], int | None]) -> list[Part]:
    """The placed parts of the OBJ file ``data``; ``names_only`` is the material library
    trimesh is given (names and tags), ``material_of`` maps its materials to the loader's."""
    resolver = ConstantResolver(names_only.encode())
    scene = trimesh.load_scene(io.BytesIO(data), file_type="obj", resolver=resolver, process=False)
    return scene_parts(scene, material_of)


class ReadOnlyResolver(trimesh.resolvers.Resolver):
    """A trimesh resolver that never writes."""

    def write(self, name: str, data: Any) -> None:
        raise GeoscalerError("reading a mesh never writes files")

    def namespaced(self, namespace: str) -> ReadOnlyResolver:
        return self

    def keys(self) -> list[str]:
        return []


class ConstantResolver(ReadOnlyResolver):
    """Serves the same bytes whatever is asked: the material library trimesh's OBJ reader wants."""

    def __init__(self, data: bytes):
        self.data = data

    def get(self, name: str) -> bytes:
        return self.data


def scene_parts(scene: trimesh.Scene, material_of: Callable[[Any], int | None]) -> list[Part]:
    """Every triangle geometry of ``scene`` placed by its node transform."""
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry[name]
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
            parts.append(place(geometry, np.asarray(transform, dtype=np.float64), material_of))
    return parts


def place(
    geometry: trimesh.Trimesh, transform: np.ndarray, material_of: Callable[[Any], int | None]
) -> Part:
    """Apply a 4x4 transform to a trimesh geometry and read its UVs and file normals."""
    linear = transform[:3, :3]
    with np.errstate(invalid="ignore", over="ignore"):  # NaN and inf are refused later
        positions = np.asarray(geometry.vertices, dtype=np.float64) @ linear.T + transform[:3, 3]
    faces = np.asarray(geometry.faces, dtype=np.int64)
    if np.linalg.det(linear) < 0:
        faces = faces[:, ::-1]
    uvs = getattr(geometry.visual, "uv", None)
    if uvs is not None and np.shape(uvs) != (len(positions), 2):
        uvs = None
    normals = None
    # trimesh caches normals given by the file; asking for them otherwise computes them.
    if "vertex_normals" in geometry._cache and abs(np.linalg.det(linear)) > 0:
        normals = np.asarray(geometry.vertex_normals, dtype=np.float64) @ np.linalg.inv(linear)
    material = getattr(geometry.visual, "material", None)
    return Part(positions, faces, uvs, normals, material_of(material))
