"""glTF 2.0: the glTF/GLB reader and the glTF (+ .bin + PNG) / GLB writer.

Reading: the JSON is checked here (version, required extensions, external files resolved
inside the mesh's folder, base-colour texture coordinates) and each material's JSON is kept,
texture indices replaced by samplers, so that saving writes it back; trimesh reads geometry
and images. glTF UVs have ``v = 0`` at the top of the image: trimesh flips them into the
OpenGL convention on reading, the writer flips them back. Writing: one mesh with one primitive
per material, sharing the vertex accessors; images as PNG files (glTF) or in the binary chunk
(GLB). glTF's numeric enums have names here (:data:`FLOAT`, :data:`ARRAY_BUFFER`...).
"""

from __future__ import annotations

import copy
import io
import json
import struct
import urllib.parse
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import Material, TexturedMesh

from .assemble import MaterialBuilder, Part, scene_parts
from .gltf_check import buffer_data, check_data, check_structure
from .images import decode_texture
from .paths import FolderResolver, resolve_reference

if TYPE_CHECKING:
    from .save import ImageOut

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

TEXTURE_SLOTS = {
    "baseColorTexture": ("pbrMetallicRoughness", "baseColorTexture"),
    "metallicRoughnessTexture": ("pbrMetallicRoughness", "metallicRoughnessTexture"),
    "normalTexture": ("normalTexture",),
    "occlusionTexture": ("occlusionTexture",),
    "emissiveTexture": ("emissiveTexture",),
}
"""Texture slots of a glTF material: slot name (a trimesh ``PBRMaterial`` attribute too) ->
path of its texture-info object in the material JSON."""

# ----------------------------------------------------------------------------- reading


_GLTF_TAG = "geoscaler-material-"
# Required extensions this loader honours (KHR_texture_transform: refused on base colour).
_REQUIRED_OK = {
    "EXT_texture_webp",
    "KHR_texture_transform",
    "KHR_materials_unlit",
    "KHR_materials_emissive_strength",
    "KHR_materials_pbrSpecularGlossiness",
}


def load_gltf(path: Path) -> tuple[list[Part], list[MaterialBuilder], list[Path]]:
    """Read a glTF or GLB file, for :func:`geoscaler.io.assemble.assemble`.

    Returns
    -------
    parts : list of Part
        The placed geometries; ``Part.material`` indexes ``builders``.
    builders : list of MaterialBuilder
        One per glTF material, in file order.
    files : list of Path
        The file itself and the external buffers and images it references, resolved.
    """
    root = path.parent.resolve()
    data = path.read_bytes()
    binary = path.suffix.lower() == ".glb"
    doc, chunk = _split_glb(data, path) if binary else (_parse_json(data, path), None)
    check_structure(doc, path)
    files = [path.resolve(), *_check_gltf(doc, path, root)]
    check_data(doc, path, buffer_data(doc, path, root, chunk))
    tagged = copy.deepcopy(doc)
    for index, material in enumerate(tagged.get("materials", [])):
        material["name"] = f"{_GLTF_TAG}{index}"
    payload = _pack_glb(tagged, chunk) if binary else json.dumps(tagged).encode()
    with warnings.catch_warnings():  # image sizes are checked before decoding, in our words
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        scene = trimesh.load_scene(
            io.BytesIO(payload), file_type=path.suffix.lower()[1:],
            resolver=FolderResolver(path, root), process=False,
        )  # fmt: skip
    loaded: dict[int, Any] = {}

    def material_of(material: Any) -> int | None:
        name = getattr(material, "name", "") if material is not None else ""
        if not isinstance(name, str) or not name.startswith(_GLTF_TAG):
            return None
        loaded[int(name[len(_GLTF_TAG) :])] = material
        return int(name[len(_GLTF_TAG) :])

    parts = scene_parts(scene, material_of)
    builders = [
        lambda i=i: _gltf_material(path, doc, i, loaded[i])
        for i in range(len(doc.get("materials", [])))
    ]
    return parts, builders, files


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


def _pack_glb(doc: dict, chunk: bytes | None) -> bytes:
    """A GLB file from a JSON document and an optional BIN chunk."""
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text
    if chunk is not None:
        chunk = chunk + b"\x00" * (-len(chunk) % 4)
        body += struct.pack("<I4s", len(chunk), b"BIN\x00") + chunk
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def _check_gltf(doc: dict, path: Path, root: Path) -> list[Path]:
    """Check version, required extensions and external files; return the files referenced."""
    version = str(doc.get("asset", {}).get("version", ""))
    if not version.startswith("2"):
        raise GeoscalerError(
            f"{path}: glTF version {version or '(missing)'}; only glTF 2.0 is supported. "
            "Re-export it as glTF 2.0."
        )
    unknown = sorted(set(doc.get("extensionsRequired", [])) - _REQUIRED_OK)
    if unknown:
        raise GeoscalerError(
            f"{path}: requires glTF extension(s) {', '.join(unknown)}, which GeoScaler cannot "
            "read (compressed geometry or textures). Re-export it without compression."
        )
    files = []
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
    return files


def _is_external(item: dict) -> bool:
    uri = item.get("uri")
    return isinstance(uri, str) and not uri.startswith("data:")


def _unquote(uri: str) -> str:
    return urllib.parse.unquote(uri)


def _texture_image_index(doc: dict, texture_index: int) -> int | None:
    """The image a glTF texture shows (its source, or an extension's source)."""
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
        info = material.get("pbrMetallicRoughness", {}).get("baseColorTexture")
        if isinstance(info, dict) and "index" in info:
            images.add(_texture_image_index(doc, info["index"]))
    return images


def _image_label(doc: dict, texture_index: int, path: Path) -> str:
    image_index = _texture_image_index(doc, texture_index)
    image = doc.get("images", [])[image_index] if image_index is not None else {}
    if _is_external(image):
        return repr(_unquote(image["uri"]))
    return f"image #{image_index} embedded in {path.name}"


def _gltf_material(path: Path, doc: dict, index: int, pbr: Any) -> Material:
    """Build a Material from the glTF JSON (exact factor, checks) and trimesh's images."""
    raw = doc["materials"][index]
    name = raw.get("name") or f"material_{index}"
    pbr_json = raw.get("pbrMetallicRoughness", {})
    info = pbr_json.get("baseColorTexture")
    if isinstance(info, dict):
        _check_base_color_info(info, path, name)
    texture = None
    if pbr.baseColorTexture is not None:
        label = _image_label(doc, info["index"], path) if isinstance(info, dict) else name
        texture = decode_texture(pbr.baseColorTexture, label, path)
    elif isinstance(info, dict):
        raise GeoscalerError(
            f"{path}: the base-colour image {_image_label(doc, info['index'], path)} of "
            f"material {name!r} could not be decoded. Re-save it as PNG or JPEG."
        )
    for slot, keys in TEXTURE_SLOTS.items():  # every map decodes, before any work starts
        image = getattr(pbr, slot, None) if slot != "baseColorTexture" else None
        if image is not None:
            map_info = _get_path(raw, keys)
            index = map_info.get("index") if isinstance(map_info, dict) else None
            label = _image_label(doc, index, path) if index is not None else f"{slot} of {name}"
            decode_texture(image, label, path)
    if "baseColorFactor" in pbr_json:
        factor = np.asarray(pbr_json["baseColorFactor"], dtype=np.float32)
    elif pbr.baseColorFactor is not None:
        factor = (np.asarray(pbr.baseColorFactor, dtype=np.float32) / 255).reshape(4)
    else:
        factor = np.ones(4, dtype=np.float32)
    pbr.name, pbr.baseColorTexture = name, None
    return Material(name, texture, factor, pbr, _gltf_properties(doc, raw, path))


def _check_base_color_info(info: dict, path: Path, name: str) -> None:
    if info.get("texCoord", 0) != 0:
        raise GeoscalerError(
            f"{path}: material {name!r} maps its base colour with TEXCOORD_{info['texCoord']}; "
            "GeoScaler supports TEXCOORD_0 only. Re-export with one UV set."
        )
    if "KHR_texture_transform" in info.get("extensions", {}):
        raise GeoscalerError(
            f"{path}: material {name!r} transforms its base-colour UVs "
            "(KHR_texture_transform), which GeoScaler does not support. Apply the transform "
            "to the UVs in your 3D tool and re-export."
        )


def _gltf_properties(doc: dict, raw: dict, path: Path) -> dict[str, Any]:
    """The material JSON with each texture index replaced by that texture's sampler."""
    properties = copy.deepcopy(raw)
    properties.pop("name", None)
    for keys in TEXTURE_SLOTS.values():
        info = _get_path(properties, keys)
        if isinstance(info, dict) and "index" in info:
            texture = doc.get("textures", [])[info.pop("index")]
            if "sampler" in texture:
                info["sampler"] = copy.deepcopy(doc["samplers"][texture["sampler"]])
    extensions = properties.get("extensions", {})
    for key in [k for k, v in extensions.items() if _has_texture_reference(v)]:
        warnings.warn(
            f"{path}: material extension {key} refers to textures GeoScaler does not carry; "
            "it is left out of saved files.",
            stacklevel=6,
        )
        del extensions[key]
    return properties


def _get_path(tree: dict, keys: tuple[str, ...]) -> Any:
    for key in keys:
        if not isinstance(tree, dict):
            return None
        tree = tree.get(key)
    return tree


def _has_texture_reference(value: Any) -> bool:
    if isinstance(value, dict):
        return "index" in value or any(_has_texture_reference(v) for v in value.values())
    if isinstance(value, list):
        return any(_has_texture_reference(v) for v in value)
    return False


# ----------------------------------------------------------------------------- writing


class _BinaryBuffer:
    """Accumulates buffer views and accessors of one glTF buffer."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, blob: bytes, target: int | None = None) -> int:
        """Add ``blob`` as a 4-byte aligned buffer view; return its index."""
        self.data += b"\x00" * (-len(self.data) % 4)
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(blob)}
        if target is not None:
            view["target"] = target
        self.data += blob
        self.views.append(view)
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, bounds: bool = False) -> int:
        """Add ``array`` ``(N, K)`` float32 or ``(N,)`` uint32 as an accessor of type ``kind``
        (``"VEC3"``, ``"SCALAR"``...) in a view for ``target``; return the accessor index."""
        component = UNSIGNED_INT if array.dtype == np.uint32 else FLOAT
        accessor = {
            "bufferView": self.view(np.ascontiguousarray(array).tobytes(), target),
            "componentType": component,
            "count": len(array),
            "type": kind,
        }
        if bounds:
            accessor["min"] = array.min(axis=0).tolist()
            accessor["max"] = array.max(axis=0).tolist()
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def gltf_files(
    mesh: TexturedMesh, used: list[int], images: list[ImageOut], slots: dict, path: Path
) -> dict[str, bytes]:
    """The files of ``mesh`` saved as ``path``: PNG maps, the .bin and the .gltf last, or the
    .glb alone (images in its binary chunk).

    ``used`` are the materials that faces use, ``images`` the maps to write and ``slots``
    which image each ``(material, slot)`` shows (see :mod:`geoscaler.io.save`).
    """
    binary = path.suffix.lower() == ".glb"
    buffer = _BinaryBuffer()
    positions = mesh.positions.astype(np.float32)
    attributes = {
        "POSITION": buffer.accessor(positions, "VEC3", ARRAY_BUFFER, bounds=True),
        "NORMAL": buffer.accessor(mesh.normals.astype(np.float32), "VEC3", ARRAY_BUFFER),
        "TEXCOORD_0": buffer.accessor(_gltf_uvs(mesh.uvs), "VEC2", ARRAY_BUFFER),
    }
    primitives = []  # mode left out: TRIANGLES
    for k, m in enumerate(used):
        indices = mesh.faces[mesh.face_material == m].astype(np.uint32).ravel()
        accessor = buffer.accessor(indices, "SCALAR", ELEMENT_ARRAY_BUFFER)
        primitives.append({"attributes": attributes, "indices": accessor, "material": k})
    files: dict[str, bytes] = {}
    image_json = []
    for image in images:
        png = image.png(path.suffix.lower())
        if binary:
            image_json.append({"bufferView": buffer.view(png), "mimeType": "image/png"})
        else:
            files[image.name] = png
            image_json.append({"uri": urllib.parse.quote(image.name), "mimeType": "image/png"})
    doc = _gltf_document(mesh, used, slots, primitives, image_json, path.stem)
    doc["accessors"], doc["bufferViews"] = buffer.accessors, buffer.views
    doc["buffers"] = [{"byteLength": len(buffer.data)}]
    if binary:
        files[path.name] = _pack_glb(doc, bytes(buffer.data))
        return files
    doc["buffers"][0]["uri"] = urllib.parse.quote(path.stem + ".bin")
    files[path.stem + ".bin"] = bytes(buffer.data)
    files[path.name] = json.dumps(doc, indent=1).encode()
    return files


def _gltf_uvs(uvs: np.ndarray) -> np.ndarray:
    """OpenGL UVs to glTF's (v down from the top of the image), ``(V, 2)`` float32."""
    out = np.asarray(uvs, dtype=np.float32).copy()
    out[:, 1] = 1.0 - out[:, 1]
    return out


def _gltf_document(
    mesh: TexturedMesh, used: list[int], slots: dict, primitives: list, images: list, stem: str
) -> dict:
    textures: list[dict] = []
    samplers: list[dict] = []
    materials = []
    for m in used:
        material = _gltf_material_json(mesh.materials[m], m, slots, textures, samplers)
        materials.append(material)
    doc: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "GeoScaler"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": stem}],
        "meshes": [{"name": stem, "primitives": primitives}],
        "materials": materials,
    }
    for key, value in (("textures", textures), ("samplers", samplers), ("images", images)):
        if value:
            doc[key] = value
    used_extensions = sorted(_extension_names(materials))
    if used_extensions:
        doc["extensionsUsed"] = used_extensions
    return doc


def _gltf_material_json(
    material: Material, m: int, slots: dict, textures: list, samplers: list
) -> dict:
    """The material's saved properties with texture slots pointing at the written images."""
    out = copy.deepcopy(material.properties)
    out["name"] = material.name
    pbr = out.setdefault("pbrMetallicRoughness", {})
    pbr["baseColorFactor"] = [float(x) for x in material.base_color_factor]
    for slot, keys in TEXTURE_SLOTS.items():
        parent = out if len(keys) == 1 else out.setdefault(keys[0], {})
        info = parent.pop(keys[-1], None)
        if (m, slot) not in slots:
            continue
        info = dict(info) if isinstance(info, dict) else {}
        sampler = info.pop("sampler", None)
        texture = {"source": slots[(m, slot)]}
        if sampler is not None:
            if sampler not in samplers:
                samplers.append(sampler)
            texture["sampler"] = samplers.index(sampler)
        if texture not in textures:
            textures.append(texture)
        info["index"] = textures.index(texture)
        parent[keys[-1]] = info
    return out


def _extension_names(value: Any) -> set[str]:
    """Names of every ``extensions`` entry inside a JSON value."""
    names: set[str] = set()
    if isinstance(value, dict):
        if isinstance(value.get("extensions"), dict):
            names.update(value["extensions"])
        for item in value.values():
            names |= _extension_names(item)
    elif isinstance(value, list):
        for item in value:
            names |= _extension_names(item)
    return names
