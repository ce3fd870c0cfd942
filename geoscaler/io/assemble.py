"""Joining the parts of a loaded scene into one welded :class:`~geoscaler.mesh.TexturedMesh`.

The format readers (:mod:`geoscaler.io.obj`, :mod:`geoscaler.io.gltf`) turn a file into placed
parts (:class:`Part`) and material builders; :func:`assemble` joins them, keeps the materials
the faces use, welds vertices that agree exactly on every attribute the output carries
(position, UV, normal, extra attributes) and points by exact position, and takes normals from
the file where it has them (computed over points elsewhere).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import (
    ATTRIBUTE_COLUMNS,
    Material,
    TexturedMesh,
    check_vertices,
    check_visible,
    compute_vertex_normals,
    first_occurrence_groups,
    normalize_rows,
)


class Part(NamedTuple):
    """One placed geometry of a loaded scene, in world space."""

    positions: np.ndarray  # (n, 3) float64
    faces: np.ndarray  # (m, 3) int64
    uvs: np.ndarray | None  # (n, 2) float64
    normals: np.ndarray | None  # (n, 3) float64, from the file
    material: int | None  # index into the loader's material list; None: no material
    attributes: dict[str, np.ndarray] | None = None  # TANGENT, COLOR_0, TEXCOORD_1 (glTF)


MaterialBuilder = Callable[[], Material]
"""Builds one material of the file; called only for materials that faces use."""


def assemble(
    path: Path, parts: list[Part], builders: list[MaterialBuilder], files: list[Path]
) -> TexturedMesh:
    """Join placed parts into one welded TexturedMesh with the materials the faces use.

    Parameters
    ----------
    path : Path
        The mesh file: ``source_path``, and the start of every message.
    parts : list of Part
        Placed geometries; ``Part.material`` indexes ``builders`` (None: no material).
    builders : list of MaterialBuilder
        The file's materials, in file order; only those the faces use are built.
    files : list of Path
        Every file read (``source_files``; duplicates are dropped).

    Raises
    ------
    GeoscalerError
        No triangles, no base-colour texture at all, textured faces without UVs; vertices or
        faces that :func:`geoscaler.mesh.check_vertices` and
        :func:`geoscaler.mesh.check_visible` refuse (NaN, absurd sizes or UVs, nothing
        textured to see).
    """
    if not parts:
        raise GeoscalerError(f"{path}: contains no triangles; GeoScaler needs a triangle mesh")
    used = sorted({p.material for p in parts if p.material is not None})
    slot = {m: i for i, m in enumerate(used)}
    materials = [builders[m]() for m in used]
    if any(p.material is None for p in parts):
        slot[None] = len(materials)
        materials.append(Material("default", None))
    _check_textures(path, parts, materials, slot)
    parts = sorted(parts, key=lambda p: slot[p.material])
    positions, uvs, normals, faces, face_material = _concatenate(parts, slot)
    attributes = _attributes(path, parts)
    check_vertices(positions, uvs, str(path))
    normals = _unit_normals(normals)
    key = np.concatenate([positions, uvs, normals, *attributes.values()], axis=1)
    group, first = first_occurrence_groups(key)
    faces = group[faces]
    keep = np.zeros(len(first), dtype=bool)
    keep[faces] = True
    renumber = np.cumsum(keep) - 1
    faces, first = renumber[faces], first[keep]
    positions, uvs, normals = positions[first], uvs[first], normals[first]
    vertex_to_point, _ = first_occurrence_groups(positions)
    computed = compute_vertex_normals(positions, faces, vertex_to_point)
    has = normals[:, 0] != NO_NORMAL
    mesh = TexturedMesh(
        positions=positions,
        faces=faces.astype(np.int64),
        uvs=uvs,
        normals=np.where(has[:, None], normals, computed).astype(np.float32),
        vertex_to_point=vertex_to_point,
        face_material=face_material,
        materials=materials,
        source_path=path,
        source_files=list(dict.fromkeys(files)),
        attributes={name: values[first] for name, values in attributes.items()},
    )
    check_visible(mesh, str(path))
    return mesh


def _check_textures(path: Path, parts: list[Part], materials: list[Material], slot) -> None:
    if all(m.base_color_texture is None for m in materials):
        raise GeoscalerError(
            f"{path}: none of its materials has a base-colour texture (map_Kd in the MTL, "
            "baseColorTexture in glTF), so there is nothing to downsample. Assign an image "
            "texture to the mesh's material and re-export."
        )
    for part in parts:
        material = materials[slot[part.material]]
        if part.uvs is None and material.base_color_texture is not None:
            raise GeoscalerError(
                f"{path}: faces with the textured material {material.name!r} have no texture "
                "coordinates (vt in OBJ, TEXCOORD_0 in glTF). UV-unwrap the mesh and re-export."
            )


def _concatenate(parts: list[Part], slot: dict) -> tuple[np.ndarray, ...]:
    """Stack parts: float32 positions/uvs, float64 normals (NaN where the file has none)."""
    offsets = np.cumsum([0] + [len(p.positions) for p in parts])
    positions = np.concatenate([p.positions for p in parts]).astype(np.float32)
    uvs = np.concatenate(
        [p.uvs if p.uvs is not None else np.zeros((len(p.positions), 2)) for p in parts]
    ).astype(np.float32)
    normals = np.concatenate(
        [p.normals if p.normals is not None else np.full((len(p.positions), 3), np.nan)
         for p in parts]
    )  # fmt: skip
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=False)])
    face_material = np.concatenate(
        [np.full(len(p.faces), slot[p.material], dtype=np.int64) for p in parts]
    )
    return positions, uvs, normals, faces, face_material


def _attributes(path: Path, parts: list[Part]) -> dict[str, np.ndarray]:
    """The extra attributes of the joined parts, ``(V, k)`` float32 each, in the order of
    :data:`geoscaler.mesh.ATTRIBUTE_COLUMNS`. A part without one that others have gets a
    neutral value: COLOR_0 white (RGB to RGBA: opaque), TEXCOORD_1 zero (that part's
    materials cannot use it); TANGENT is then dropped for all, with a warning (renderers
    compute tangents where a mesh has none)."""
    out = {}
    for name in ATTRIBUTE_COLUMNS:
        values = [(p.attributes or {}).get(name) for p in parts]
        if all(v is None for v in values):
            continue
        if name == "TANGENT" and any(v is None for v in values):
            warnings.warn(
                f"{path}: only some primitives have TANGENT; it is dropped (renderers compute "
                "tangents from the normal map's UVs where a mesh has none).",
                stacklevel=5,
            )
            continue
        width = max(v.shape[1] for v in values if v is not None)
        filled = []
        for part, v in zip(parts, values, strict=True):
            fill = 1.0 if name == "COLOR_0" else 0.0
            block = np.full((len(part.positions), width), fill)
            if v is not None:
                block[:, : v.shape[1]] = v
            filled.append(block)
        out[name] = np.concatenate(filled).astype(np.float32)
    return out


NO_NORMAL = np.float32(2.0)
"""What :func:`_unit_normals` writes for a vertex the file gives no usable normal: no unit
vector has it, so such vertices weld only with each other."""


def _unit_normals(normals: np.ndarray) -> np.ndarray:
    """``(N, 3)`` float32 unit file normals of ``(N, 3)`` float64 ``normals``; rows that are
    NaN (the file has none) or of zero length hold :data:`NO_NORMAL`."""
    return normalize_rows(normals, np.full(3, NO_NORMAL)).astype(np.float32)
