"""glTF geometry: the scene's nodes placed, each triangle primitive read from its accessors.

The document has passed :func:`geoscaler.io.gltf_check.check_structure` and
:func:`~geoscaler.io.gltf_check.check_data` (indices in range, accessors inside their views),
so reading here is plain array slicing. What GeoScaler keeps of a primitive is
:data:`KEPT_ATTRIBUTES`; :func:`check_kept` refuses, naming it, what it cannot keep
(animations, skins, morph targets, other attributes), so nothing is dropped in silence.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from geoscaler.errors import GeoscalerError

from .assemble import Part
from .gltf_check import TYPE_SIZES

KEPT_ATTRIBUTES = ("POSITION", "NORMAL", "TANGENT", "TEXCOORD_0", "TEXCOORD_1", "COLOR_0")
"""The vertex attributes GeoScaler reads and writes back."""
_KEPT_TEXT = "POSITION, NORMAL, TANGENT, TEXCOORD_0, TEXCOORD_1 and COLOR_0"
_DTYPES = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_NORMALIZED = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}
_TRIANGLES, _STRIP, _FAN = 4, 5, 6


def check_kept(doc: dict, path: Path) -> None:
    """Refuse (``GeoscalerError``) what GeoScaler cannot keep in the one static mesh it
    writes: animations, skins, morph targets and attributes other than :data:`KEPT_ATTRIBUTES`
    (``JOINTS_n``, ``WEIGHTS_n``, ``TEXCOORD_2`` and up, ``COLOR_1`` and up, custom ``_NAME``).
    Each message names what was found and what to do in the 3D tool."""
    cannot = "which GeoScaler cannot keep: it writes one static mesh"
    if doc.get("animations"):
        raise GeoscalerError(
            f"{path}: has {len(doc['animations'])} animation(s), {cannot}. Remove the "
            "animations (or keep one frame) in your 3D tool and re-export."
        )
    if doc.get("skins") or any("skin" in node for node in doc.get("nodes", [])):
        raise GeoscalerError(
            f"{path}: has a skin (skeletal animation, JOINTS_n/WEIGHTS_n), {cannot}. Apply "
            "the pose and remove the armature in your 3D tool, then re-export."
        )
    for m, mesh in enumerate(doc.get("meshes", [])):
        for p, primitive in enumerate(mesh["primitives"]):
            where = f"meshes[{m}].primitives[{p}]"
            if primitive.get("targets"):
                raise GeoscalerError(
                    f"{path}: {where} has morph targets (shape keys), {cannot}. Apply or "
                    "remove the shape keys in your 3D tool and re-export."
                )
            others = sorted(set(primitive["attributes"]) - set(KEPT_ATTRIBUTES))
            if others:
                raise GeoscalerError(
                    f"{path}: {where} has vertex attribute(s) {', '.join(others)}, which "
                    f"GeoScaler cannot keep: it keeps {_KEPT_TEXT}. Leave the others (extra "
                    "UV sets or colour layers, skin weights, custom attributes) out of the "
                    "export."
                )


def read_accessor(doc: dict, buffers: list[bytes], index: int) -> np.ndarray:
    """``(count, components)`` values of an accessor: float64 where ``normalized`` (scaled
    to [0, 1] or [-1, 1] as glTF says), its own type otherwise. Checked beforehand."""
    accessor = doc["accessors"][index]
    view = doc["bufferViews"][accessor["bufferView"]]
    dtype = np.dtype(_DTYPES[accessor["componentType"]])
    components = TYPE_SIZES[accessor["type"]]
    stride = view.get("byteStride", dtype.itemsize * components)
    offset = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    data = buffers[view["buffer"]]
    shape, strides = (accessor["count"], components), (stride, dtype.itemsize)
    values = np.ndarray(shape, dtype, data, offset, strides).copy()
    scale = _NORMALIZED.get(accessor["componentType"])
    if accessor.get("normalized") and scale is not None:
        return np.maximum(values / scale, -1.0)
    return values


def gltf_parts(doc: dict, buffers: list[bytes], path: Path) -> list[Part]:
    """Every triangle primitive of the default scene (scene 0 when none is named; every root
    node when there are no scenes), placed by its node's world transform. Points and lines
    are left out, with a warning."""
    nodes = doc.get("nodes", [])
    if doc.get("scenes"):
        roots = doc["scenes"][doc.get("scene", 0)].get("nodes", [])
    else:
        children = {c for node in nodes for c in node.get("children", [])}
        roots = [n for n in range(len(nodes)) if n not in children]
    parts, skipped = [], 0
    stack = [(root, np.eye(4)) for root in reversed(roots)]
    while stack:
        index, parent = stack.pop()
        node = nodes[index]
        world = parent @ _local_matrix(node)
        stack += [(child, world) for child in reversed(node.get("children", []))]
        for primitive in doc["meshes"][node["mesh"]]["primitives"] if "mesh" in node else []:
            if primitive.get("mode", _TRIANGLES) not in (_TRIANGLES, _STRIP, _FAN):
                skipped += 1
                continue
            part = _primitive_part(doc, buffers, primitive, world)
            if len(part.faces):
                parts.append(part)
    if skipped:
        warnings.warn(
            f"{path}: {skipped} point or line primitive(s) are not triangles; they are left "
            "out (and not written to saved files).",
            stacklevel=4,
        )
    return parts


def _local_matrix(node: dict) -> np.ndarray:
    """A node's 4 x 4 transform: its column-major ``matrix``, or translation * rotation *
    scale (the quaternion normalised; a zero one is no rotation)."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = np.asarray(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64)
    length = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = (x / length, y / length, z / length, w / length) if length > 0 else (0, 0, 0, 1)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    matrix = np.eye(4)
    matrix[:3, :3] = rotation * np.asarray(node.get("scale", [1, 1, 1]), dtype=np.float64)
    matrix[:3, 3] = node.get("translation", [0, 0, 0])
    return matrix


def _primitive_faces(doc: dict, buffers: list[bytes], primitive: dict, count: int) -> np.ndarray:
    """``(F, 3)`` int64 triangles of a triangle, strip or fan primitive (glTF 2.0, 3.7.2.1)."""
    if "indices" in primitive:
        index = read_accessor(doc, buffers, primitive["indices"])[:, 0].astype(np.int64)
    else:
        index = np.arange(count, dtype=np.int64)
    mode = primitive.get("mode", _TRIANGLES)
    if mode == _TRIANGLES:
        return index.reshape(-1, 3)
    i = np.arange(max(len(index) - 2, 0))
    if mode == _STRIP:
        return np.stack([index[i], index[i + 1 + i % 2], index[i + 2 - i % 2]], axis=1)
    return np.stack([index[i + 1], index[i + 2], np.zeros_like(i) + index[0]], axis=1)


def _primitive_part(doc: dict, buffers: list[bytes], primitive: dict, world: np.ndarray) -> Part:
    """One primitive placed in world space, its kept attributes transformed with it."""
    attributes = primitive["attributes"]

    def read(name: str) -> np.ndarray | None:
        if name not in attributes:
            return None
        return read_accessor(doc, buffers, attributes[name]).astype(np.float64)

    linear = world[:3, :3]
    determinant = np.linalg.det(linear)
    with np.errstate(invalid="ignore", over="ignore"):  # NaN and inf are refused later
        positions = read("POSITION") @ linear.T + world[:3, 3]
    faces = _primitive_faces(doc, buffers, primitive, len(positions))
    if determinant < 0:
        faces = faces[:, ::-1]
    uvs, normals = read("TEXCOORD_0"), read("NORMAL")
    if uvs is not None:
        uvs[:, 1] = 1.0 - uvs[:, 1]  # glTF's v runs down the image; ours up
    if normals is not None:
        normals = normals @ np.linalg.inv(linear) if determinant != 0 else None
    extra = {}
    tangents = read("TANGENT")
    if tangents is not None:
        identity = np.array_equal(linear, np.eye(3))
        xyz = tangents[:, :3] if identity else tangents[:, :3] @ linear.T
        sign = np.where(tangents[:, 3] < 0, -1.0, 1.0) * (-1.0 if determinant < 0 else 1.0)
        extra["TANGENT"] = np.concatenate([unit_tangents(xyz), sign[:, None]], axis=1)
    colors = read("COLOR_0")
    if colors is not None:
        extra["COLOR_0"] = np.clip(np.nan_to_num(colors), 0.0, 1.0)
    second = read("TEXCOORD_1")
    if second is not None:
        second[:, 1] = 1.0 - second[:, 1]
        extra["TEXCOORD_1"] = second
    material = primitive.get("material")
    return Part(positions, faces, uvs, normals, material, extra)


def unit_tangents(xyz: np.ndarray) -> np.ndarray:
    """``(N, 3)`` tangent directions at unit length: rows already within 1e-4 of it are kept
    bit for bit (so a file's tangents round-trip exactly), zero or non-finite ones become
    +X, the rest are normalised."""
    length = np.linalg.norm(xyz, axis=1, keepdims=True)
    good = np.isfinite(length) & (length > 1e-12)
    safe = np.where(good, length, 1.0)
    scaled = np.where(np.abs(safe - 1.0) > 1e-4, xyz / safe, xyz)
    return np.where(good, scaled, np.array([1.0, 0.0, 0.0]))
