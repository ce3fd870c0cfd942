"""Hand-made assets with every map, attribute and reference the writer must keep.

:func:`rich_gltf` is a glTF written byte by byte (not by GeoScaler, not by trimesh) that holds
what a complete asset carries: TANGENT, COLOR_0 (normalised bytes on one primitive, floats on
the other), TEXCOORD_1 and a ``texCoord: 1`` reference, ``KHR_texture_transform``,
``KHR_materials_clearcoat`` with textures, one image file behind two image entries (as Poly
Haven's sofa has), one image shown by several slots of both materials, JPEG and PNG images,
external and embedded.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image

FLOAT, UNSIGNED_BYTE, UNSIGNED_SHORT = 5126, 5121, 5123


def encode(pixels: np.ndarray, fmt: str, **options) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format=fmt, **options)
    return buffer.getvalue()


def smooth(height: int, width: int, seed: int) -> np.ndarray:
    """An ``(H, W, 3)`` uint8 image with gentle gradients (JPEG-friendly)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    channels = [np.sin(x * a + y * b + c) for a, b, c in rng.uniform(1, 6, (3, 3))]
    return np.round(127.5 + 100 * np.stack(channels, axis=2)).astype(np.uint8)


WOOD = encode(smooth(16, 16, 1), "JPEG", quality=85)
NORMAL = encode(np.dstack([smooth(8, 8, 2)[..., :2], np.full((8, 8), 255, np.uint8)]), "PNG")
ORM = encode(smooth(8, 8, 3), "PNG")
CLEARCOAT = encode(smooth(8, 8, 4), "JPEG", quality=80)

QUAD_UVS = np.float32([[0, 1], [1, 1], [1, 0], [0, 0]])  # glTF: v = 0 at the top
SECOND_UVS = np.float32([[0.1, 0.7], [0.3, 0.7], [0.3, 0.9], [0.1, 0.9]])
TANGENTS = {
    "painted": np.float32([[1, 0, 0, 1]] * 4),
    "coated": np.float32([[0, 1, 0, -1], [0, 1, 0, -1], [0.6, 0.8, 0, 1], [0.6, 0.8, 0, 1]]),
}
COLORS_BYTES = np.uint8([[255, 0, 0, 255], [0, 255, 0, 128], [0, 0, 255, 0], [51, 102, 153, 204]])
COLORS_FLOAT = np.float32([[0.5, 0.25, 0.125]] * 2 + [[0.1, 0.2, 0.3]] * 2)
IMAGE_FILES = {"wood.jpg": WOOD, "normal.png": NORMAL, "orm.png": ORM}
TRANSFORM = {"KHR_texture_transform": {"offset": [0.5, 0.0], "scale": [2.0, 2.0]}}
CLEAR_CLAMP = {"wrapS": 33071, "wrapT": 33071}

MATERIALS = [
    {
        "name": "painted",
        "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0},
            "baseColorFactor": [1.0, 0.875, 0.75, 1.0],
            "metallicFactor": 0.0,
        },
        "normalTexture": {"index": 2, "scale": 0.5, "extensions": TRANSFORM},
        "occlusionTexture": {"index": 3, "texCoord": 1, "strength": 0.75},
    },
    {
        "name": "coated",
        "pbrMetallicRoughness": {"baseColorTexture": {"index": 1}, "metallicRoughnessTexture":
                                 {"index": 3}},
        "extensions": {
            "KHR_materials_clearcoat": {
                "clearcoatFactor": 1.0,
                "clearcoatTexture": {"index": 4},
                "clearcoatRoughnessTexture": {"index": 3},
                "clearcoatNormalTexture": {"index": 2, "scale": 0.8},
            }
        },
    },
]  # fmt: skip


class _Blob:
    def __init__(self) -> None:
        self.data, self.views, self.accessors = b"", [], []

    def view(self, blob: bytes, target: int | None = None) -> int:
        self.data += b"\0" * (-len(self.data) % 4)
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(blob)}
        self.views.append({**view, **({"target": target} if target else {})})
        self.data += blob
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, component: int, **extra) -> int:
        target = 34963 if kind == "SCALAR" else 34962
        view = self.view(np.ascontiguousarray(array).tobytes(), target)
        self.accessors.append({"bufferView": view, "componentType": component,
                               "count": len(array), "type": kind, **extra})  # fmt: skip
        return len(self.accessors) - 1


def rich_document() -> tuple[dict, bytes]:
    """The glTF document and its binary buffer (images ``wood.jpg``, ``normal.png`` and
    ``orm.png`` external, the clearcoat JPEG in the buffer)."""
    blob = _Blob()
    primitives = []
    for m, (name, x) in enumerate((("painted", 0.0), ("coated", 2.0))):
        positions = np.float32([[x, 0, 0], [x + 1, 0, 0], [x + 1, 1, 0], [x, 1, 0]])
        attributes = {
            "POSITION": blob.accessor(positions, "VEC3", FLOAT, min=positions.min(0).tolist(),
                                      max=positions.max(0).tolist()),
            "NORMAL": blob.accessor(np.float32([[0, 0, 1]] * 4), "VEC3", FLOAT),
            "TANGENT": blob.accessor(TANGENTS[name], "VEC4", FLOAT),
            "TEXCOORD_0": blob.accessor(QUAD_UVS, "VEC2", FLOAT),
            "TEXCOORD_1": blob.accessor(SECOND_UVS, "VEC2", FLOAT),
        }  # fmt: skip
        if m == 0:
            colors = blob.accessor(COLORS_BYTES, "VEC4", UNSIGNED_BYTE, normalized=True)
        else:
            colors = blob.accessor(COLORS_FLOAT, "VEC3", FLOAT)
        attributes["COLOR_0"] = colors
        indices = blob.accessor(np.uint16([0, 1, 2, 0, 2, 3]), "SCALAR", UNSIGNED_SHORT)
        primitives.append({"attributes": attributes, "indices": indices, "material": m})
    clearcoat = blob.view(CLEARCOAT)
    doc = {
        "asset": {"version": "2.0", "generator": "GeoScaler tests"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": primitives}],
        "materials": MATERIALS,
        "textures": [
            {"source": 0, "sampler": 0},
            {"source": 1, "sampler": 0},
            {"source": 2, "sampler": 1},
            {"source": 3},
            {"source": 4},
        ],
        "samplers": [{"magFilter": 9729, "minFilter": 9987}, CLEAR_CLAMP],
        "images": [
            {"uri": "wood.jpg", "name": "wood"},
            {"uri": "wood.jpg", "name": "wood again"},
            {"uri": "normal.png"},
            {"uri": "orm.png"},
            {"bufferView": clearcoat, "mimeType": "image/jpeg", "name": "clearcoat"},
        ],
        "buffers": [{"byteLength": len(blob.data), "uri": "rich.bin"}],
        "bufferViews": blob.views,
        "accessors": blob.accessors,
        "extensionsUsed": ["KHR_materials_clearcoat", "KHR_texture_transform"],
    }
    return doc, blob.data


def rich_gltf(folder: Path) -> Path:
    """``rich.gltf`` + ``rich.bin`` + its three image files in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    doc, blob = rich_document()
    (folder / "rich.bin").write_bytes(blob)
    for name, data in IMAGE_FILES.items():
        (folder / name).write_bytes(data)
    (folder / "rich.gltf").write_text(json.dumps(doc, indent=1))
    return folder / "rich.gltf"


def read_glb(path: Path) -> tuple[dict, bytes]:
    """The JSON document and BIN chunk of a GLB file."""
    data = path.read_bytes()
    size = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + size])
    blob = data[20 + size + 8 :]
    return doc, blob


def written_images(path: Path) -> list[bytes]:
    """The bytes of every image of a written .gltf (files beside it) or .glb (its chunk)."""
    if path.suffix == ".glb":
        doc, blob = read_glb(path)
        views = doc["bufferViews"]
        return [blob[views[i["bufferView"]]["byteOffset"]:][: views[i["bufferView"]]
                ["byteLength"]] for i in doc["images"]]  # fmt: skip
    doc = json.loads(path.read_text())
    return [(path.parent / image["uri"]).read_bytes() for image in doc["images"]]


def document(path: Path) -> dict:
    """The JSON document of a written .gltf or .glb."""
    return read_glb(path)[0] if path.suffix == ".glb" else json.loads(path.read_text())
