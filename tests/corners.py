"""Every face corner of a mesh file in world space, read independently of GeoScaler's loader.

The geometry tests compare an input file with what GeoScaler wrote, corner by corner. Reading
both through :mod:`geoscaler.io` would hide a fault of the loader itself (welding vertices,
averaging normals), so this reader goes from the file's bytes to world-space corners with no
welding at all: glTF/GLB accessors and node transforms, OBJ ``v``/``vt``/``vn`` indices.
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import numpy as np
from scipy.spatial import cKDTree

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16,
               5125: np.uint32, 5126: np.float32}  # fmt: skip
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


@dataclass
class Corners:
    """``(F, 3, k)`` float64 arrays, one row per face corner, in world space.

    ``normals`` and ``tangents`` (xyz unit, w the handedness) are None where the file has
    none; ``attributes`` holds the other per-corner attributes the file carries (glTF
    ``COLOR_0`` as RGBA, ``TEXCOORD_1``), each in every primitive or left out.
    """

    positions: np.ndarray
    uvs: np.ndarray
    normals: np.ndarray | None
    tangents: np.ndarray | None
    attributes: dict[str, np.ndarray]


def world_corners(path: Path) -> Corners:
    """The corners of every triangle of an OBJ, glTF or GLB file, in world space."""
    return _obj_corners(path) if path.suffix.lower() == ".obj" else _gltf_corners(path)


def matched_faces(a: Corners, b: Corners, by_uv: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Pair the faces of ``a`` and ``b`` by where their corners stand (position and, with
    ``by_uv``, UV; corners in any order, faces in any order); faces standing on the same
    corners (a file may hold a face twice) pair by their normals too.

    Returns ``(order_a, corner_b)``: face ``order_a[i]`` of ``a`` is face ``i`` of ``b``, and
    ``corner_b[i, j]`` is the corner of that face of ``a`` that stands at corner ``j`` of ``b``.
    Fails when a face of ``b`` has no face of ``a`` left within float precision of it.
    """
    assert len(a.positions) == len(b.positions), "the face counts differ"
    scale = float(np.abs(a.positions).max()) or 1.0
    key_a, rank_a = _face_keys(a, scale, by_uv)
    key_b, rank_b = _face_keys(b, scale, by_uv)
    near = min(8, len(key_a))
    distance, candidates = cKDTree(key_a).query(key_b, k=near)
    distance, candidates = distance.reshape(len(key_b), near), candidates.reshape(len(key_b), near)
    order_a = np.full(len(key_b), -1)
    taken = np.zeros(len(key_a), dtype=bool)
    for face in np.argsort(distance[:, 0], kind="stable"):
        free = [c for c, d in zip(candidates[face], distance[face], strict=True)
                if d < 1e-4 and not taken[c]]  # fmt: skip
        assert free, f"output face {face} stands on no input face left"
        order_a[face] = free[0]
        taken[free[0]] = True
    inverse_a = np.argsort(rank_a, axis=1)
    corner_b = np.take_along_axis(inverse_a[order_a], rank_b, axis=1)
    return order_a, corner_b


def _face_keys(corners: Corners, scale: float, by_uv: bool) -> tuple[np.ndarray, np.ndarray]:
    """Each face's corners sorted by (position, UV), flattened with their normals weighted
    1e-6 (to tell apart faces on the same corners): ``(F, 15 or 24)``, or without the UVs;
    and the sort ``(F, 3)``, corner ranks in the face."""
    columns = [corners.positions / scale, corners.uvs if by_uv else 0 * corners.uvs]
    if corners.normals is not None:
        columns.append(corners.normals * 1e-6)
    rows = np.concatenate(columns, axis=2)
    rank = np.lexsort(rows[:, :, :5].transpose(2, 0, 1)[::-1], axis=-1)
    ordered = np.take_along_axis(rows, rank[:, :, None], axis=1)
    return ordered.reshape(len(rows), -1), rank


def _obj_corners(path: Path) -> Corners:
    lists: dict[str, list[list[float]]] = {"v": [], "vt": [], "vn": []}
    faces: list[list[tuple[int, ...]]] = []
    for line in path.read_text(encoding="utf-8-sig").splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] in lists:
            lists[words[0]].append([float(w) for w in words[1:4]])
        elif words[0] == "f":
            corners = [_obj_corner(w, lists) for w in words[1:]]
            faces += [[corners[0], corners[k], corners[k + 1]] for k in range(1, len(corners) - 1)]
    index = np.array(faces)  # (F, 3, 3): v, vt, vn (-1: absent)
    positions = np.array(lists["v"])[:, :3][index[..., 0]]
    uvs = np.array(lists["vt"])[:, :2][index[..., 1]]
    normals = None
    if (index[..., 2] >= 0).all():
        normals = _unit(np.array(lists["vn"])[index[..., 2]])
    return Corners(positions, uvs, normals, None, {})


def _obj_corner(word: str, lists: dict[str, list]) -> tuple[int, int, int]:
    fields = (word.split("/") + ["", ""])[:3]
    out = []
    for field, name in zip(fields, ("v", "vt", "vn"), strict=True):
        if not field:
            out.append(-1)
            continue
        k = int(field)
        out.append(k - 1 if k > 0 else len(lists[name]) + k)
    return tuple(out)


def _gltf_corners(path: Path) -> Corners:
    doc, buffers = _gltf_document(path)
    rows: dict[str, list[np.ndarray]] = {}
    for node, world in _world_matrices(doc):
        if "mesh" not in doc["nodes"][node]:
            continue
        for primitive in doc["meshes"][doc["nodes"][node]["mesh"]]["primitives"]:
            if primitive.get("mode", 4) != 4:
                continue
            for name, values in _primitive_corners(doc, buffers, primitive, world).items():
                rows.setdefault(name, []).append(values)
    count = len(rows["POSITION"])
    joined = {name: np.concatenate(v) for name, v in rows.items() if len(v) == count}
    return Corners(
        positions=joined.pop("POSITION"),
        uvs=joined.pop("TEXCOORD_0"),
        normals=joined.pop("NORMAL", None),
        tangents=joined.pop("TANGENT", None),
        attributes=joined,
    )


def _primitive_corners(doc: dict, buffers: list[bytes], primitive: dict, world: np.ndarray):
    attributes = primitive["attributes"]
    count = doc["accessors"][attributes["POSITION"]]["count"]
    if "indices" in primitive:
        index = _accessor(doc, buffers, primitive["indices"]).astype(np.int64).reshape(-1, 3)
    else:
        index = np.arange(count).reshape(-1, 3)
    linear, offset = world[:3, :3], world[:3, 3]
    if np.linalg.det(linear) < 0:
        index = index[:, ::-1]
    out = {}
    for name, accessor in attributes.items():
        values = _accessor(doc, buffers, accessor).astype(np.float64)
        if name == "POSITION":
            values = values @ linear.T + offset
        elif name == "NORMAL":
            values = _unit(values @ np.linalg.inv(linear))
        elif name == "TANGENT":
            handed = np.sign(np.linalg.det(linear))
            values = np.c_[_unit(values[:, :3] @ linear.T), values[:, 3] * handed]
        elif name.startswith("TEXCOORD"):
            values = np.c_[values[:, 0], 1.0 - values[:, 1]]  # OpenGL's v, as OBJ and GeoScaler
        elif name == "COLOR_0" and values.shape[1] == 3:
            values = np.c_[values, np.ones(len(values))]
        out[name] = values[index]
    return out


def _accessor(doc: dict, buffers: list[bytes], number: int) -> np.ndarray:
    accessor = doc["accessors"][number]
    view = doc["bufferViews"][accessor["bufferView"]]
    dtype = np.dtype(_COMPONENTS[accessor["componentType"]])
    width = _WIDTH[accessor["type"]]
    stride = view.get("byteStride") or dtype.itemsize * width
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    shape, strides = (accessor["count"], width), (stride, dtype.itemsize)
    values = np.ndarray(shape, dtype, buffers[view["buffer"]], start, strides).copy()
    if accessor.get("normalized"):
        values = values / np.iinfo(dtype).max
    return values


def _gltf_document(path: Path) -> tuple[dict, list[bytes]]:
    data = path.read_bytes()
    chunk = b""
    if data[:4] == b"glTF":
        size = struct.unpack_from("<I", data, 12)[0]
        doc = json.loads(data[20 : 20 + size])
        chunk = data[20 + size + 8 :]
    else:
        doc = json.loads(data)
    buffers = []
    for buffer in doc["buffers"]:
        uri = buffer.get("uri")
        if uri is None:
            buffers.append(chunk)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            buffers.append((path.parent / unquote(uri)).read_bytes())
    return doc, buffers


def _world_matrices(doc: dict) -> list[tuple[int, np.ndarray]]:
    """Every node of the default scene with its world matrix, walked without recursion."""
    scene = doc.get("scenes", [{}])[doc.get("scene", 0)]
    stack = [(node, np.eye(4)) for node in scene.get("nodes", [])]
    out = []
    while stack:
        node, parent = stack.pop()
        world = parent @ _local_matrix(doc["nodes"][node])
        out.append((node, world))
        stack += [(child, world) for child in doc["nodes"][node].get("children", [])]
    return out


def _local_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    rotation = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    matrix = np.eye(4)
    matrix[:3, :3] = rotation * np.array(node.get("scale", [1, 1, 1]), dtype=np.float64)
    matrix[:3, 3] = node.get("translation", [0, 0, 0])
    return matrix


def _unit(vectors: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.where(length > 0, length, 1.0)
