"""The glTF 2.0 document checked before anything is read from it.

trimesh reads what it is given and fills in what is missing: an index past the end of an
accessor lands in the next primitive, an accessor without data becomes zeros, a node that is its
own child recurses. Here the document is held to the specification first, one refusal per
mistake, each naming where in the file it is (``accessors[2]``, ``nodes[0].children``):

- :func:`check_structure`: every array is a list of objects, every index points at an existing
  item, the node graph is a forest (walked without recursion, so any depth is read) whose roots
  each scene lists once, transforms and material factors are finite numbers of the right count
  and range, enums are enums;
- :func:`check_data`: buffers hold the bytes they claim, buffer views fit their buffers,
  accessors their views (strides included), the attributes a primitive reads have data (not
  Draco- or meshopt-compressed, not sparse) of the right type and equal counts, and its indices
  point at its own vertices.
"""

from __future__ import annotations

import base64
import binascii
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from geoscaler.errors import GeoscalerError

from .paths import resolve_reference

COMPONENT_SIZES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
"""Accessor ``componentType`` -> bytes per component."""
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
"""Accessor ``type`` -> components per element."""
_ARRAYS = (
    "accessors", "animations", "buffers", "bufferViews", "cameras", "images", "materials",
    "meshes", "nodes", "samplers", "scenes", "skins", "textures",
)  # fmt: skip
_INDEX_TYPES = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32}
_ATTRIBUTE_FORMATS = {
    "POSITION": ({"VEC3"}, {5126}, "VEC3 of FLOAT"),
    "NORMAL": ({"VEC3"}, {5126, 5120, 5122}, "VEC3 of FLOAT or signed"),
    "TANGENT": ({"VEC4"}, {5126, 5120, 5122}, "VEC4 of FLOAT or signed"),
    "TEXCOORD_0": ({"VEC2"}, {5126, 5121, 5123}, "VEC2 of FLOAT or unsigned"),
    "TEXCOORD_1": ({"VEC2"}, {5126, 5121, 5123}, "VEC2 of FLOAT or unsigned"),
    "COLOR_0": ({"VEC3", "VEC4"}, {5126, 5121, 5123}, "VEC3 or VEC4 of FLOAT or unsigned"),
}
"""The attributes GeoScaler reads: accessor types, component types and how to say them."""
_FILTERS = {9728, 9729, 9984, 9985, 9986, 9987}
_WRAPS = {33071, 33648, 10497}
_ALPHA_MODES = {"OPAQUE", "MASK", "BLEND"}
_TEXTURE_INFOS = {
    ("pbrMetallicRoughness", "baseColorTexture"),
    ("pbrMetallicRoughness", "metallicRoughnessTexture"),
    ("normalTexture",),
    ("occlusionTexture",),
    ("emissiveTexture",),
}


def _refuse(path: Path, where: str, problem: str) -> GeoscalerError:
    return GeoscalerError(
        f"{path}: {where} {problem}; the file breaks the glTF 2.0 specification. Re-export it "
        "from your 3D tool (the Khronos glTF validator shows every such problem)."
    )


def _items(doc: dict, name: str) -> list:
    return doc.get(name, [])


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def check_structure(doc: dict, path: Path) -> None:
    """Hold the JSON document to the shape the glTF 2.0 schema gives it (see module doc)."""
    _check_arrays(doc, path)
    _check_extension_lists(doc, path)
    if not isinstance(doc.get("asset"), dict):
        raise _refuse(path, "'asset'", "is missing or not an object")
    ref = _Refs(doc, path)
    _check_scenes(doc, path, ref)
    _check_nodes(doc, path, ref)
    for name, check in _ITEM_CHECKS:  # the table is below the checks it names
        for i, item in enumerate(_items(doc, name)):
            check(item, path, f"{name}[{i}]", ref)


def _check_arrays(doc: dict, path: Path) -> None:
    """Every top-level array is a list of objects."""
    for name in _ARRAYS:
        value = doc.get(name, [])
        if not isinstance(value, list) or not all(isinstance(item, dict) for item in value):
            raise _refuse(path, f"'{name}'", "is not a list of objects")


def _check_extension_lists(doc: dict, path: Path) -> None:
    """``extensionsUsed`` and ``extensionsRequired`` are lists of names."""
    for name in ("extensionsUsed", "extensionsRequired"):
        value = doc.get(name, [])
        if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
            raise _refuse(path, f"'{name}'", "is not a list of extension names")


class _Refs:
    """Checks of single values, each refusing with the value's place in the document."""

    def __init__(self, doc: dict, path: Path):
        self.doc, self.path = doc, path

    def index(self, value: Any, array: str, where: str) -> int:
        count = len(_items(self.doc, array))
        if not _is_int(value) or not 0 <= value < count:
            raise _refuse(self.path, where, f"is {value!r}, not an index into '{array}' ({count})")
        return value

    def whole(self, value: Any, where: str, low: int = 0) -> int:
        if not _is_int(value) or value < low:
            raise _refuse(self.path, where, f"is {value!r}, not a whole number >= {low}")
        return value

    def numbers(self, value: Any, count: int, where: str, low=-math.inf, high=math.inf) -> None:
        ok = isinstance(value, list) and len(value) == count
        if not ok or not all(_is_number(x) and low <= x <= high for x in value):
            bounds = "" if low == -math.inf else f" between {low:g} and {high:g}"
            what = "a number" if count == 1 else f"{count} numbers"
            raise _refuse(self.path, where, f"is {value!r}, not {what}{bounds}")

    def enum(self, tree: dict, key: str, allowed: set, where: str) -> None:
        if key in tree and tree[key] not in allowed:
            raise _refuse(self.path, f"{where}.{key}", f"is {tree[key]!r}, not a valid value")


def _list(value: Any, path: Path, where: str) -> list:
    if not isinstance(value, list):
        raise _refuse(path, where, "is not a list")
    return value


def _dict(value: Any, path: Path, where: str) -> list[tuple[str, Any]]:
    if not isinstance(value, dict):
        raise _refuse(path, f"{where}.extensions", "is not an object")
    return list(value.items())


def _check_scenes(doc: dict, path: Path, ref: _Refs) -> None:
    """The default scene and the nodes each scene lists are indices of existing items."""
    if "scene" in doc:
        ref.index(doc["scene"], "scenes", "'scene'")
    for s, scene in enumerate(_items(doc, "scenes")):
        for node in _list(scene.get("nodes", []), path, f"scenes[{s}].nodes"):
            ref.index(node, "nodes", f"scenes[{s}].nodes")


def _check_nodes(doc: dict, path: Path, ref: _Refs) -> None:
    """Indices, transforms, one parent per node, no cycle; each scene lists roots, once."""
    nodes = _items(doc, "nodes")
    parent: dict[int, int] = {}
    for n, node in enumerate(nodes):
        _check_node(node, n, path, ref, parent)
    _check_acyclic(nodes, parent, path)
    _check_scene_roots(doc, parent, path)


def _check_node(node: dict, n: int, path: Path, ref: _Refs, parent: dict[int, int]) -> None:
    """Node ``n``'s mesh, children (entered in ``parent``) and transform."""
    where = f"nodes[{n}]"
    if "mesh" in node:
        ref.index(node["mesh"], "meshes", f"{where}.mesh")
    _check_children(node, n, path, ref, parent)
    for key, count in (("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)):
        if key in node:
            ref.numbers(node[key], count, f"{where}.{key}")


def _check_children(node: dict, n: int, path: Path, ref: _Refs, parent: dict[int, int]) -> None:
    """Node ``n``'s children exist, once each, and have no other parent (entered in ``parent``)."""
    where = f"nodes[{n}].children"
    for child in _list(node.get("children", []), path, where):
        ref.index(child, "nodes", where)
        if child == n:
            raise _refuse(path, where, "lists the node itself (a cycle)")
        if parent.get(child) == n:
            raise _refuse(path, where, f"lists node {child} twice")
        if child in parent:
            raise _refuse(path, where, f"gives node {child} a second parent")
        parent[child] = n


def _check_scene_roots(doc: dict, parent: dict[int, int], path: Path) -> None:
    """Each scene lists root nodes only, each once."""
    for s, scene in enumerate(_items(doc, "scenes")):
        listed: set[int] = set()
        for node in scene.get("nodes", []):
            where = f"scenes[{s}].nodes"
            if node in parent:
                problem = f"lists node {node}, a child of node {parent[node]}, not a root node"
                raise _refuse(path, where, problem)
            if node in listed:
                raise _refuse(path, where, f"lists node {node} twice")
            listed.add(node)


def _check_acyclic(nodes: list[dict], parent: dict[int, int], path: Path) -> None:
    """Refuse a cycle. With one parent per node, a walk down from the nodes without a parent
    reaches every node exactly once unless some hang on a cycle; the walk keeps its own stack,
    so a chain of any depth is checked in time and memory linear in the number of nodes."""
    reached = [False] * len(nodes)
    stack = [n for n in range(len(nodes)) if n not in parent]
    while stack:
        n = stack.pop()
        reached[n] = True
        stack += nodes[n].get("children", [])
    unreached = next((n for n, done in enumerate(reached) if not done), None)
    if unreached is None:
        return
    seen, node = set(), unreached
    while node not in seen:  # every unreached node has an unreached parent: this loops
        seen.add(node)
        node = parent[node]
    raise _refuse(path, f"nodes[{node}]", "is its own ancestor (a cycle)")


def _check_accessor_fields(accessor: dict, path: Path, where: str, ref: _Refs) -> None:
    if accessor.get("componentType") not in COMPONENT_SIZES:
        raise _refuse(path, f"{where}.componentType", f"is {accessor.get('componentType')!r}")
    if accessor.get("type") not in TYPE_SIZES:
        raise _refuse(path, f"{where}.type", f"is {accessor.get('type')!r}")
    ref.whole(accessor.get("count"), f"{where}.count", low=1)
    ref.whole(accessor.get("byteOffset", 0), f"{where}.byteOffset")
    if "bufferView" in accessor:
        ref.index(accessor["bufferView"], "bufferViews", f"{where}.bufferView")
    size = TYPE_SIZES[accessor["type"]]
    for key in ("min", "max"):
        if key in accessor:
            ref.numbers(accessor[key], size, f"{where}.{key}")


def _check_mesh(mesh: dict, path: Path, where: str, ref: _Refs) -> None:
    """A mesh's primitives: a list of primitives, each checked."""
    primitives = _list(mesh.get("primitives"), path, f"{where}.primitives")
    for p, primitive in enumerate(primitives):
        _check_primitive_fields(primitive, path, f"{where}.primitives[{p}]", ref)


def _check_primitive_fields(primitive: Any, path: Path, where: str, ref: _Refs) -> None:
    """A primitive's attributes, indices and material are indices; its mode is 0 to 6."""
    if not isinstance(primitive, dict) or not isinstance(primitive.get("attributes"), dict):
        raise _refuse(path, where, "has no 'attributes' object")
    for name, accessor in primitive["attributes"].items():
        ref.index(accessor, "accessors", f"{where}.attributes.{name}")
    for key, array in (("indices", "accessors"), ("material", "materials")):
        if key in primitive:
            ref.index(primitive[key], array, f"{where}.{key}")
    mode = primitive.get("mode", 4)
    if not _is_int(mode) or mode not in range(7):
        raise _refuse(path, f"{where}.mode", f"is {primitive['mode']!r}, not 0 to 6")


def _check_buffer_view_fields(view: dict, path: Path, where: str, ref: _Refs) -> None:
    """A buffer view's buffer is an index; its offset, length and stride whole numbers."""
    ref.index(view.get("buffer"), "buffers", f"{where}.buffer")
    for key in ("byteOffset", "byteLength", "byteStride"):
        if key in view or key == "byteLength":
            ref.whole(view.get(key), f"{where}.{key}", low=int(key == "byteLength"))


def _check_buffer_fields(buffer: dict, path: Path, where: str, ref: _Refs) -> None:
    """A buffer's length is a whole number >= 1."""
    ref.whole(buffer.get("byteLength"), f"{where}.byteLength", low=1)


def _check_image_fields(image: dict, path: Path, where: str, ref: _Refs) -> None:
    """An image has a buffer view (an index) or a URI."""
    if "bufferView" in image:
        ref.index(image["bufferView"], "bufferViews", f"{where}.bufferView")
    elif not isinstance(image.get("uri"), str):
        raise _refuse(path, where, "has neither a 'uri' nor a 'bufferView'")


def _check_texture_fields(texture: dict, path: Path, where: str, ref: _Refs) -> None:
    """A texture's source and sampler, and its extensions' sources, are indices."""
    for key, array in (("source", "images"), ("sampler", "samplers")):
        if key in texture:
            ref.index(texture[key], array, f"{where}.{key}")
    for name, extension in _dict(texture.get("extensions", {}), path, where):
        if isinstance(extension, dict) and "source" in extension:
            ref.index(extension["source"], "images", f"{where}.extensions.{name}")


_SAMPLER_ENUMS = (
    ("magFilter", _FILTERS), ("minFilter", _FILTERS), ("wrapS", _WRAPS), ("wrapT", _WRAPS)
)  # fmt: skip


def _check_sampler_fields(sampler: dict, path: Path, where: str, ref: _Refs) -> None:
    """A sampler's filters and wraps are valid enum values."""
    for key, allowed in _SAMPLER_ENUMS:
        ref.enum(sampler, key, allowed, where)


def _check_material(material: dict, path: Path, where: str, ref: _Refs) -> None:
    """A material's factors, enums and every texture reference it holds."""
    pbr = material.get("pbrMetallicRoughness", {})
    if not isinstance(pbr, dict):
        raise _refuse(path, f"{where}.pbrMetallicRoughness", "is not an object")
    _check_factors(material, pbr, where, ref)
    ref.enum(material, "alphaMode", _ALPHA_MODES, where)
    ref.enum(material, "doubleSided", {True, False}, where)
    for here, info in _texture_infos(material, pbr, path, where):
        if info is not None:
            _check_texture_info(info, path, here, ref)


def _check_factors(material: dict, pbr: dict, where: str, ref: _Refs) -> None:
    """A material's colour, metallic, roughness and emissive factors and alpha cutoff."""
    if "baseColorFactor" in pbr:
        ref.numbers(pbr["baseColorFactor"], 4, f"{where}.baseColorFactor", 0, 1)
    for key in ("metallicFactor", "roughnessFactor"):
        if key in pbr:
            ref.numbers([pbr[key]], 1, f"{where}.{key}", 0, 1)
    if "emissiveFactor" in material:
        ref.numbers(material["emissiveFactor"], 3, f"{where}.emissiveFactor", 0, 1)
    if "alphaCutoff" in material:
        ref.numbers([material["alphaCutoff"]], 1, f"{where}.alphaCutoff", 0)


def _texture_infos(material: dict, pbr: dict, path: Path, where: str) -> list[tuple[str, Any]]:
    """``(place, texture info or None)`` of the core texture slots and of every extension's
    ``*Texture`` key."""
    infos = [
        (f"{where}.{keys[-1]}", pbr.get(keys[1]) if len(keys) == 2 else material.get(keys[0]))
        for keys in _TEXTURE_INFOS
    ]
    for name, extension in _dict(material.get("extensions", {}), path, where):
        for key, value in extension.items() if isinstance(extension, dict) else ():
            if key.endswith("Texture"):
                infos.append((f"{where}.extensions.{name}.{key}", value))
    return infos


def _check_texture_info(info: Any, path: Path, here: str, ref: _Refs) -> None:
    """A texture info is an object with a texture index, a UV set and in-range numbers."""
    if not isinstance(info, dict):
        raise _refuse(path, here, "is not a texture object")
    ref.index(info.get("index"), "textures", f"{here}.index")
    ref.whole(info.get("texCoord", 0), f"{here}.texCoord")
    for key in ("scale", "strength"):
        if key in info:
            high = 1 if key == "strength" else math.inf
            ref.numbers([info[key]], 1, f"{here}.{key}", 0 if high == 1 else -math.inf, high)
    extensions = info.get("extensions")
    if isinstance(extensions, dict) and "KHR_texture_transform" in extensions:
        _check_transform(extensions["KHR_texture_transform"], path, here, ref)


def _check_transform(transform: Any, path: Path, here: str, ref: _Refs) -> None:
    """A ``KHR_texture_transform``: an object of finite numbers of the right count."""
    where = f"{here}.extensions.KHR_texture_transform"
    if not isinstance(transform, dict):
        raise _refuse(path, where, "is not an object")
    for key, count in (("offset", 2), ("scale", 2)):
        if key in transform:
            ref.numbers(transform[key], count, f"{where}.{key}")
    if "rotation" in transform:
        ref.numbers([transform["rotation"]], 1, f"{where}.rotation")
    if "texCoord" in transform:
        ref.whole(transform["texCoord"], f"{where}.texCoord")


_ITEM_CHECKS: tuple[tuple[str, Callable[[dict, Path, str, _Refs], None]], ...] = (
    ("meshes", _check_mesh),
    ("accessors", _check_accessor_fields),
    ("bufferViews", _check_buffer_view_fields),
    ("buffers", _check_buffer_fields),
    ("images", _check_image_fields),
    ("textures", _check_texture_fields),
    ("samplers", _check_sampler_fields),
    ("materials", _check_material),
)
"""The top-level arrays whose items :func:`check_structure` checks one by one, in order."""


# ----------------------------------------------------------------------------- data


def buffer_data(doc: dict, path: Path, root: Path, chunk: bytes | None) -> list[bytes | None]:
    """The bytes of every buffer: the GLB's BIN chunk, a data URI or a file inside ``root``;
    None for an external file that is missing (reported by the caller)."""
    data: list[bytes | None] = []
    for b, buffer in enumerate(_items(doc, "buffers")):
        uri = buffer.get("uri")
        if uri is None:
            if chunk is None:
                raise _refuse(path, f"buffers[{b}]", "has no 'uri' and there is no GLB BIN chunk")
            data.append(chunk)
        elif not isinstance(uri, str):
            raise _refuse(path, f"buffers[{b}].uri", f"is {uri!r}, not a string")
        elif uri.startswith("data:"):
            data.append(data_uri_bytes(uri, path, f"buffers[{b}].uri"))
        else:
            from urllib.parse import unquote

            file = resolve_reference(unquote(uri), path.parent, root, path, f"buffer #{b}")
            data.append(file.read_bytes())
    return data


def data_uri_bytes(uri: str, path: Path, where: str) -> bytes:
    header, _, payload = uri.partition(",")
    if not header.endswith(";base64"):
        raise _refuse(path, where, "is a data URI that is not base64")
    try:
        return base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise _refuse(path, where, f"is a data URI that does not decode ({exc})") from None


def check_data(doc: dict, path: Path, buffers: list[bytes]) -> None:
    """Buffers, views and the accessors primitives read hold what they claim (module doc)."""
    for b, (buffer, data) in enumerate(zip(_items(doc, "buffers"), buffers, strict=True)):
        if len(data) < buffer["byteLength"]:
            raise _refuse(
                path, f"buffers[{b}]", f"holds {len(data)} bytes, not {buffer['byteLength']}"
            )
    views = _items(doc, "bufferViews")
    for v, view in enumerate(views):
        end = view.get("byteOffset", 0) + view["byteLength"]
        if end > doc["buffers"][view["buffer"]]["byteLength"]:
            raise _refuse(path, f"bufferViews[{v}]", f"ends at byte {end}, past its buffer")
    for m, mesh in enumerate(_items(doc, "meshes")):
        for p, primitive in enumerate(mesh["primitives"]):
            _check_primitive(doc, path, buffers, primitive, f"meshes[{m}].primitives[{p}]")


def _element_size(accessor: dict) -> int:
    return COMPONENT_SIZES[accessor["componentType"]] * TYPE_SIZES[accessor["type"]]


def _accessor_bytes(doc: dict, path: Path, a: int, where: str) -> tuple[int, int]:
    """``(byte offset in its buffer, stride)`` of accessor ``a``, checked to fit its view."""
    accessor = doc["accessors"][a]
    here = f"{where} (accessors[{a}])"
    if "sparse" in accessor:
        raise _refuse(path, here, "is sparse, which GeoScaler does not read")
    if "bufferView" not in accessor:
        raise _refuse(
            path, here, "has no data (no bufferView; Draco or meshopt compression is not read)"
        )
    view = doc["bufferViews"][accessor["bufferView"]]
    element = _element_size(accessor)
    stride = view.get("byteStride", element)
    if stride < element or stride > 252 or stride % 4 and stride != element:
        raise _refuse(path, here, f"has a byteStride of {stride} for {element}-byte elements")
    end = accessor.get("byteOffset", 0) + stride * (accessor["count"] - 1) + element
    if end > view["byteLength"]:
        raise _refuse(path, here, f"reads {end} bytes of a {view['byteLength']}-byte view")
    return view.get("byteOffset", 0) + accessor.get("byteOffset", 0), stride


def _check_primitive(
    doc: dict, path: Path, buffers: list[bytes], primitive: dict, where: str
) -> None:
    attributes, accessors = primitive["attributes"], doc["accessors"]
    if "POSITION" not in attributes:
        raise _refuse(path, where, "has no POSITION attribute")
    reads = {f"attributes.{k}": v for k, v in attributes.items() if k in _ATTRIBUTE_FORMATS}
    for name, a in reads.items():
        _accessor_bytes(doc, path, a, f"{where}.{name}")
        kinds, components, words = _ATTRIBUTE_FORMATS[name.partition(".")[2]]
        accessor = accessors[a]
        if accessor["type"] not in kinds or accessor["componentType"] not in components:
            raise _refuse(path, f"{where}.{name}", f"is not {words}")
    position = accessors[attributes["POSITION"]]
    counts = {accessors[a]["count"] for a in reads.values()}
    if len(counts) > 1:
        raise _refuse(path, f"{where}.attributes", f"have different counts {sorted(counts)}")
    triangles = primitive.get("mode", 4) == 4
    if "indices" not in primitive:
        if triangles and position["count"] % 3:
            raise _refuse(path, where, f"has {position['count']} vertices, not triangles")
        return
    a = primitive["indices"]
    indices = accessors[a]
    here = f"{where}.indices"
    if indices["type"] != "SCALAR" or indices["componentType"] not in _INDEX_TYPES:
        raise _refuse(path, here, "is not SCALAR of unsigned integers")
    if triangles and indices["count"] % 3:
        raise _refuse(path, here, f"has {indices['count']} entries, not a multiple of 3")
    offset, stride = _accessor_bytes(doc, path, a, here)
    dtype = np.dtype(_INDEX_TYPES[indices["componentType"]]).newbyteorder("<")
    data = buffers[doc["bufferViews"][indices["bufferView"]]["buffer"]]
    values = np.ndarray((indices["count"],), dtype, data, offset, (stride,))
    largest = int(values.max())
    if largest >= position["count"]:
        raise _refuse(path, here, f"has index {largest}, past its {position['count']} vertices")
