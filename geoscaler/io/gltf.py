"""glTF 2.0: the glTF/GLB reader (the writer is :mod:`geoscaler.io.gltf_write`).

Reading: the JSON is checked (:mod:`geoscaler.io.gltf_check`: the specification; here: version,
required extensions, external files resolved inside the mesh's folder, base-colour texture
coordinates; :func:`geoscaler.io.gltf_scene.check_kept`: nothing that would be dropped), the
geometry is read from the accessors (:mod:`geoscaler.io.gltf_scene`) and every image a used
material shows is decoded once, however many textures, materials or image entries (same URI,
same buffer view) show it. Each material's JSON is kept with texture indices replaced by the
textures' samplers, so that saving writes it back. glTF UVs have ``v = 0`` at the top of the
image; they are flipped into the OpenGL convention here and back by the writer. glTF's numeric
enums have names here (:data:`FLOAT`, :data:`ARRAY_BUFFER`...).
"""

from __future__ import annotations

import copy
import json
import struct
import urllib.parse
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import BASE_COLOR, Material, SourceImage

from .assemble import MaterialBuilder, Part
from .gltf_check import buffer_data, check_data, check_structure, data_uri_bytes
from .gltf_scene import check_kept, gltf_parts
from .images import open_embedded, source_image
from .paths import resolve_reference
from .slots import SPECULAR_GLOSSINESS, slot_path, texture_infos
from .texture_transform import EXTENSION, apply, base_color_matrix, texture_coordinate_set

# glTF enums (the OpenGL constants the glTF 2.0 specification uses).
UNSIGNED_BYTE = 5121
"""Accessor ``componentType``: 8-bit unsigned integers."""
UNSIGNED_SHORT = 5123
"""Accessor ``componentType``: 16-bit unsigned integers."""
UNSIGNED_INT = 5125
"""Accessor ``componentType``: 32-bit unsigned integers (the indices GeoScaler writes)."""
FLOAT = 5126
"""Accessor ``componentType``: 32-bit floats (the vertex attributes GeoScaler writes)."""
ARRAY_BUFFER = 34962
"""Buffer view ``target`` of vertex attributes."""
ELEMENT_ARRAY_BUFFER = 34963
"""Buffer view ``target`` of vertex indices."""
TRIANGLES = 4
"""Primitive ``mode`` of triangle lists: the default, so the writer leaves ``mode`` out."""

# ----------------------------------------------------------------------------- reading

# Required extensions this loader honours (KHR_texture_transform: io/texture_transform.py).
_REQUIRED_OK = {
    "EXT_texture_webp",
    "KHR_texture_transform",
    "KHR_materials_unlit",
    "KHR_materials_emissive_strength",
    SPECULAR_GLOSSINESS,
}


def load_gltf(path: Path) -> tuple[list[Part], list[MaterialBuilder], list[Path]]:
    """Read a glTF or GLB file, for :func:`geoscaler.io.assemble.assemble`.

    Returns
    -------
    parts : list of Part
        The placed geometries; ``Part.material`` indexes ``builders``.
    builders : list of MaterialBuilder
        One per glTF material, in file order; they share one image cache.
    files : list of Path
        The file itself and the external buffers and images it references, resolved.
    """
    root = path.parent.resolve()
    data = path.read_bytes()
    binary = path.suffix.lower() == ".glb"
    doc, chunk = _split_glb(data, path) if binary else (_parse_json(data, path), None)
    check_structure(doc, path)
    files, missing = _check_gltf(doc, path, root)
    check_kept(doc, path)
    buffers = buffer_data(doc, path, root, chunk)
    check_data(doc, path, buffers)
    parts = _fold_base_color_transforms(doc, gltf_parts(doc, buffers, path), path)
    images = _Images(doc, buffers, path, root, missing)
    builders = [
        lambda i=i: _gltf_material(path, doc, i, images)
        for i in range(len(doc.get("materials", [])))
    ]
    return parts, builders, [path.resolve(), *files]


def _parse_json(data: bytes, path: Path) -> dict:
    def refuse_constant(name: str) -> None:
        raise ValueError(f"{name} is not a JSON number")

    try:
        doc = json.loads(data, parse_constant=refuse_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        raise GeoscalerError(
            f"{path}: not valid glTF JSON ({exc}). The file may be corrupt or truncated: "
            "re-export it from your 3D tool."
        ) from exc
    if not isinstance(doc, dict):
        raise GeoscalerError(f"{path}: not a glTF document (the JSON is not an object)")
    return doc


def _split_glb(data: bytes, path: Path) -> tuple[dict, bytes | None]:
    """The JSON document and the BIN chunk of a GLB file."""
    if len(data) < 20 or data[:4] != b"glTF":
        raise GeoscalerError(
            f"{path}: not a GLB file (no 'glTF' header). It may be corrupt, or a glTF JSON "
            "file: then name it .gltf."
        )
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise GeoscalerError(f"{path}: GLB version {version}; only glTF 2.0 is supported")
    if length != len(data):
        raise GeoscalerError(
            f"{path}: its GLB header gives a length of {length} bytes, the file has "
            f"{len(data)}: it is truncated or corrupt; re-export or re-download it"
        )
    doc, chunk, offset = None, None, 12
    while offset + 8 <= len(data):
        size, kind = struct.unpack_from("<I4s", data, offset)
        body = data[offset + 8 : offset + 8 + size]
        if len(body) < size:
            raise GeoscalerError(f"{path}: truncated GLB file; re-export or re-download it")
        if offset == 12 and kind != b"JSON":
            raise GeoscalerError(f"{path}: GLB file whose first chunk is not JSON; it is corrupt")
        if kind == b"JSON" and doc is None:
            doc = _parse_json(body, path)
        elif kind == b"BIN\x00" and chunk is None:
            chunk = body
        offset += 8 + size
    if doc is None:
        raise GeoscalerError(f"{path}: GLB file without a JSON chunk; it is corrupt")
    return doc, chunk


def pack_glb(doc: dict, chunk: bytes | None) -> bytes:
    """A GLB file from a JSON document and an optional BIN chunk."""
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text
    if chunk is not None:
        chunk = chunk + b"\x00" * (-len(chunk) % 4)
        body += struct.pack("<I4s", len(chunk), b"BIN\x00") + chunk
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def _check_gltf(doc: dict, path: Path, root: Path) -> tuple[list[Path], set[int]]:
    """Check version, required extensions and external files; return the files referenced
    and the images that are missing (a missing base-colour image is refused)."""
    version = str(doc.get("asset", {}).get("version", ""))
    if not version.startswith("2"):
        raise GeoscalerError(
            f"{path}: glTF version {version or '(missing)'}; only glTF 2.0 is supported. "
            "Re-export it as glTF 2.0."
        )
    required = doc.get("extensionsRequired", [])
    unknown = sorted(e for e in required if e not in _REQUIRED_OK and "_materials_" not in e)
    if unknown:
        raise GeoscalerError(
            f"{path}: requires glTF extension(s) {', '.join(unknown)}, which GeoScaler cannot "
            "read (compressed geometry or textures). Re-export it without compression."
        )
    files, missing = [], set()
    for index, buffer in enumerate(doc.get("buffers", [])):
        if _is_external(buffer):
            what = f"buffer #{index}"
            files.append(resolve_reference(_unquote(buffer["uri"]), path.parent, root, path, what))
    base_images = _base_color_images(doc)
    for index, image in enumerate(doc.get("images", [])):
        if not _is_external(image):
            continue
        try:
            ref = _unquote(image["uri"])
            files.append(resolve_reference(ref, path.parent, root, path, f"image #{index}"))
        except GeoscalerError as exc:
            if index in base_images:
                raise
            warnings.warn(f"{exc} The map is skipped.", stacklevel=5)
            missing.add(index)
    return files, missing


def _is_external(item: dict) -> bool:
    uri = item.get("uri")
    return isinstance(uri, str) and not uri.startswith("data:")


def _unquote(uri: str) -> str:
    return urllib.parse.unquote(uri)


def _texture_image_index(doc: dict, texture_index: int) -> int | None:
    """The image a glTF texture shows (its WebP source, its source, or an extension's)."""
    texture = doc.get("textures", [])[texture_index]
    extensions = texture.get("extensions", {})
    if "source" in extensions.get("EXT_texture_webp", {}):
        return extensions["EXT_texture_webp"]["source"]
    if "source" in texture:
        return texture["source"]
    sources = [e["source"] for e in extensions.values() if isinstance(e, dict) and "source" in e]
    return sources[0] if sources else None


def _base_color_images(doc: dict) -> set[int]:
    images = set()
    for material in doc.get("materials", []):
        for slot, parent, key in texture_infos(material):
            if slot in (BASE_COLOR, f"{SPECULAR_GLOSSINESS}/diffuseTexture"):
                images.add(_texture_image_index(doc, parent[key]["index"]))
    return images


def _image_label(doc: dict, image_index: int | None, path: Path) -> str:
    image = doc.get("images", [])[image_index] if image_index is not None else {}
    if _is_external(image):
        return repr(_unquote(image["uri"]))
    return f"image #{image_index} embedded in {path.name}"


class _Images:
    """Decodes each image of a glTF file once: image entries with the same resolved URI, the
    same buffer view or the same data URI share one :class:`~geoscaler.mesh.SourceImage`."""

    def __init__(
        self, doc: dict, buffers: list[bytes], path: Path, root: Path, missing: set[int]
    ) -> None:
        self.doc, self.buffers, self.path, self.root = doc, buffers, path, root
        self.missing = missing
        self.decoded: dict[Any, SourceImage] = {}

    def get(self, index: int | None) -> SourceImage | None:
        """The image of ``doc["images"][index]``; None for no image or a missing file."""
        if index is None or index in self.missing:
            return None
        image, path = self.doc["images"][index], self.path
        name = image.get("name") if isinstance(image.get("name"), str) else f"image{index}"
        if "bufferView" in image:
            view = self.doc["bufferViews"][image["bufferView"]]
            start = view.get("byteOffset", 0)
            data = self.buffers[view["buffer"]][start : start + view["byteLength"]]
            key: Any = ("view", image["bufferView"])
        elif image["uri"].startswith("data:"):
            data = data_uri_bytes(image["uri"], path, f"images[{index}].uri")
            key = ("data", data)
        else:
            ref = _unquote(image["uri"])
            file = resolve_reference(ref, path.parent, self.root, path, f"image #{index}")
            key, name = ("file", file), Path(ref).name
            if key not in self.decoded:
                data = file.read_bytes()
        if key not in self.decoded:
            label = _image_label(self.doc, index, path)
            opened = open_embedded(data, label, path)
            self.decoded[key] = source_image(opened, data, label, path, name)
        return self.decoded[key]


def _gltf_material(path: Path, doc: dict, index: int, images: _Images) -> Material:
    """Build a Material from the glTF JSON: every texture slot's image decoded (shared with
    every other slot and material that shows it), exact factors, the JSON kept."""
    raw = doc["materials"][index]
    name = raw.get("name") or f"material_{index}"
    properties = _gltf_properties(doc, raw, path)
    textures: dict[str, np.ndarray] = {}
    sources: dict[str, SourceImage] = {}
    for slot, parent, key in texture_infos(raw):
        info = parent[key]
        image_index = _texture_image_index(doc, info["index"])
        is_base = slot == BASE_COLOR or (
            slot == f"{SPECULAR_GLOSSINESS}/diffuseTexture" and BASE_COLOR not in textures
        )
        if is_base:
            _check_base_color_info(info, path, name, transformable=slot == BASE_COLOR)
        image = images.get(image_index)
        if image is None:
            if is_base and image_index not in images.missing:
                raise GeoscalerError(
                    f"{path}: the base-colour texture of material {name!r} shows no image. "
                    "Assign an image to it and re-export."
                )
            _remove_info(properties, slot)
            continue
        textures[slot], sources[slot] = image.pixels, image
    base = textures.pop(BASE_COLOR, None)
    pbr_json = raw.get("pbrMetallicRoughness", {})
    factor = pbr_json.get("baseColorFactor")
    gloss = f"{SPECULAR_GLOSSINESS}/diffuseTexture"
    if base is None and gloss in textures:  # the archived workflow's diffuse map
        base, sources[BASE_COLOR] = textures[gloss], sources[gloss]
        if factor is None:
            factor = raw["extensions"][SPECULAR_GLOSSINESS].get("diffuseFactor")
    factor = np.ones(4, np.float32) if factor is None else np.asarray(factor, np.float32)
    return Material(name, base, factor, properties, textures, sources)


def _check_base_color_info(info: dict, path: Path, name: str, transformable: bool) -> None:
    uv_set = texture_coordinate_set(info)
    if uv_set != 0:
        raise GeoscalerError(
            f"{path}: material {name!r} maps its base colour with TEXCOORD_{uv_set}; "
            "GeoScaler supports TEXCOORD_0 only. Re-export with one UV set."
        )
    if not transformable and EXTENSION in info.get("extensions", {}):
        raise GeoscalerError(
            f"{path}: material {name!r} transforms the UVs of its {SPECULAR_GLOSSINESS} diffuse "
            f"texture ({EXTENSION}), which GeoScaler reads on baseColorTexture only. Convert "
            "the material to metallic-roughness in your 3D tool and re-export."
        )


def _fold_base_color_transforms(doc: dict, parts: list[Part], path: Path) -> list[Part]:
    """Parts whose material transforms its base colour, with the transform applied to their
    UVs (:mod:`geoscaler.io.texture_transform`)."""
    materials = doc.get("materials", [])
    folded = []
    for part in parts:
        matrix = None
        if part.material is not None and part.uvs is not None:
            raw = materials[part.material]
            name = raw.get("name") or f"material_{part.material}"
            matrix = base_color_matrix(raw, f"{path}: material {name!r}")
        folded.append(part if matrix is None else part._replace(uvs=apply(matrix, part.uvs)))
    return folded


def _gltf_properties(doc: dict, raw: dict, path: Path) -> dict[str, Any]:
    """The material JSON with each texture index replaced by that texture's sampler. An
    extension that refers to textures elsewhere than in its ``...Texture`` fields is left
    out, with a warning."""
    properties = copy.deepcopy(raw)
    properties.pop("name", None)
    for _, parent, key in list(texture_infos(properties)):
        texture = doc.get("textures", [])[parent[key].pop("index")]
        if "sampler" in texture:
            parent[key]["sampler"] = copy.deepcopy(doc["samplers"][texture["sampler"]])
    extensions = properties.get("extensions", {})
    for key in [k for k, v in extensions.items() if _has_texture_reference(v)]:
        warnings.warn(
            f"{path}: material extension {key} refers to textures in a way GeoScaler does "
            "not read; it is left out of saved files.",
            stacklevel=6,
        )
        del extensions[key]
    return properties


def _remove_info(properties: dict, slot: str) -> None:
    """Drop a slot's texture-info object (its image is missing)."""
    *parents, key = slot_path(slot)
    tree = properties
    for name in parents:
        tree = tree.get(name, {})
    tree.pop(key, None)


def _has_texture_reference(value: Any) -> bool:
    if isinstance(value, dict):
        return "index" in value or any(_has_texture_reference(v) for v in value.values())
    if isinstance(value, list):
        return any(_has_texture_reference(v) for v in value)
    return False
