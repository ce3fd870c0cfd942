"""Textured meshes: the one in-memory form every module works on, and its file formats.

Conventions (used everywhere in the project):

- UVs follow OpenGL/OBJ: ``v = 0`` is the bottom row of the texture image. Texture arrays
  are stored as images are, row 0 at the top, so texel row ``y`` holds ``v = 1 - (y + 0.5) / H``.
- Vertices are split at UV seams: one row of ``positions``/``uvs``/``normals`` per distinct
  (position, UV) pair. ``vertex_to_point`` welds them back to 3D points by position.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass
class Material:
    """A material as far as rendering needs it, plus the loader's object for export.

    Attributes:
        name: material name from the file.
        base_color_texture: ``(H, W, C)`` uint8 sRGB, ``C`` 3 or 4, row 0 at the top; None when
            the material has no base-colour map.
        base_color_factor: ``(4,)`` float32 linear RGBA multiplier (1 where the texture is the
            colour, as for OBJ ``map_Kd``).
        source: the loader's material (e.g. a trimesh ``PBRMaterial``), kept so that export can
            preserve every other map and property untouched.
    """

    name: str
    base_color_texture: np.ndarray | None
    base_color_factor: np.ndarray = field(
        default_factory=lambda: np.ones(4, dtype=np.float32)
    )
    source: Any = None


@dataclass
class TexturedMesh:
    """A triangle mesh with per-vertex UVs and base-colour textures.

    Attributes:
        positions: ``(V, 3)`` float32, scene-graph transforms applied, file units.
        faces: ``(F, 3)`` int64 indices into ``positions``/``uvs``/``normals``, CCW front faces.
        uvs: ``(V, 2)`` float32 texture coordinates (OpenGL convention, may lie outside [0, 1]).
        normals: ``(V, 3)`` float32 unit vertex normals.
        vertex_to_point: ``(V,)`` int64 index of the welded 3D point of each vertex.
        face_material: ``(F,)`` int64 index into ``materials``.
        materials: the materials, at least one with a base-colour texture.
        source_path: the file it was loaded from, if any.
    """

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    normals: np.ndarray
    vertex_to_point: np.ndarray
    face_material: np.ndarray
    materials: list[Material]
    source_path: Path | None = None

    @property
    def num_points(self) -> int:
        """Number of welded 3D points."""
        return int(self.vertex_to_point.max()) + 1 if len(self.vertex_to_point) else 0

    def points(self) -> np.ndarray:
        """``(P, 3)`` float32 welded 3D points (the position of each point's vertices)."""
        out = np.zeros((self.num_points, 3), dtype=np.float32)
        out[self.vertex_to_point] = self.positions
        return out

    def normalization(self) -> tuple[np.ndarray, float]:
        """PROTOCOL.md scene normalisation as ``(centre (3,), scale)``.

        ``normalized = (positions - centre) * scale`` puts the bounding-box centre at the
        origin and the farthest vertex at distance 1.
        """
        lo, hi = self.positions.min(axis=0), self.positions.max(axis=0)
        centre = ((lo + hi) / 2).astype(np.float64)
        radius = float(np.linalg.norm(self.positions - centre, axis=1).max())
        return centre.astype(np.float32), (1.0 / radius if radius > 0 else 1.0)

    def normalized_positions(self) -> np.ndarray:
        """``(V, 3)`` float32 positions in the protocol's unit scene."""
        centre, scale = self.normalization()
        return ((self.positions - centre) * scale).astype(np.float32)
