"""Saving a mesh: which files a save writes, checking them, and writing them atomically.

:func:`output_files` and :func:`save_mesh` share one plan (:func:`_plan_images`): the maps each
used material shows, one PNG per distinct map. The format modules turn the plan into file
contents (:func:`geoscaler.io.obj.obj_files`, :func:`geoscaler.io.gltf.gltf_files`).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from geoscaler.mesh import Material, TexturedMesh, bake_color_factor

from .atomic import write_files
from .gltf import TEXTURE_SLOTS, gltf_files
from .images import image_to_texture, png_bytes
from .obj import MTL_SLOT_KEYWORDS, obj_files
from .paths import check_outputs, check_suffix


class ImageOut(NamedTuple):
    """One image file (or GLB image) to write, shared by the slots that show it."""

    name: str
    material: Material
    slot: str
    source: Any  # the texture array or the PIL image of the map

    def png(self, suffix: str) -> bytes:
        """The PNG file of this image as written for a mesh file of type ``suffix``."""
        return png_bytes(_map_pixels(self.material, self.slot, self.source, suffix))


_SLOT_FILE_NAMES = {
    "baseColorTexture": "basecolor",
    "metallicRoughnessTexture": "metallicroughness",
    "normalTexture": "normal",
    "occlusionTexture": "occlusion",
    "emissiveTexture": "emissive",
}


def save_mesh(mesh: TexturedMesh, path: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Write ``mesh`` as ``.obj`` (+ MTL + PNGs), ``.gltf`` (+ .bin + PNGs) or ``.glb``.

    Every map and glTF material property the mesh carries is written (OBJ/MTL keeps base
    colour, normal and emissive maps and warns about the rest). The base-colour factor is
    always written explicitly; for OBJ, where ``map_Kd`` is the colour, a factor other than 1
    is baked into the texture. All files are first written into a temporary folder beside
    ``path`` and then renamed into place, the main file last.

    Returns
    -------
    list of Path
        The files written, the main file last: :func:`output_files`.

    Raises
    ------
    GeoscalerError
        Unsupported suffix; a file to write is one the mesh was read from (even with
        ``overwrite``); an output exists and ``overwrite`` is False; the folder is missing or
        not writable (:func:`geoscaler.io.paths.check_outputs`).
    """
    path = Path(path)
    suffix = check_suffix(path)
    mesh.validate()
    used = _used_materials(mesh)
    if not used:
        raise ValueError("the mesh has no faces; there is nothing to save")
    images, slots = _plan_images(mesh, used, path.stem, suffix)
    check_outputs(_targets(path, suffix, images), force=overwrite, inputs=_inputs(mesh))
    if suffix == ".obj":
        files = obj_files(mesh, used, images, slots, path)
    else:
        files = gltf_files(mesh, used, images, slots, path)
    return write_files(path.parent, files)


def output_files(mesh: TexturedMesh, path: str | Path) -> list[Path]:
    """Every file :func:`save_mesh` writes for ``mesh`` at ``path``, the main file last.

    OBJ comes with its PNG maps and MTL library, glTF with its PNG maps and .bin buffer; GLB
    is one file. Nothing is checked or written: pass the list to
    :func:`geoscaler.io.paths.check_outputs` to refuse bad outputs before long work.

    Raises
    ------
    GeoscalerError
        Unsupported suffix.
    """
    path = Path(path)
    suffix = check_suffix(path)
    with warnings.catch_warnings():  # save_mesh warns about maps OBJ cannot hold
        warnings.simplefilter("ignore")
        images, _ = _plan_images(mesh, _used_materials(mesh), path.stem, suffix)
    return _targets(path, suffix, images)


def _used_materials(mesh: TexturedMesh) -> list[int]:
    return [m for m in range(len(mesh.materials)) if (mesh.face_material == m).any()]


def _inputs(mesh: TexturedMesh) -> list[Path]:
    """The files a save must never write over."""
    inputs = list(mesh.source_files)
    return inputs + ([Path(mesh.source_path)] if mesh.source_path is not None else [])


def _targets(path: Path, suffix: str, images: list[ImageOut]) -> list[Path]:
    names = [] if suffix == ".glb" else [image.name for image in images]
    names += [path.stem + ".mtl"] if suffix == ".obj" else []
    names += [path.stem + ".bin"] if suffix == ".gltf" else []
    return [path.parent / name for name in [*names, path.name]]


def _plan_images(
    mesh: TexturedMesh, used: list[int], stem: str, suffix: str
) -> tuple[list[ImageOut], dict[tuple[int, str], int]]:
    """Images to write and which image each (material, slot) shows; shared images once."""
    images: list[ImageOut] = []
    by_identity: dict[tuple, int] = {}
    slots: dict[tuple[int, str], int] = {}
    for m in used:
        material = mesh.materials[m]
        for slot, pixels_source in _material_maps(material, suffix).items():
            baked = slot == "baseColorTexture" and suffix == ".obj"
            key = (id(pixels_source), tuple(material.base_color_factor) if baked else None)
            if key not in by_identity:
                by_identity[key] = len(images)
                name = f"{stem}_{m}_{_SLOT_FILE_NAMES[slot]}.png"
                images.append(ImageOut(name, material, slot, pixels_source))
            slots[(m, slot)] = by_identity[key]
    return images, slots


def _material_maps(material: Material, suffix: str) -> dict[str, Any]:
    """The maps of a material that the format can hold: slot -> array or PIL image."""
    maps: dict[str, Any] = {}
    if material.base_color_texture is not None:
        maps["baseColorTexture"] = material.base_color_texture
    for slot in TEXTURE_SLOTS:
        image = getattr(material.source, slot, None) if slot != "baseColorTexture" else None
        if image is None:
            continue
        if suffix == ".obj" and slot not in MTL_SLOT_KEYWORDS:
            warnings.warn(
                f"material {material.name!r}: OBJ/MTL cannot express its {slot}; it is not "
                "written. Save as .glb or .gltf to keep it.",
                stacklevel=4,
            )
            continue
        maps[slot] = image
    return maps


def _map_pixels(material: Material, slot: str, source: Any, suffix: str) -> np.ndarray:
    """``(H, W, C)`` uint8 pixels to write for a map (OBJ base colour: factor baked in)."""
    if slot != "baseColorTexture":
        return image_to_texture(source)
    factor = np.asarray(material.base_color_factor, dtype=np.float64)
    if suffix == ".obj" and not np.allclose(factor[:3], 1.0):
        return bake_color_factor(source, np.array([*factor[:3], 1.0]))
    return source
