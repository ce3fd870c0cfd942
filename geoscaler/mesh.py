"""Textured meshes: the one in-memory form every module works on.

This module owns the data model only: :class:`Material`, :class:`TexturedMesh`, the checks
that keep them consistent (:func:`check_texture`) and the array operations that define their
fields (welding vertices into points, vertex normals, baking a colour factor). Reading and
writing files is :mod:`geoscaler.io`.

Conventions (used everywhere in the project):

- UVs follow OpenGL/OBJ: ``v = 0`` is the bottom row of the texture image. Texture arrays
  are stored as images are, row 0 at the top, so texel row ``y`` holds ``v = 1 - (y + 0.5) / H``.
- Vertices are split at UV seams: one row of ``positions``/``uvs``/``normals`` per distinct
  (position, UV) pair. ``vertex_to_point`` welds them back to 3D points by position
  (:func:`weld_points`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .errors import GeoscalerError
from .texture import linear_to_srgb, srgb_to_linear


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
            preserve every other map and property untouched. Its images are the maps other
            than base colour (normal, occlusion, emissive, metallic-roughness); its base-colour
            slot is left empty: ``base_color_texture`` is the one truth.
        properties: the glTF material object (JSON) without image indices: every texture slot
            keeps its fields (``scale``, ``strength``, ``texCoord``, ``extensions``) and the
            texture's sampler under ``"sampler"``. Export writes it back. Empty for plain OBJ.
    """

    name: str
    base_color_texture: np.ndarray | None
    base_color_factor: np.ndarray = field(default_factory=lambda: np.ones(4, dtype=np.float32))
    source: Any = None
    properties: dict[str, Any] = field(default_factory=dict)


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
        source_files: every file read to build it (mesh, MTL, buffers, textures), resolved;
            :func:`geoscaler.io.save_mesh` refuses to write over any of them.
    """

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    normals: np.ndarray
    vertex_to_point: np.ndarray
    face_material: np.ndarray
    materials: list[Material]
    source_path: Path | None = None
    source_files: list[Path] = field(default_factory=list)

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

    def with_texture(
        self, material_index: int, texture: np.ndarray, uvs: np.ndarray | None = None
    ) -> TexturedMesh:
        """A copy with a new base-colour texture for one material, and optionally new UVs.

        Parameters
        ----------
        material_index : int
            Which material gets ``texture``.
        texture : (H, W, C) uint8
            sRGB texels, ``C`` 3 or 4, row 0 at the top. Kept by reference, not copied.
        uvs : (V, 2) float, optional
            New texture coordinates of every vertex (OpenGL convention).

        Returns
        -------
        TexturedMesh
            Shares every unchanged array with ``self``; factor, other maps, properties and
            source files carry over, so :func:`geoscaler.io.save_mesh` still protects the
            input files.
        """
        if not 0 <= material_index < len(self.materials):
            raise ValueError(
                f"material_index {material_index} out of range for {len(self.materials)} materials"
            )
        check_texture(texture, f"texture for material {material_index}")
        materials = list(self.materials)
        materials[material_index] = replace(materials[material_index], base_color_texture=texture)
        new_uvs = self.uvs
        if uvs is not None:
            new_uvs = np.asarray(uvs, dtype=np.float32)
            if new_uvs.shape != self.uvs.shape:
                raise ValueError(f"uvs must have shape {self.uvs.shape}, got {new_uvs.shape}")
        return replace(self, uvs=new_uvs, materials=materials)

    def validate(self) -> None:
        """Raise ``ValueError`` when the arrays disagree in shape or index range."""
        count = len(self.positions)
        shapes = {
            "positions": (self.positions, (count, 3)),
            "uvs": (self.uvs, (count, 2)),
            "normals": (self.normals, (count, 3)),
            "vertex_to_point": (self.vertex_to_point, (count,)),
            "faces": (self.faces, (len(self.faces), 3)),
            "face_material": (self.face_material, (len(self.faces),)),
        }
        for name, (array, shape) in shapes.items():
            if np.shape(array) != shape:
                raise ValueError(f"{name} has shape {np.shape(array)}, expected {shape}")
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= count):
            raise ValueError("faces index vertices out of range")
        if len(self.faces) and (
            self.face_material.min() < 0 or self.face_material.max() >= len(self.materials)
        ):
            raise ValueError("face_material indexes materials out of range")
        for material in self.materials:
            if material.base_color_texture is not None:
                what = f"texture of material {material.name!r}"
                check_texture(material.base_color_texture, what)
            if np.shape(material.base_color_factor) != (4,):
                raise ValueError(f"material {material.name!r}: base_color_factor must be (4,)")


class TextureError(GeoscalerError, ValueError):
    """A texture array of the wrong type or shape.

    Both a :class:`GeoscalerError` (a texture given by the user, reported without a traceback)
    and a ``ValueError`` (a wrong argument to the data model).
    """


_CHANNEL_NAMES = {1: "grey", 2: "grey+alpha", 3: "RGB", 4: "RGBA"}


def check_texture(
    texture: np.ndarray, what: str = "texture", channels: tuple[int, ...] = (3, 4)
) -> None:
    """Raise :class:`TextureError` unless ``texture`` is a texture array.

    The one texture-array check of the project: the data model (base-colour maps, ``C`` 3 or
    4) and the texture filters (``C`` 1 to 4) both use it.

    Parameters
    ----------
    texture : (H, W, C) uint8 expected
        ``H, W >= 1`` and ``C`` one of ``channels``.
    what : str
        What the texture is, the start of the message (e.g. ``"texture of material 'wood'"``).
    channels : tuple of int
        The channel counts accepted: 1 (grey), 2 (grey+alpha), 3 (RGB), 4 (RGBA).
    """
    if isinstance(texture, np.ndarray):
        if (
            texture.dtype == np.uint8
            and texture.ndim == 3
            and texture.shape[2] in channels
            and 0 not in texture.shape[:2]
        ):
            return
        got = f"a {texture.dtype} array of shape {texture.shape}"
    else:
        got = f"a {type(texture).__name__}"
    counts = [str(c) for c in sorted(channels)]
    names = [_CHANNEL_NAMES[c] for c in sorted(channels)]
    raise TextureError(
        f"{what}: expected an (H, W, C) uint8 array (8 bits per channel) with C = "
        f"{_either(counts)} ({_either(names)}), got {got}"
    )


def _either(words: list[str]) -> str:
    """``a``, ``a or b``, ``a, b or c``."""
    return " or ".join([", ".join(words[:-1]), words[-1]] if len(words) > 1 else words)


# ----------------------------------------------------------------------------- array operations


def bake_color_factor(texture: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """Multiply an sRGB texture by a linear RGB(A) factor, as a renderer would.

    Parameters
    ----------
    texture : (H, W, C) uint8
        sRGB colour, ``C`` 3 or 4 (alpha is linear).
    factor : (4,) float
        Linear RGBA multiplier; alpha is applied only when the texture has an alpha channel.

    Returns
    -------
    (H, W, C) uint8
    """
    encoded = torch.from_numpy(texture[..., :3] / 255.0)
    linear = srgb_to_linear(encoded) * torch.as_tensor(np.asarray(factor[:3], dtype=np.float64))
    out = texture.copy()
    out[..., :3] = np.round(linear_to_srgb(linear).numpy() * 255)
    if texture.shape[2] == 4:
        out[..., 3] = np.round(np.clip(texture[..., 3] * float(factor[3]), 0, 255))
    return out


def first_occurrence_groups(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group identical rows (bitwise, with -0 == 0), numbered in order of first occurrence.

    Parameters
    ----------
    rows : (N, K) float32

    Returns
    -------
    group : (N,) int64
        Group of each row.
    first : (G,) int64
        Index of the first row of each group.
    """
    rows = np.ascontiguousarray(rows + np.float32(0))  # -0.0 + 0.0 == +0.0
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[inverse.ravel()].astype(np.int64), first[order].astype(np.int64)


def weld_points(positions: np.ndarray) -> np.ndarray:
    """``(V,)`` int64 point index of each vertex: equal positions share a point.

    Points are numbered in order of first occurrence; ``positions`` is ``(V, 3)`` float32.
    """
    return first_occurrence_groups(np.asarray(positions, dtype=np.float32))[0]


def normalize_rows(vectors: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Unit rows of ``(N, 3)`` float ``vectors``; rows of zero or non-finite length become
    ``fallback`` ``(3,)``. Returns ``(N, 3)`` float."""
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    good = np.isfinite(length) & (length > 1e-20)
    return np.where(good, vectors / np.where(good, length, 1.0), fallback)


def compute_vertex_normals(
    positions: np.ndarray, faces: np.ndarray, vertex_to_point: np.ndarray
) -> np.ndarray:
    """Area-weighted normals over welded points, so UV seams do not crease the shading.

    Parameters
    ----------
    positions : (V, 3) float
    faces : (F, 3) int, CCW front faces
    vertex_to_point : (V,) int

    Returns
    -------
    (V, 3) float32 unit normals; vertices of no or degenerate faces get +Z.
    """
    corners = np.asarray(positions, dtype=np.float64)[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    point_of_corner = vertex_to_point[faces].ravel()
    count = int(vertex_to_point.max()) + 1 if len(vertex_to_point) else 0
    weights = np.repeat(face_normals, 3, axis=0)
    summed = np.stack(
        [np.bincount(point_of_corner, weights=weights[:, k], minlength=count) for k in range(3)],
        axis=1,
    )
    return normalize_rows(summed[vertex_to_point], np.array([0.0, 0.0, 1.0])).astype(np.float32)
