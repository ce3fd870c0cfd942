"""Saving a mesh: which files a save writes, checking them, and writing them atomically.

:func:`output_files`, :func:`save_mesh` and :func:`written_image` share one plan
(:func:`_plan_images`): the textures each used material shows that the format can hold, one
image per distinct array (by identity), its file name and its type. Images are encoded by
:func:`geoscaler.io.images.encoded_image` (the input's bytes where a texture is unchanged);
the format modules turn the plan into file contents (:func:`geoscaler.io.obj.obj_files`,
:func:`geoscaler.io.gltf_write.gltf_files`).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import BASE_COLOR, Material, SourceImage, TexturedMesh, bake_color_factor

from .atomic import write_files
from .gltf_write import gltf_files
from .images import FILE_SUFFIXES, encoded_image, written_mime
from .obj import obj_files
from .paths import check_outputs, check_suffix, side_file
from .slots import in_gltf, in_mtl, slot_file_name


class ImageOut(NamedTuple):
    """One image file (or GLB image) to write, shared by the slots that show it."""

    name: str  # file name (a .gltf's or an .obj's image file; unused in a .glb)
    pixels: np.ndarray  # as written (an OBJ base colour with its factor baked in)
    source: SourceImage | None  # where the texture came from
    image_format: str | None  # what encoded_image is asked for
    texture: np.ndarray  # the mesh's array (``pixels`` unless baked)

    def encoded(self) -> tuple[bytes, str]:
        """The image's bytes and MIME type, as :func:`encoded_image` makes them."""
        return encoded_image(self.pixels, self.source, self.image_format)


def save_mesh(
    mesh: TexturedMesh,
    path: str | Path,
    *,
    overwrite: bool = False,
    image_format: str | None = None,
) -> list[Path]:
    """Write ``mesh`` as ``.obj`` (+ MTL + images), ``.gltf`` (+ .bin + images) or ``.glb``.

    Every texture of every used material is written, each distinct array once (materials and
    slots that share it point at the same image), with every glTF material property and the
    extra vertex attributes; OBJ/MTL keeps base colour, normal, emissive and MTL's own maps
    and warns about the rest (glTF warns about MTL's own maps). A texture unchanged since
    loading is written as the input's bytes; another is encoded in its source's format, or
    in ``image_format`` (``"png"``, ``"jpeg"``, ``"webp"``) when given
    (:func:`geoscaler.io.images.encoded_image`). The base-colour factor is always written
    explicitly; for OBJ, where ``map_Kd`` is the colour, a factor other than 1 is baked into
    the texture. All files are first written into a temporary folder beside ``path`` and
    then renamed into place, the main file last.

    Returns
    -------
    list of Path
        The files written, the main file last: :func:`output_files`.

    Raises
    ------
    GeoscalerError
        Unsupported suffix; WebP asked for an OBJ; a file to write is one the mesh was read
        from (even with ``overwrite``); an output exists and ``overwrite`` is False; the
        folder is missing or not writable (:func:`geoscaler.io.paths.check_outputs`).
    """
    path = Path(path)
    suffix = check_suffix(path)
    mesh.validate()
    used = _used_materials(mesh)
    if not used:
        raise ValueError("the mesh has no faces; there is nothing to save")
    images, slots = _plan_images(mesh, used, path, image_format)
    check_outputs(_targets(path, suffix, images), force=overwrite, inputs=_inputs(mesh))
    encoded = [image.encoded() for image in images]
    writer = obj_files if suffix == ".obj" else gltf_files
    return write_files(path.parent, writer(mesh, used, images, encoded, slots, path))


def output_files(
    mesh: TexturedMesh, path: str | Path, *, image_format: str | None = None
) -> list[Path]:
    """Every file :func:`save_mesh` writes for ``mesh`` at ``path``, the main file last.

    OBJ comes with its image files and MTL library, glTF with its image files and .bin
    buffer; GLB is one file. Nothing is checked, encoded or written: pass the list to
    :func:`geoscaler.io.paths.check_outputs` to refuse bad outputs before long work.

    Raises
    ------
    GeoscalerError
        Unsupported suffix; WebP asked for an OBJ.
    """
    path = Path(path)
    suffix = check_suffix(path)
    with warnings.catch_warnings():  # save_mesh warns about maps the format cannot hold
        warnings.simplefilter("ignore")
        images, _ = _plan_images(mesh, _used_materials(mesh), path, image_format)
    return _targets(path, suffix, images)


def written_image(
    mesh: TexturedMesh, pixels: np.ndarray, path: str | Path, image_format: str | None = None
) -> tuple[int, str]:
    """``(bytes, MIME type)`` of the image :func:`save_mesh` writes (or wrote) for the texture
    array ``pixels`` of ``mesh`` at ``path``; ``(0, "")`` where that format does not write it.
    Encodings are memoised, so after a save this encodes nothing."""
    path = Path(path)
    check_suffix(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        images, _ = _plan_images(mesh, _used_materials(mesh), path, image_format)
    found = next((image for image in images if image.texture is pixels), None)
    if found is None:
        return 0, ""
    data, mime = found.encoded()
    return len(data), mime


def _used_materials(mesh: TexturedMesh) -> list[int]:
    return [m for m in range(len(mesh.materials)) if (mesh.face_material == m).any()]


def _inputs(mesh: TexturedMesh) -> list[Path]:
    """The files a save must never write over."""
    inputs = list(mesh.source_files)
    return inputs + ([Path(mesh.source_path)] if mesh.source_path is not None else [])


def _targets(path: Path, suffix: str, images: list[ImageOut]) -> list[Path]:
    names = [] if suffix == ".glb" else [image.name for image in images]
    names += [side_file(path, ".mtl").name] if suffix == ".obj" else []
    names += [side_file(path, ".bin").name] if suffix == ".gltf" else []
    return [path.parent / name for name in [*names, path.name]]


def _plan_images(
    mesh: TexturedMesh, used: list[int], path: Path, image_format: str | None
) -> tuple[list[ImageOut], dict[tuple[int, str], int]]:
    """Images to write and which image each (material, slot) shows; shared arrays once.

    File names: ``STEM_NAME.EXT`` with the source's name, ``STEM_M_SLOT.EXT`` for a texture
    made in code, made unique with ``_2``, ``_3``... ``EXT`` says the encoding. ``STEM`` is the
    output's (:func:`geoscaler.io.paths.side_file`) and ``NAME`` is made of the same safe
    characters (:func:`geoscaler.io.images.file_stem`), so URIs and MTL statements hold the
    names as they are.
    """
    suffix = path.suffix.lower()
    if suffix == ".obj" and image_format == "webp":
        raise GeoscalerError(
            f"{path}: OBJ/MTL readers do not read WebP images; save as .glb or .gltf for WebP "
            "(EXT_texture_webp), or choose png or jpeg for an OBJ"
        )
    images: list[ImageOut] = []
    by_identity: dict[tuple, int] = {}
    slots: dict[tuple[int, str], int] = {}
    names: set[str] = set()
    for m in used:
        material = mesh.materials[m]
        for slot, texture in _writable(material, suffix).items():
            factor = np.asarray(material.base_color_factor, dtype=np.float64)
            baked = slot == BASE_COLOR and suffix == ".obj" and not np.allclose(factor[:3], 1)
            key = (id(texture), tuple(factor[:3]) if baked else None)
            if key not in by_identity:
                pixels = (
                    bake_color_factor(texture, np.array([*factor[:3], 1.0])) if baked else texture
                )
                source = material.sources.get(slot)
                wanted = image_format
                if suffix == ".obj" and wanted is None and source and source.mime == "image/webp":
                    wanted = "png"  # OBJ readers do not read WebP
                mime = written_mime(pixels, source, wanted)
                stem = source.name if source is not None else f"{m}_{slot_file_name(slot)}"
                name = _unique(side_file(path, f"_{stem}").name, FILE_SUFFIXES[mime], names)
                by_identity[key] = len(images)
                images.append(ImageOut(name, pixels, source, wanted, texture))
            slots[(m, slot)] = by_identity[key]
    return images, slots


def _unique(stem: str, suffix: str, taken: set[str]) -> str:
    name, k = stem + suffix, 1
    while name.lower() in taken:
        k += 1
        name = f"{stem}_{k}{suffix}"
    taken.add(name.lower())
    return name


def _writable(material: Material, suffix: str) -> dict[str, np.ndarray]:
    """The textures of a material that the format can hold, by slot; warns about the rest."""
    fits = in_mtl if suffix == ".obj" else in_gltf
    out = {}
    for slot, pixels in material.textures().items():
        if fits(slot):
            out[slot] = pixels
            continue
        fix = "Save as .glb or .gltf" if suffix == ".obj" else "Save as .obj"
        what = "OBJ/MTL" if suffix == ".obj" else "glTF"
        warnings.warn(
            f"material {material.name!r}: {what} cannot express its {slot}; it is not "
            f"written. {fix} to keep it.",
            stacklevel=5,
        )
    return out
