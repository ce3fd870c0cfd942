"""Textured meshes: the one in-memory form every module works on.

This module owns the data model only: :class:`Material`, :class:`TexturedMesh`, the checks
that keep them consistent (:func:`check_texture`) and the array operations that define their
fields (welding vertices into points, vertex normals, baking a colour factor). Reading and
writing files is :mod:`geoscaler.io`.

Conventions (used everywhere in the project):

- UVs follow OpenGL/OBJ: ``v = 0`` is the bottom row of the texture image. Texture arrays
  are stored as images are, row 0 at the top, so texel row ``y`` holds ``v = 1 - (y + 0.5) / H``.
- Vertices are split at UV seams and hard edges: one row of ``positions``/``uvs``/``normals``
  (and ``attributes``) per distinct (position, UV, normal, attributes) tuple, so every face
  corner keeps what the file gave it. ``vertex_to_point`` welds them back to 3D points by
  position (:func:`weld_points`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .color import linear_to_srgb, srgb_to_linear
from .errors import GeoscalerError


@dataclass(frozen=True, eq=False)
class SourceImage:
    """How a texture came in: the image file (or embedded image) it was decoded from.

    Compared and hashed by identity: the loader gives one object per image of the file, shared
    by every slot and material that shows it.

    Attributes:
        pixels: the very ``(H, W, C)`` uint8 array decoded from it (read-only); a texture
            whose array ``is`` this one is unchanged since loading.
        mime: its type as its bytes say (``"image/png"``, ``"image/jpeg"``, ``"image/webp"``;
            others, e.g. ``"image/bmp"`` from an MTL, are re-encoded as PNG when written).
        data: the encoded file bytes as read.
        name: a file-name stem to reuse when writing it (e.g. ``"sofa_03_diff_1k"``).
    """

    pixels: np.ndarray
    mime: str
    data: bytes
    name: str


BASE_COLOR = "baseColorTexture"
"""The slot name of the base colour in :attr:`Material.sources` and :meth:`TexturedMesh.images`."""
ATTRIBUTE_COLUMNS = {"TANGENT": (4,), "COLOR_0": (3, 4), "TEXCOORD_1": (2,)}
"""The extra per-vertex glTF attributes a mesh can carry, and their column counts."""


@dataclass
class Material:
    """A material: what rendering needs, every other map, and the file's material properties.

    Texture arrays are ``(H, W, C)`` uint8, row 0 at the top. The loader gives the same array
    object to every slot and material that shows the same image, read-only; sharing is by
    identity (:meth:`TexturedMesh.images`, :meth:`TexturedMesh.with_images`).

    Attributes:
        name: material name from the file.
        base_color_texture: sRGB, ``C`` 3 or 4; None when the material has no base-colour map.
        base_color_factor: ``(4,)`` float32 linear RGBA multiplier (1 where the texture is the
            colour, as for OBJ ``map_Kd``).
        properties: the glTF material object (JSON) without texture indices: every texture
            slot keeps its fields (``scale``, ``strength``, ``texCoord``, ``extensions`` such as
            ``KHR_texture_transform``) and the texture's sampler under ``"sampler"``; extension
            slots stay inside their extension objects. From an MTL: ``emissiveFactor`` (Ke),
            and under ``"mtl"`` what only MTL says (map keywords and options, other
            statements). Export writes it back.
        maps: every texture map other than base colour, ``C`` 1 to 4, by slot: glTF names
            (``"metallicRoughnessTexture"``, ``"normalTexture"``, ``"occlusionTexture"``,
            ``"emissiveTexture"``), extension slots as ``"EXTENSION/field"`` (e.g.
            ``"KHR_materials_clearcoat/clearcoatNormalTexture"``), and MTL maps glTF has no
            slot for as ``"mtl:KEYWORD"`` (``"mtl:map_Ks"``, ``"mtl:map_Ns"``, ``"mtl:map_d"``,
            ``"mtl:bump"`` for a grey height map...).
        sources: for every slot that has one, ``"baseColorTexture"`` included, the image it
            was loaded from. Kept when a texture is replaced, so the writer can reuse its
            format and name (and its bytes, for a texture still ``is`` its source's pixels).
    """

    name: str
    base_color_texture: np.ndarray | None
    base_color_factor: np.ndarray = field(default_factory=lambda: np.ones(4, dtype=np.float32))
    properties: dict[str, Any] = field(default_factory=dict)
    maps: dict[str, np.ndarray] = field(default_factory=dict)
    sources: dict[str, SourceImage] = field(default_factory=dict)

    def textures(self) -> dict[str, np.ndarray]:
        """Every texture of the material by slot: base colour first (when it has one), then
        :attr:`maps` in their order."""
        first = {} if self.base_color_texture is None else {BASE_COLOR: self.base_color_texture}
        return {**first, **self.maps}


@dataclass
class TexturedMesh:
    """A triangle mesh with per-vertex UVs and its materials' textures.

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
        attributes: extra per-vertex glTF attributes kept from the file and written back
            (:data:`ATTRIBUTE_COLUMNS`): ``"TANGENT"`` ``(V, 4)`` float32 (unit xyz, w = +-1),
            ``"COLOR_0"`` ``(V, 3 or 4)`` float32 in [0, 1], ``"TEXCOORD_1"`` ``(V, 2)``
            float32 in the OpenGL convention, as ``uvs``.
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
    attributes: dict[str, np.ndarray] = field(default_factory=dict)

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

        ``texture``: ``(H, W, C)`` uint8 sRGB, ``C`` 3 or 4, row 0 at the top, kept by reference;
        ``uvs``: ``(V, 2)`` texture coordinates of every vertex (OpenGL convention). The copy
        shares every unchanged array with ``self``; factor, other maps, properties, sources
        and source files carry over (so :func:`geoscaler.io.save_mesh` still protects the
        input files). Only this material's base colour changes, even where the array is
        shared with other slots or materials: :meth:`with_images` replaces it everywhere.
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

    def corner_uvs(self, uvs: np.ndarray | None = None) -> np.ndarray:
        """``(F, 3, 2)`` float32 UV of every face corner: of ``uvs``, ``(V, 2)`` per vertex or
        ``(F, 3, 2)`` per corner already, or of the mesh's own when None."""
        uvs = self.uvs if uvs is None else np.asarray(uvs, np.float32)
        if uvs.shape == self.uvs.shape:
            return uvs[self.faces]
        if uvs.shape != (len(self.faces), 3, 2):
            raise ValueError(
                f"uvs must have shape {self.uvs.shape} (per vertex) or "
                f"{(len(self.faces), 3, 2)} (per face corner), got {uvs.shape}"
            )
        return uvs

    def with_uvs(self, uvs: np.ndarray) -> TexturedMesh:
        """A copy with new UVs, ``(V, 2)`` per vertex or ``(F, 3, 2)`` per face corner.

        A vertex whose corners get different UVs (a layout that cut a chart through it) is
        split: the corners of its first UV in sorted order keep it, each other UV gets a copy
        appended (position, normal, point and attributes copied). Faces keep their order and
        every corner its position, so the copy renders as the mesh does with those UVs; where
        no corners disagree it has the same vertices."""
        if np.shape(uvs) == self.uvs.shape:
            return replace(self, uvs=np.asarray(uvs, np.float32))
        corners = np.ascontiguousarray(self.corner_uvs(uvs).reshape(-1, 2))
        count = len(self.positions)
        keys = np.column_stack([self.faces.reshape(-1), corners.view(np.int32)])
        unique, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        vertex = unique[:, 0]
        keeps = np.r_[True, vertex[1:] != vertex[:-1]]
        ids = np.where(keeps, vertex, count + np.cumsum(~keeps) - 1)
        source = np.concatenate([np.arange(count), vertex[~keeps]])
        new_uvs = self.uvs[source]
        new_uvs[ids] = corners[first]
        return replace(
            self,
            positions=self.positions[source],
            faces=ids[inverse.reshape(-1)].reshape(-1, 3),
            uvs=new_uvs,
            normals=self.normals[source],
            vertex_to_point=self.vertex_to_point[source],
            attributes={name: values[source] for name, values in self.attributes.items()},
        )

    def images(self) -> list[tuple[np.ndarray, list[tuple[int, str]]]]:
        """Every distinct texture array (base colours and maps, by identity) with the
        ``(material index, slot)`` pairs that show it.

        Ordered by first appearance: materials in order, each material's slots as
        :meth:`Material.textures` gives them (base colour first).
        """
        found: dict[int, tuple[np.ndarray, list[tuple[int, str]]]] = {}
        for index, material in enumerate(self.materials):
            for slot, pixels in material.textures().items():
                found.setdefault(id(pixels), (pixels, []))[1].append((index, slot))
        return list(found.values())

    def with_images(self, replacements: Mapping[int, np.ndarray]) -> TexturedMesh:
        """A copy where every texture array whose ``id()`` is a key of ``replacements`` is
        replaced by the value, base colours and maps alike, so that textures shared before
        stay shared. ``sources`` and everything else carry over (arrays by reference).

        Raises ``ValueError`` (:class:`TextureError`) for a replacement that is not a texture
        array (``C`` 3 or 4 for a base colour, 1 to 4 for another map).
        """
        materials = []
        for index, material in enumerate(self.materials):
            textures = {}
            for slot, pixels in material.textures().items():
                textures[slot] = new = replacements.get(id(pixels), pixels)
                if new is not pixels:
                    channels = (3, 4) if slot == BASE_COLOR else (1, 2, 3, 4)
                    check_texture(new, f"replacement of {slot} of material {index}", channels)
            base = textures.pop(BASE_COLOR, None)
            materials.append(replace(material, base_color_texture=base, maps=textures))
        return replace(self, materials=materials)

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
            for slot, pixels in material.maps.items():
                check_texture(pixels, f"{slot} of material {material.name!r}", (1, 2, 3, 4))
        for name, array in self.attributes.items():
            _check_attribute(name, array, count)


def _check_attribute(name: str, array: np.ndarray, count: int) -> None:
    """Raise ``ValueError`` unless ``array`` is a valid value of attribute ``name`` for
    ``count`` vertices (:data:`ATTRIBUTE_COLUMNS`; what glTF requires of its values)."""
    if name not in ATTRIBUTE_COLUMNS:
        raise ValueError(f"attribute {name!r} is not one of {', '.join(ATTRIBUTE_COLUMNS)}")
    shape = np.shape(array)
    if len(shape) != 2 or shape[0] != count or shape[1] not in ATTRIBUTE_COLUMNS[name]:
        columns = " or ".join(str(c) for c in ATTRIBUTE_COLUMNS[name])
        raise ValueError(f"attribute {name} has shape {shape}, expected ({count}, {columns})")
    values = np.asarray(array, dtype=np.float64)
    if not np.isfinite(values).all():
        raise ValueError(f"attribute {name} has NaN or infinite values")
    if name == "COLOR_0" and (values.min(initial=0) < 0 or values.max(initial=0) > 1):
        raise ValueError("attribute COLOR_0 has values outside [0, 1]")
    if name == "TANGENT" and not np.isin(values[:, 3], (-1.0, 1.0)).all():
        raise ValueError("attribute TANGENT has w components other than 1 and -1")


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


# ----------------------------------------------------------------------------- sanity and measures

MAX_COORDINATE = 1e15
"""Largest position coordinate accepted (file units): squared, it stays far inside float32."""
MIN_EXTENT = 1e-15
"""Smallest mesh accepted: the farthest vertex from the bounding-box centre, in file units.
Below it the protocol's normalisation (a float32 scale to the unit sphere) loses the shape."""
MAX_UV = 1e4
"""Largest UV magnitude accepted, in texture repeats: float32 UVs there are spaced about 0.001
apart (two texels of a 2048 map), and the level of detail of farther ones overflows."""
MIN_TEXTURED_AREA = 1e-6
"""Smallest total area of the textured faces, in the protocol's unit scene: about 0.07 pixel
squared in a 512 x 512 view at the validation distance, so nothing of the texture is seen."""


def check_geometry(mesh: TexturedMesh, what: str) -> None:
    """Raise ``GeoscalerError`` unless the mesh can be rendered and its texture seen.

    The one geometry check of the project, made where a mesh is loaded and where a job starts
    (a mesh made in code is not loaded): the vertices (:func:`check_vertices`) and the
    textured faces (:func:`check_visible`). ``what`` starts each message (the file's name).
    """
    check_vertices(mesh.positions, mesh.uvs, what)
    check_visible(mesh, what)


def check_vertices(positions: np.ndarray, uvs: np.ndarray, what: str) -> None:
    """Refuse (``GeoscalerError``) NaN or infinite positions or UVs, coordinates beyond
    :data:`MAX_COORDINATE`, a mesh smaller than :data:`MIN_EXTENT` and UVs beyond
    :data:`MAX_UV`. ``positions`` ``(V, 3)``, ``uvs`` ``(V, 2)``; ``what`` starts each message.
    """
    positions = np.asarray(positions, dtype=np.float64)
    uvs = np.asarray(uvs, dtype=np.float64)
    if not (np.isfinite(positions).all() and np.isfinite(uvs).all()):
        raise GeoscalerError(
            f"{what}: has NaN or infinite vertex positions or UVs; repair the mesh and re-export"
        )
    largest = float(np.abs(positions).max(initial=0.0))
    if largest > MAX_COORDINATE:
        raise GeoscalerError(
            f"{what}: has vertex coordinates up to {largest:.3g}, beyond what GeoScaler reads "
            f"({MAX_COORDINATE:.0e}); scale the mesh down or move it near the origin in your "
            "3D tool and re-export"
        )
    if len(positions):
        centre = (positions.min(axis=0) + positions.max(axis=0)) / 2
        extent = float(np.linalg.norm(positions - centre, axis=1).max())
        if extent < MIN_EXTENT:
            size = "all its vertices at one point" if extent == 0 else f"{extent:.3g} units across"
            raise GeoscalerError(
                f"{what}: is too small to render ({size}; at least {MIN_EXTENT:.0e} is needed); "
                "scale it up in your 3D tool and re-export"
            )
    farthest = float(np.abs(uvs).max(initial=0.0))
    if farthest > MAX_UV:
        raise GeoscalerError(
            f"{what}: has UVs up to {farthest:.3g} texture repeats from the origin; GeoScaler "
            f"reads UVs within +-{MAX_UV:,.0f} (float32 cannot address texels farther out). "
            "Move each UV chart by whole repeats towards [0, 1] and re-export"
        )


def check_visible(mesh: TexturedMesh, what: str) -> None:
    """Refuse (``GeoscalerError``) a mesh whose textured faces are all degenerate (zero area)
    or together smaller than :data:`MIN_TEXTURED_AREA` in the protocol's unit scene.
    Its vertices must have passed :func:`check_vertices`."""
    textured = [i for i, m in enumerate(mesh.materials) if m.base_color_texture is not None]
    faces = mesh.faces[np.isin(mesh.face_material, textured)]
    corners = mesh.normalized_positions().astype(np.float64)[faces]
    doubled = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = float(np.linalg.norm(doubled, axis=1).sum() / 2)
    if area <= 0:
        raise GeoscalerError(
            f"{what}: all {len(faces):,} textured triangles are degenerate (their corners "
            "coincide or lie on a line), so nothing textured can be seen; repair the mesh"
        )
    if area < MIN_TEXTURED_AREA:
        raise GeoscalerError(
            f"{what}: its textured triangles are too small to be seen in any view (together "
            f"{area:.2g} of the unit sphere the mesh is scaled to); repair the mesh"
        )
