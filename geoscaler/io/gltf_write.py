"""glTF 2.0 writing: one mesh, one primitive per material, every map and material property.

The primitives share the vertex accessors (POSITION, NORMAL, TEXCOORD_0 and the mesh's extra
attributes: TANGENT, COLOR_0, TEXCOORD_1, all float32); indices are 16-bit where the vertices
allow, else 32-bit. Each distinct image is written once, as a file
beside a .gltf or in the binary chunk of a .glb, and every slot of every material that shows
it points at it; texture-info fields (``texCoord``, ``scale``, ``KHR_texture_transform``...)
and samplers are written back, extension slots inside their extension objects. WebP images are
referenced through ``EXT_texture_webp`` (required; no fallback image).
"""

from __future__ import annotations

import copy
import json
import urllib.parse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from geoscaler.mesh import Material, TexturedMesh

from .gltf import (
    ARRAY_BUFFER,
    ELEMENT_ARRAY_BUFFER,
    FLOAT,
    UNSIGNED_INT,
    UNSIGNED_SHORT,
    pack_glb,
)
from .paths import side_file
from .slots import MTL_PROPERTIES, slot_path, texture_infos
from .texture_transform import unfolded

if TYPE_CHECKING:
    from .save import ImageOut

WEBP = "EXT_texture_webp"


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
        """Add ``array`` ``(N, K)`` float32 or ``(N,)`` uint16/uint32 as an accessor of type
        ``kind`` (``"VEC3"``, ``"SCALAR"``...) in a view for ``target``; return its index."""
        component = {np.dtype(np.uint16): UNSIGNED_SHORT, np.dtype(np.uint32): UNSIGNED_INT}
        component = component.get(array.dtype, FLOAT)
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
    mesh: TexturedMesh,
    used: list[int],
    images: list[ImageOut],
    encoded: list[tuple[bytes, str]],
    slots: dict[tuple[int, str], int],
    path: Path,
) -> dict[str, bytes]:
    """The files of ``mesh`` saved as ``path``: image files, the .bin and the .gltf last, or
    the .glb alone (images in its binary chunk).

    ``used`` are the materials that faces use, ``images`` the images to write with their
    ``encoded`` bytes and MIME types, and ``slots`` which image each ``(material, slot)``
    shows (see :mod:`geoscaler.io.save`).
    """
    binary = path.suffix.lower() == ".glb"
    mesh = unfolded(mesh)  # the UVs the file's KHR_texture_transform expects
    buffer = _BinaryBuffer()
    attributes = {
        "POSITION": buffer.accessor(mesh.positions.astype(np.float32), "VEC3", ARRAY_BUFFER, True),
        "NORMAL": buffer.accessor(mesh.normals.astype(np.float32), "VEC3", ARRAY_BUFFER),
        "TEXCOORD_0": buffer.accessor(_gltf_uvs(mesh.uvs), "VEC2", ARRAY_BUFFER),
    }
    for name, values in mesh.attributes.items():
        values = _gltf_uvs(values) if name.startswith("TEXCOORD") else values
        kind = f"VEC{values.shape[1]}"
        attributes[name] = buffer.accessor(values.astype(np.float32), kind, ARRAY_BUFFER)
    primitives = []  # mode left out: TRIANGLES
    index_type = np.uint16 if len(mesh.positions) < 65535 else np.uint32  # 65535: restart
    for k, m in enumerate(used):
        indices = mesh.faces[mesh.face_material == m].astype(index_type).ravel()
        accessor = buffer.accessor(indices, "SCALAR", ELEMENT_ARRAY_BUFFER)
        primitives.append({"attributes": attributes, "indices": accessor, "material": k})
    files: dict[str, bytes] = {}
    image_json = []
    for image, (data, mime) in zip(images, encoded, strict=True):
        entry: dict[str, Any] = {"mimeType": mime}
        if binary:
            entry["bufferView"] = buffer.view(data)
        else:
            files[image.name] = data
            entry["uri"] = urllib.parse.quote(image.name)
        if image.source is not None:
            entry["name"] = image.source.name
        image_json.append(entry)
    webp = [mime == "image/webp" for _, mime in encoded]
    doc = _gltf_document(mesh, used, slots, primitives, image_json, webp, path.stem)
    doc["accessors"], doc["bufferViews"] = buffer.accessors, buffer.views
    doc["buffers"] = [{"byteLength": len(buffer.data)}]
    if binary:
        files[path.name] = pack_glb(doc, bytes(buffer.data))
        return files
    bin_name = side_file(path, ".bin").name
    doc["buffers"][0]["uri"] = urllib.parse.quote(bin_name)  # safe: quoting changes nothing
    files[bin_name] = bytes(buffer.data)
    files[path.name] = json.dumps(doc, indent=1).encode()
    return files


def _gltf_uvs(uvs: np.ndarray) -> np.ndarray:
    """OpenGL UVs to glTF's (v down from the top of the image), ``(V, 2)`` float32."""
    out = np.asarray(uvs, dtype=np.float32).copy()
    out[:, 1] = 1.0 - out[:, 1]
    return out


def _gltf_document(
    mesh: TexturedMesh,
    used: list[int],
    slots: dict[tuple[int, str], int],
    primitives: list,
    images: list,
    webp: list[bool],
    stem: str,
) -> dict:
    textures: list[dict] = []
    samplers: list[dict] = []
    materials = []
    for m in used:
        material = mesh.materials[m]
        mine = {slot: image for (k, slot), image in slots.items() if k == m}
        materials.append(_material_json(material, mine, textures, samplers, webp))
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
    used_extensions = sorted(_extension_names(materials) | _extension_names(textures))
    if used_extensions:
        doc["extensionsUsed"] = used_extensions
    if any(webp):
        doc["extensionsRequired"] = [WEBP]
    return doc


def _material_json(
    material: Material, slots: dict[str, int], textures: list, samplers: list, webp: list[bool]
) -> dict:
    """The material's saved properties with every slot that has an image pointing at it
    (texture-info fields and sampler kept) and every other texture-info object removed."""
    out = copy.deepcopy(material.properties)
    out.pop(MTL_PROPERTIES, None)
    out["name"] = material.name
    pbr = out.setdefault("pbrMetallicRoughness", {})
    pbr["baseColorFactor"] = [float(x) for x in material.base_color_factor]
    infos = {slot: parent.pop(key) for slot, parent, key in list(texture_infos(out))}
    for slot, image in slots.items():
        info = dict(infos.get(slot, {}))
        sampler = info.pop("sampler", None)
        texture: dict[str, Any] = {"source": image}
        if webp[image]:
            texture = {"extensions": {WEBP: {"source": image}}}
        if sampler is not None:
            if sampler not in samplers:
                samplers.append(sampler)
            texture["sampler"] = samplers.index(sampler)
        if texture not in textures:
            textures.append(texture)
        info["index"] = textures.index(texture)
        *parents, key = slot_path(slot)
        tree = out
        for name in parents:
            tree = tree.setdefault(name, {})
        tree[key] = info
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
