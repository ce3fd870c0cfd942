"""Hostile inputs (#16): what an attacker or a careless user gives GeoScaler, and what it says.

Every case builds its files in a fresh folder and runs the command line in-process. Each
refusal must keep every promise of the README: exit status 2, one line that starts with
``geoscaler: error:`` and names the problem, no traceback, the input files' bytes unchanged,
and no file written anywhere (the output folder included). A property test then feeds a few
hundred seeded mutations of valid GLB and OBJ files to ``info`` and accepts only clean outcomes.
"""

from __future__ import annotations

import base64
import ctypes
import hashlib
import json
import os
import random
import re
import shutil
import struct
import subprocess
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import ONE_VIEW
from gltf_validator import ValidatorMissing, validate
from mesh_support import QUAD_OBJ, TEXTURE, one_primitive_scene, png_bytes, two_material_mesh
from PIL import Image

from geoscaler.cli import main
from geoscaler.io import check_outputs, load_mesh, save_mesh

ODD_STEM = "öut ☃ 雪"
ODD_SIDE = "out_" + hashlib.sha1(ODD_STEM.encode()).hexdigest()[:8]
"""An output name with an accent, spaces and characters outside Latin, and the name its side
files (.bin, .mtl, images) get: accents dropped, ASCII runs kept, the stem's SHA-1 added."""
QUICK_OPTIMIZE = {"pool_views": 1, "views_per_step": 1, "validate_every": 1, "warmup_steps": 1}
MTL = b"newmtl mat\nmap_Kd tex.png\n"
FLOAT, UNSIGNED_INT = 5126, 5125

# ----------------------------------------------------------------------------- file builders


def glb(doc: dict, blob: bytes = b"", length_delta: int = 0) -> bytes:
    """A GLB file: header, JSON chunk, BIN chunk (when ``blob``); the header's length field
    is off by ``length_delta``."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text
    if blob:
        blob += b"\0" * (-len(blob) % 4)
        body += struct.pack("<I4s", len(blob), b"BIN\0") + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body) + length_delta) + body


def quad(
    positions: np.ndarray | None = None,
    uvs: np.ndarray | None = None,
    indices: np.ndarray | None = None,
    image: bytes | None = None,
) -> tuple[dict, bytes]:
    """A textured quad as a glTF document and its binary buffer (image embedded)."""
    if positions is None:
        positions = np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    if uvs is None:
        uvs = np.float32([[0, 1], [1, 1], [1, 0], [0, 0]])
    if indices is None:
        indices = np.uint32([0, 1, 2, 0, 2, 3])
    parts = [
        np.float32(positions).tobytes(),
        np.float32(uvs).tobytes(),
        indices.tobytes(),
        png_bytes(TEXTURE) if image is None else image,
    ]
    blob, views = b"", []
    for part in parts:
        blob += b"\0" * (-len(blob) % 4)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(part)})
        blob += part
    doc = {
        **one_primitive_scene(),
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}],
        "images": [{"bufferView": 3, "mimeType": "image/png"}],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": FLOAT, "count": len(positions), "type": "VEC3"},
            {"bufferView": 1, "componentType": FLOAT, "count": len(uvs), "type": "VEC2"},
            {"bufferView": 2, "componentType": UNSIGNED_INT, "count": len(indices),
             "type": "SCALAR"},
        ],
    }  # fmt: skip
    return doc, blob


def edited(edit: Callable[[dict], object], **quad_args) -> dict[str, bytes]:
    """``mesh.glb``: the quad with ``edit`` applied to its JSON document."""
    doc, blob = quad(**quad_args)
    edit(doc)
    return {"mesh.glb": glb(doc, blob)}


def as_gltf(edit: Callable[[dict], object] = lambda doc: None) -> dict[str, bytes]:
    """``mesh.gltf`` + ``mesh.bin``: the quad as a glTF file with an external buffer."""
    doc, blob = quad()
    doc["buffers"][0]["uri"] = "mesh.bin"
    edit(doc)
    return {"mesh.gltf": json.dumps(doc).encode(), "mesh.bin": blob}


def obj(text: str = QUAD_OBJ, mtl: bytes = MTL, texture: bytes | None = None) -> dict:
    """``mesh.obj`` + ``mesh.mtl`` + ``tex.png``."""
    image = png_bytes(TEXTURE) if texture is None else texture
    return {"mesh.obj": text.encode(), "mesh.mtl": mtl, "tex.png": image}


def png_header(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width x height`` and whose data is a few bytes."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data)
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = zlib.compress(b"\0" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", data)


def image_bytes(image: Image.Image, fmt: str = "PNG") -> bytes:
    from io import BytesIO

    buffer = BytesIO()
    image.save(buffer, format=fmt)
    return buffer.getvalue()


def data_uri(blob: bytes) -> str:
    return "data:application/octet-stream;base64," + base64.b64encode(blob).decode()


def set_path(tree: dict, keys: str, value) -> None:
    """``tree[a][b]... = value`` for ``keys`` ``"a.b..."`` (list indices as numbers)."""
    *head, last = keys.split(".")
    for key in head:
        tree = tree[int(key)] if key.isdigit() else tree[key]
    tree[int(last) if last.isdigit() else last] = value


def turning_chain(doc: dict) -> None:
    """The quad hung on 10,000 nested nodes: each moves +1 along its parent's x, nodes 2500,
    5000 and 7500 also turn a quarter turn about z, and the last, scaled by 2, holds the mesh.
    The moves sum to (2501 - 2500, 2500 - 2499) = (1, 1), in a frame turned three quarters."""
    quarter = [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]
    doc["nodes"] = [{"children": [i + 1], "translation": [1, 0, 0]} for i in range(9999)]
    for level in (2500, 5000, 7500):
        doc["nodes"][level]["rotation"] = quarter
    doc["nodes"].append({"mesh": 0, "translation": [1, 0, 0], "scale": [2, 2, 2]})
    doc["scenes"] = [{"nodes": [0]}]


CHAIN_POSITIONS = np.float64([[1, 1, 0], [1, -1, 0], [3, -1, 0], [3, 1, 0]])
"""The quad's corners (0, 0), (1, 0), (1, 1), (0, 1) placed by :func:`turning_chain`: scaled
by 2, turned by (x, y) -> (y, -x), moved to (1, 1)."""


# ----------------------------------------------------------------------------- the corpus


@dataclass
class Case:
    """One hostile run: files written into ``in/``, then ``argv`` (``{in}``, ``{out}`` name the
    input and output folders); the error must contain ``expect``."""

    name: str
    files: dict[str, bytes]
    argv: list[str]
    expect: str
    prepare: Callable[[Path, Path], None] | None = None
    kind: str = field(default="")


def info(mesh: str = "mesh.glb") -> list[str]:
    return ["info", f"{{in}}/{mesh}", "--json"]


def render(mesh: str = "mesh.glb", out: str = "{out}/view.png", *extra: str) -> list[str]:
    return ["render", f"{{in}}/{mesh}", "-o", out, "--device", "cpu", *extra]


def downsample(mesh: str = "mesh.glb", out: str = "{out}/small.glb", *extra: str) -> list[str]:
    argv = ["downsample", f"{{in}}/{mesh}", "-o", out, "--steps", "1", "--device", "cpu"]
    return argv + list(extra)


def bin_first(doc: dict, blob: bytes) -> bytes:
    """A GLB whose BIN chunk comes before its JSON chunk."""
    chunks = glb(doc, blob)[12:]
    json_size = 8 + struct.unpack_from("<I", chunks)[0]
    body = chunks[json_size:] + chunks[:json_size]
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def glb_cases() -> list[Case]:
    doc, blob = quad()
    good = glb(doc, blob)
    bad_json = struct.pack("<I4s", 8, b"JSON") + b"{oops!!}"
    return [
        Case("glb-not-glb", {"mesh.glb": b"PK\x03\x04" + good[4:]}, info(), "not a GLB file"),
        Case("glb-empty", {"mesh.glb": b""}, info(), "not a GLB file"),
        Case("glb-version-1", {"mesh.glb": good[:4] + b"\1\0\0\0" + good[8:]}, info(),
             "GLB version 1"),
        Case("glb-length-too-long", {"mesh.glb": glb(doc, blob, 100)}, info(),
             "GLB header gives a length"),
        Case("glb-truncated", {"mesh.glb": good[:-40]}, info(), "GLB header gives a length"),
        Case("glb-trailing-garbage", {"mesh.glb": good + b"\0" * 64}, info(),
             "GLB header gives a length"),
        Case("glb-bin-first", {"mesh.glb": bin_first(doc, blob)}, info(), "first chunk is not"),
        Case("glb-json-chunk-garbage", {"mesh.glb": struct.pack("<4sII", b"glTF", 2, 28)
             + bad_json}, info(), "not valid glTF JSON"),
        Case("glb-json-array", {"mesh.glb": glb([1, 2])}, info(), "not a glTF document"),
        Case("glb-no-bin-chunk", {"mesh.glb": glb(doc)}, info(), "no GLB BIN chunk"),
    ]  # fmt: skip


def gltf_cases() -> list[Case]:
    pbr = "materials.0.pbrMetallicRoughness"
    nan_doc, blob = quad()
    nan_text = json.dumps(nan_doc).replace('"count": 4', '"count": NaN', 1).encode()
    inf_text = json.dumps(nan_doc).replace('"version": "2.0"', '"version": Infinity').encode()
    cases = [
        ("nan-literal", {"mesh.gltf": nan_text}, "NaN is not a JSON number"),
        ("infinity-literal", {"mesh.gltf": inf_text}, "Infinity is not a JSON number"),
    ]
    edits = [
        ("factor-nested", f"{pbr}.baseColorFactor", [[1, 1, 1, 1]], "baseColorFactor is"),
        ("factor-3", f"{pbr}.baseColorFactor", [1, 1, 1], "not 4 numbers between 0 and 1"),
        ("factor-above-1", f"{pbr}.baseColorFactor", [2, 1, 1, 1], "baseColorFactor is [2,"),
        ("factor-string", f"{pbr}.baseColorFactor", "red", "baseColorFactor is 'red'"),
        ("metallic-negative", f"{pbr}.metallicFactor", -1, "metallicFactor is [-1]"),
        ("emissive-string", "materials.0.emissiveFactor", "x", "emissiveFactor is 'x'"),
        ("alpha-mode", "materials.0.alphaMode", "SOMETIMES", "alphaMode is 'SOMETIMES'"),
        ("accessors-object", "accessors", {"a": 1}, "'accessors' is not a list of objects"),
        ("attribute-index", "meshes.0.primitives.0.attributes.POSITION", 9,
         "attributes.POSITION is 9, not an index into 'accessors' (3)"),
        ("attribute-bool", "meshes.0.primitives.0.attributes.POSITION", True,
         "is True, not an index"),
        ("indices-count", "accessors.2.count", 5, "has 5 entries, not a multiple of 3"),
        ("stride-short", "bufferViews.0.byteStride", 4, "byteStride of 4 for 12-byte elements"),
        ("sparse", "accessors.0.sparse", {"count": 1}, "is sparse"),
        ("view-past-buffer", "bufferViews.3.byteLength", 10**6, "past its buffer"),
        ("buffer-too-long", "buffers.0.byteLength", 10**6, "holds"),
        ("accessor-past-view", "accessors.0.count", 40, "reads 480 bytes of a 48-byte view"),
        ("count-zero", "accessors.0.count", 0, "count is 0, not a whole number >= 1"),
        ("position-vec2", "accessors.0.type", "VEC2", "POSITION is not VEC3 of FLOAT"),
        ("uv-count-differs", "accessors.1.count", 3, "have different counts [3, 4]"),
        ("component-type", "accessors.1.componentType", 1234, "componentType is 1234"),
        ("node-own-child", "nodes.0.children", [0], "lists the node itself (a cycle)"),
        ("node-matrix-15", "nodes.0.matrix", [1] * 15, "matrix is"),
        ("node-translation-str", "nodes.0.translation", ["a", 0, 0], "translation is"),
        ("node-scale-2", "nodes.0.scale", [1, 1], "scale is [1, 1], not 3 numbers"),
        ("scene-index", "scene", 3, "'scene' is 3, not an index into 'scenes' (1)"),
        ("mesh-index", "nodes.0.mesh", 7, "nodes[0].mesh is 7"),
        ("mode-9", "meshes.0.primitives.0.mode", 9, "mode is 9, not 0 to 6"),
        ("texture-source", "textures.0.source", 5, "textures[0].source is 5"),
        ("texture-index-str", f"{pbr}.baseColorTexture.index", "0", "index is '0'"),
        ("sampler-wrap", "samplers", [{"wrapS": 1}], "samplers[0].wrapS is 1"),
        ("asset-missing", "asset", None, "'asset' is missing or not an object"),
        ("version-1", "asset.version", "1.0", "glTF version 1.0"),
        ("requires-draco", "extensionsRequired", ["KHR_draco_mesh_compression"],
         "KHR_draco_mesh_compression"),
        ("image-url", "images.0", {"uri": "http://example.com/t.png"}, "is a URL"),
        ("image-outside", "images.0", {"uri": "../secret.png"}, "points outside"),
        ("buffer-data-not-base64", "buffers.0.uri", "data:application/octet-stream,abc",
         "data URI that is not base64"),
        ("buffer-data-broken", "buffers.0.uri", "data:application/octet-stream;base64,@@@",
         "does not decode"),
        ("texcoord-1", f"{pbr}.baseColorTexture.texCoord", 1, "TEXCOORD_1"),
        ("joints", "meshes.0.primitives.0.attributes.JOINTS_0", 0,
         "vertex attribute(s) JOINTS_0, which GeoScaler cannot keep"),
        ("morph-targets", "meshes.0.primitives.0.targets", [{"POSITION": 0}],
         "has morph targets (shape keys), which GeoScaler cannot keep"),
        ("animations", "animations", [{"channels": [], "samplers": []}],
         "has 1 animation(s), which GeoScaler cannot keep"),
    ]  # fmt: skip
    for name, keys, value, expect in edits:

        def edit(doc, keys=keys, value=value):
            if value is None:
                del doc[keys]
            else:
                set_path(doc, keys, value)

        cases.append((name, edited(edit), expect))
    cases += [
        ("draco-used-only", edited(lambda d: (d.__setitem__("extensionsUsed",
         ["KHR_draco_mesh_compression"]), d["accessors"][0].pop("bufferView"))),
         "has no data (no bufferView"),
        ("node-cycle", edited(lambda d: d.__setitem__("nodes", [{"children": [1]},
         {"children": [0], "mesh": 0}])), "is its own ancestor"),
        ("node-two-parents", edited(lambda d: d.__setitem__("nodes", [{"children": [2]},
         {"children": [2]}, {"mesh": 0}])), "gives node 2 a second parent"),
        ("node-twice-a-child", edited(lambda d: d.__setitem__("nodes", [{"children": [1, 1]},
         {"mesh": 0}])), "nodes[0].children lists node 1 twice"),
        ("scene-lists-a-child", edited(lambda d: d.__setitem__("nodes", [{"children": [1]},
         {"mesh": 0}]) or d["scenes"][0].__setitem__("nodes", [0, 1])),
         "scenes[0].nodes lists node 1, a child of node 0, not a root node"),
        ("scene-lists-a-root-twice", edited(lambda d: d["scenes"][0].__setitem__("nodes",
         [0, 0])), "scenes[0].nodes lists node 0 twice"),
        ("node-cycle-below-a-root", edited(lambda d: d.__setitem__("nodes", [{"mesh": 0},
         {"children": [2]}, {"children": [3]}, {"children": [1]}])),
         "nodes[1] is its own ancestor (a cycle)"),
        ("index-past-vertices", edited(lambda d: None, indices=np.uint32([0, 1, 2, 0, 2, 7])),
         "has index 7, past its 4 vertices"),
        ("gltf-bin-missing", {"mesh.gltf": as_gltf()["mesh.gltf"]}, "was not found"),
        ("gltf-bin-short", {**as_gltf(), "mesh.bin": as_gltf()["mesh.bin"][:50]},
         "holds 50 bytes"),
    ]  # fmt: skip
    out = []
    for name, files, expect in cases:
        files = files if isinstance(files, dict) else files
        mesh = next(n for n in files if n.startswith("mesh."))
        out.append(Case(f"gltf-{name}", files, info(mesh), expect))
    return out


def obj_cases() -> list[Case]:
    face = "f 1/1 2/2 3/3"

    def with_face(text: str) -> str:
        return QUAD_OBJ.replace(face, text)

    float_tiff = image_bytes(Image.fromarray(np.ones((4, 4), np.float32)), "TIFF")
    truncated = png_bytes(TEXTURE)[:-30]
    cases = [
        ("face-index-0", obj(with_face("f 0/1 2/2 3/3")), "'0/1' is not a vertex index"),
        ("face-past-end", obj(with_face("f 1/1 2/2 9/3")), "refers to vertex 9, but the file"),
        ("face-negative-past", obj(with_face("f -1/-1 -2/-2 -9/-3")), "vertex -9"),
        ("face-word", obj(with_face("f a/1 2/2 3/3")), "'a/1' is not a vertex index"),
        ("uv-past-end", obj(with_face("f 1/1 2/2 3/8")), "texture coordinate 8"),
        ("vertex-nan", obj(QUAD_OBJ.replace("v 1 0 0", "v nan 0 0")), "NaN or infinite"),
        ("vertex-inf", obj(QUAD_OBJ.replace("v 1 0 0", "v inf 0 0")), "NaN or infinite"),
        ("uv-1e30", obj(QUAD_OBJ.replace("vt 1 0", "vt 1e30 0")), "UVs up to 1e+30"),
        ("mtl-d-nan", obj(mtl=b"newmtl mat\nd nan\nmap_Kd tex.png\n"), "'d nan' is not a finite"),
        ("mtl-kd-inf", obj(mtl=b"newmtl mat\nKd inf 0 0\nmap_Kd tex.png\n"), "not a finite"),
        ("mtl-outside", obj(QUAD_OBJ.replace("mtllib mesh.mtl", "mtllib ../x.mtl")),
         "points outside the mesh's folder"),
        ("map-missing", obj(mtl=b"newmtl mat\nmap_Kd nope.png\n"), "'nope.png' was not found"),
        ("map-not-image", obj(texture=b"just text"), "could not be read as an image"),
        ("map-truncated", obj(texture=truncated), "could not be"),
        ("map-float-tiff", obj(texture=float_tiff), "pixel mode 'F' is not supported"),
        ("normal-truncated", {**obj(mtl=MTL + b"norm n.png\n"), "n.png": truncated},
         "could not be"),
        ("emissive-float", {**obj(mtl=MTL + b"map_Ke e.tif\n"), "e.tif": float_tiff},
         "pixel mode 'F'"),
        ("no-uvs", obj("mtllib mesh.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl mat\nf 1 2 3\n"),
         "have no texture coordinates"),
        ("no-faces", obj("mtllib mesh.mtl\nv 0 0 0\nv 1 0 0\nl 1 2\n"), "no triangles"),
        ("binary-garbage", obj("\x00\xff\x13garbage\x01" * 50), "contains no triangles"),
        ("no-texture", obj(mtl=b"newmtl mat\nKd 1 0 0\n"), "none of its materials has"),
    ]  # fmt: skip
    return [Case(f"obj-{name}", files, info("mesh.obj"), expect) for name, files, expect in cases]


def bomb_cases() -> list[Case]:
    wide = image_bytes(Image.new("1", (20000, 4)))
    many = image_bytes(Image.new("1", (9000, 9000)))
    return [
        Case("bomb-obj-header", obj(texture=png_header(100_000, 100_000)), info("mesh.obj"),
             "could not be read as an image"),
        Case("bomb-obj-81M-pixels", obj(texture=many), info("mesh.obj"),
             "is 9000 x 9000 pixels; GeoScaler decodes textures of up to 67,108,864"),
        Case("bomb-obj-wide", obj(texture=wide), info("mesh.obj"), "is 20000 x 4 pixels"),
        Case("bomb-glb-81M-pixels", edited(lambda d: None, image=many), info(),
             "is 9000 x 9000 pixels"),
        Case("bomb-glb-header", edited(lambda d: None, image=png_header(70_000, 70_000)),
             info(), "could not be decoded"),
    ]  # fmt: skip


def geometry_cases() -> list[Case]:
    square = np.float32([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    return [
        Case("nan-position", edited(lambda d: None, positions=square * np.nan), info(),
             "NaN or infinite"),
        Case("uv-1e30-render", edited(lambda d: None, uvs=np.float32([[0, 0]] * 3 + [[1e30, 0]])),
             render(), "UVs up to 1e+30"),
        Case("coincide-downsample", edited(lambda d: None, positions=square * 0 + 1),
             downsample(), "all its vertices at one point"),
        Case("collinear-downsample", edited(lambda d: None, positions=square * [1, 0, 0]),
             downsample(), "all 2 textured triangles are degenerate"),
        Case("tiny-1e-40-render", edited(lambda d: None, positions=square * 1e-40), render(),
             "too small to render"),
        Case("huge-1e20", edited(lambda d: None, positions=square * 1e20), info(),
             "coordinates up to 1e+20"),
    ]  # fmt: skip


def link_texture(name: str, kind: str) -> Callable[[Path, Path], None]:
    def prepare(inputs: Path, out: Path) -> None:
        target = inputs / "tex.png"
        (os.link if kind == "hard" else os.symlink)(target, out / name)

    return prepare


def external_image(doc: dict) -> None:
    doc["images"][0] = {"uri": "tex.png"}


def path_cases() -> list[Case]:
    long = "a" * 300
    deep = "/".join(["d" * 200] * 25)
    return [
        Case("render-onto-texture", obj(), render("mesh.obj", "{in}/tex.png", "--force"),
             "refusing to overwrite the input file"),
        Case("render-onto-gltf-image", {**as_gltf(external_image), "tex.png": png_bytes(TEXTURE)},
             render("mesh.gltf", "{in}/tex.png", "--force"), "refusing to overwrite the input"),
        Case("render-onto-hard-link", obj(), render("mesh.obj", "{out}/h.png", "--force"),
             "refusing to overwrite the input file", link_texture("h.png", "hard")),
        Case("render-onto-symlink", obj(), render("mesh.obj", "{out}/s.png", "--force"),
             "refusing to overwrite the input file", link_texture("s.png", "soft")),
        Case("render-into-proc", obj(), render("mesh.obj", "/proc/geoscaler.png"),
             "is a system folder"),
        Case("render-into-sys", obj(), render("mesh.obj", "/sys/geoscaler.png"),
             "is a system folder"),
        Case("render-onto-dev-null", obj(), render("mesh.obj", "/dev/null", "--force"),
             "is not a regular file"),
        Case("render-name-too-long", obj(), render("mesh.obj", f"{{out}}/{long}.png"),
             "304 bytes in one name, at most 255"),
        Case("render-path-too-long", obj(), render("mesh.obj", f"{{out}}/{deep}/v.png"),
             "bytes in all"),
        Case("render-missing-folder", obj(), render("mesh.obj", "{out}/nope/v.png"),
             "does not exist"),
        Case("render-existing", obj(), render("mesh.obj", "{in}/tex2.png"), "already exists",
             lambda i, o: (i / "tex2.png").write_bytes(b"keep")),
        Case("info-name-too-long", obj(), info(f"{long}.obj"), "File name too long"),
        Case("info-a-folder", obj(), info("folder.obj"), "no such file",
             lambda i, o: (i / "folder.obj").mkdir()),
        Case("info-a-fifo", obj(), info("fifo.obj"), "no such file",
             lambda i, o: os.mkfifo(i / "fifo.obj")),
        Case("info-escape-name", obj(), info("evil\x1b[2J.obj"), "evil\\x1b[2J.obj"),
        Case("info-texture-symlink-out", obj(mtl=b"newmtl mat\nmap_Kd link.png\n"),
             info("mesh.obj"), "points outside",
             lambda i, o: os.symlink(o.parent / "elsewhere.png", i / "link.png")),
        Case("downsample-report-onto-texture", obj(),
             downsample("mesh.obj", "{out}/s.glb", "--report", "{in}/tex.png", "--force"),
             "refusing to overwrite the input file"),
        Case("downsample-report-into-sys", obj(),
             downsample("mesh.obj", "{out}/s.glb", "--report", "/sys/r.json"),
             "is a system folder"),
        Case("downsample-report-onto-mtl", obj(),
             downsample("mesh.obj", "{out}/s.glb", "--report", "{in}/mesh.mtl", "--force"),
             "mesh.mtl: refusing to overwrite the input file"),
        Case("downsample-mtl-onto-input-mtl", obj(QUAD_OBJ.replace("mesh.mtl", "s.mtl"),
             ), downsample("mesh.obj", "{in}/s.obj", "--force"),
             "s.mtl: refusing to overwrite the input file",
             lambda i, o: (i / "mesh.mtl").rename(i / "s.mtl")),
        Case("downsample-bin-onto-input-bin", as_gltf(lambda d: d["buffers"][0].__setitem__(
             "uri", "s.bin")), downsample("mesh.gltf", "{in}/s.gltf", "--force"),
             "s.bin: refusing to overwrite the input file",
             lambda i, o: (i / "mesh.bin").rename(i / "s.bin")),
        Case("downsample-odd-name-bin-onto-input-bin", as_gltf(lambda d: d["buffers"][0]
             .__setitem__("uri", f"{ODD_SIDE}.bin")), downsample("mesh.gltf",
             f"{{in}}/{ODD_STEM}.gltf", "--force"),
             f"{ODD_SIDE}.bin: refusing to overwrite the input file",
             lambda i, o: (i / "mesh.bin").rename(i / f"{ODD_SIDE}.bin")),
        Case("downsample-odd-name-existing-mtl", obj(),
             downsample("mesh.obj", f"{{out}}/{ODD_STEM}.obj"), f"{ODD_SIDE}.mtl: already exists",
             lambda i, o: (o / f"{ODD_SIDE}.mtl").write_bytes(b"keep")),
        Case("downsample-side-files-too-long", obj(),
             downsample("mesh.obj", f"{{out}}/{'b' * 248}.gltf"), "too long for the file system"),
    ]  # fmt: skip


def argument_cases() -> list[Case]:
    cases = [
        ("distance-inf", render("mesh.obj", "{out}/v.png", "--distance", "inf"), "--distance inf"),
        ("distance-nan", render("mesh.obj", "{out}/v.png", "--distance", "nan"), "--distance nan"),
        ("view-negative", render("mesh.obj", "{out}/v.png", "--view", "-1"), "--view -1"),
        ("render-jpg", render("mesh.obj", "{out}/v.jpg"), "use a .png name"),
        ("seed-negative", downsample("mesh.obj", "{out}/s.glb", "--seed", "-1"), "--seed -1"),
        ("scale-1", downsample("mesh.obj", "{out}/s.glb", "--scale", "1"), "--scale"),
        ("scale-huge", downsample("mesh.obj", "{out}/s.glb", "--scale", "1024"), "scale"),
        ("budget-negative", downsample("mesh.obj", "{out}/s.glb", "--time-budget", "-5"),
         "--time-budget"),
        ("steps-zero", downsample("mesh.obj", "{out}/s.glb", "--steps", "0"), "--steps"),
        ("method-unknown", downsample("mesh.obj", "{out}/s.glb", "--method", "nope"), "nope"),
        ("variant-on-direct", downsample("mesh.obj", "{out}/s.glb", "--variant", "full"),
         "only --method geoscaler has variants"),
        ("output-fbx", downsample("mesh.obj", "{out}/s.fbx"), "the output format"),
        ("output-is-input", downsample("mesh.obj", "{in}/mesh.obj", "--force"),
         "refusing to overwrite the input file"),
    ]  # fmt: skip
    return [Case(f"arg-{name}", obj(), argv, expect) for name, argv, expect in cases]


KINDS = {
    "malformed GLB": glb_cases,
    "malformed glTF": gltf_cases,
    "malformed OBJ/MTL": obj_cases,
    "decompression bomb": bomb_cases,
    "NaN, Inf and degenerate geometry": geometry_cases,
    "path trick": path_cases,
    "bad argument": argument_cases,
}
CASES = [replace(case, kind=kind) for kind, cases in KINDS.items() for case in cases()]


def snapshot(folder: Path) -> dict[str, bytes | str]:
    """Every entry under ``folder``: file bytes, or what it is."""
    out: dict[str, bytes | str] = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        if path.is_symlink():
            out[key] = f"link to {os.readlink(path)}"
        elif path.is_file():
            out[key] = path.read_bytes()
        else:
            out[key] = "folder" if path.is_dir() else "special"
    return out


class FolderWatch:
    """What inotify saw change in some folders (a file made, written, renamed or removed, an
    attribute set), transient changes included: a file made and removed at once still shows."""

    MASK = 0x2 | 0x4 | 0x8 | 0x40 | 0x80 | 0x100 | 0x200 | 0x400 | 0x800
    """IN_MODIFY, IN_ATTRIB, IN_CLOSE_WRITE, IN_MOVED_FROM/TO, IN_CREATE, IN_DELETE(_SELF),
    IN_MOVE_SELF: every event but reading and opening."""

    def __init__(self, folders: list[Path]):
        self.libc = ctypes.CDLL(None, use_errno=True)
        self.fd = self.libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        assert self.fd >= 0, os.strerror(ctypes.get_errno())
        self.folders = {}
        for folder in folders:
            watch = self.libc.inotify_add_watch(self.fd, os.fsencode(folder), self.MASK)
            assert watch >= 0, os.strerror(ctypes.get_errno())
            self.folders[watch] = folder

    def changes(self) -> list[str]:
        """``FOLDER/NAME MASK`` of every change since the watch began; ends the watch."""
        data = b""
        try:
            while True:
                data += os.read(self.fd, 65536)
        except BlockingIOError:
            pass
        finally:
            os.close(self.fd)
        out, at = [], 0
        while at < len(data):
            watch, mask, _, size = struct.unpack_from("iIII", data, at)
            name = data[at + 16 : at + 16 + size].rstrip(b"\0").decode(errors="replace")
            out.append(f"{self.folders.get(watch)}/{name} {mask:#x}")
            at += 16 + size
        return out


def run(argv: list[str]) -> int:
    return main(argv, evaluation=ONE_VIEW, optimize=QUICK_OPTIMIZE)


def test_the_corpus_covers_every_kind():
    counts = {kind: sum(case.kind == kind for case in CASES) for kind in KINDS}
    assert min(counts.values()) >= 5, counts
    assert len(CASES) >= 60 and len({case.name for case in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[case.name for case in CASES])
def test_hostile_input_is_refused_in_one_line(case: Case, tmp_path, capsys, monkeypatch):
    inputs, out = tmp_path / "in", tmp_path / "out"
    inputs.mkdir()
    out.mkdir()
    for name, data in case.files.items():
        (inputs / name).write_bytes(data)
    if case.prepare:
        case.prepare(inputs, out)
    monkeypatch.chdir(tmp_path)  # a file written to a relative path would show up here
    before = snapshot(tmp_path)
    argv = [a.replace("{in}", str(inputs)).replace("{out}", str(out)) for a in case.argv]
    watch = FolderWatch([tmp_path, inputs, out])
    status = run(argv)
    assert watch.changes() == []  # not even a file made and removed at once
    captured = capsys.readouterr()
    assert status == 2, captured.out + captured.err
    assert captured.err.startswith("geoscaler: error: ") and captured.err.count("\n") == 1
    assert case.expect in captured.err
    assert "Traceback" not in captured.err + captured.out
    assert snapshot(tmp_path) == before  # inputs unchanged, nothing written anywhere
    assert not Path("/proc/geoscaler.png").exists() and not Path("/sys/r.json").exists()


STRACE = shutil.which("strace")
WRITE_CALL = re.compile(
    r"\bopen(at)?\(.*O_(CREAT|TMPFILE|WRONLY|RDWR|TRUNC)"
    r"|\b(mkdir|rmdir|rename|unlink|link|symlink|creat|truncate|chmod|chown|utime)\w*\("
)
"""A system call that makes, changes or removes something, as ``strace`` prints it."""


def traced_changes(argv: list[str], folder: Path) -> tuple[int, str, list[str]]:
    """The exit status and stderr of ``python argv``, and every system call of it (child
    processes included) that makes, changes or removes something in ``folder``, as
    ``strace -f -e trace=file`` shows it."""
    log = folder.parent / f"{folder.name}.strace"
    command = [STRACE, "-f", "-qq", "-e", "trace=file", "-o", str(log), sys.executable, *argv]
    done = subprocess.run(command, cwd=folder.parent, capture_output=True, text=True, timeout=300)
    inside = (f'"{folder}"', f'"{folder}/')
    lines = log.read_text(errors="replace").splitlines()
    changes = [line for line in lines if any(i in line for i in inside) and WRITE_CALL.search(line)]
    return done.returncode, done.stderr, changes


@pytest.mark.skipif(STRACE is None, reason="strace is not installed")
def test_a_refused_output_is_never_touched_not_even_for_a_moment(tmp_path):
    """``strace`` shows no file made, written or removed in the input folder by a refused
    command (a probe made and removed at once included); the last check of a command that
    goes on, asked here directly, shows as an unnamed file (``O_TMPFILE``), nothing else."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    files = obj(QUAD_OBJ.replace("mesh.mtl", "s.mtl"))
    files["s.mtl"] = files.pop("mesh.mtl")
    for name, data in files.items():
        (inputs / name).write_bytes(data)
    before = snapshot(inputs)
    cli = ["-m", "geoscaler.cli"]
    refused = [
        ["render", "mesh.obj", "-o", "tex.png", "--force"],
        ["downsample", "mesh.obj", "-o", "out.glb", "--report", "s.mtl", "--force"],
        ["downsample", "mesh.obj", "-o", "s.obj", "--force"],  # its s.mtl is the input's
    ]
    for argv in refused:
        argv = [str(inputs / a) if "." in a else a for a in argv]
        status, err, changes = traced_changes([*cli, *argv], inputs)
        assert status == 2 and "refusing to overwrite the input file" in err, err
        assert changes == [], argv
        assert snapshot(inputs) == before
    probe = "import sys; from geoscaler.io import check_output as c; c(sys.argv[1], force=False, "
    probe += "probe=True)"
    status, err, changes = traced_changes(["-c", probe, str(inputs / "new.glb")], inputs)
    assert status == 0, err
    assert len(changes) == 1 and "O_TMPFILE" in changes[0] and f'"{inputs}"' in changes[0]
    assert snapshot(inputs) == before


def test_the_last_check_tries_a_file_that_never_appears(tmp_path):
    """Without ``probe`` the output check only looks; with it, the one file it makes has no
    name in the folder (inotify sees an unnamed file closed, nothing made or removed)."""
    watch = FolderWatch([tmp_path])
    check_outputs([tmp_path / "a.glb", tmp_path / "a.json"], force=False)
    assert watch.changes() == []
    watch = FolderWatch([tmp_path])
    check_outputs([tmp_path / "a.glb", tmp_path / "a.json"], force=False, probe=True)
    changes = watch.changes()
    assert len(changes) == 1 and re.fullmatch(rf"{re.escape(str(tmp_path))}/#\d+ 0x8", changes[0])
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- deep node graphs


def test_a_10000_level_node_chain_loads_in_place(tmp_path):
    """The glTF specification sets no depth limit; the node graph is walked without recursion
    and every level's transform is applied."""
    doc, blob = quad()
    turning_chain(doc)
    (tmp_path / "mesh.glb").write_bytes(glb(doc, blob))
    mesh = load_mesh(tmp_path / "mesh.glb")
    corners = {tuple(uv): p for uv, p in zip(np.round(mesh.uvs, 6), mesh.positions, strict=True)}
    placed = [corners[uv] for uv in [(0, 0), (1, 0), (1, 1), (0, 1)]]
    np.testing.assert_allclose(placed, CHAIN_POSITIONS, atol=1e-9)


def test_a_10000_level_node_chain_downsamples(tmp_path, capsys):
    doc, blob = quad()
    turning_chain(doc)
    (tmp_path / "mesh.glb").write_bytes(glb(doc, blob))
    out = tmp_path / "small.glb"
    argv = [a.replace("{in}", str(tmp_path)) for a in downsample("mesh.glb", str(out))]
    assert run([*argv, "--scale", "2"]) == 0, capsys.readouterr().err
    small = load_mesh(out)
    assert small.materials[0].base_color_texture.shape == (2, 4, 3)
    np.testing.assert_allclose(np.unique(small.positions, axis=0), CHAIN_POSITIONS[[1, 0, 2, 3]])


# ----------------------------------------------------------------------------- what is written


@pytest.mark.parametrize("stem", ["ö ut ☃ 雪", "100%", "a%41b", "a#b", "-s", "[x] y"])
@pytest.mark.parametrize("suffix", [".gltf", ".obj", ".glb"])
def test_odd_output_names_load_again(tmp_path, stem: str, suffix: str):
    """Names with spaces, non-ASCII, '%' and '#': the glTF URIs are percent-encoded as the
    specification says and decoded on load; OBJ names are written as they are."""
    path = tmp_path / f"{stem}{suffix}"
    save_mesh(two_material_mesh(), path)
    loaded = load_mesh(path)
    assert len(loaded.faces) == 4 and len(loaded.materials) == 2


def trimesh_textures(path: Path) -> list[tuple[int, int]]:
    """The size of each base-colour image trimesh finds for the geometries of ``path``."""
    sizes = []
    for geometry in trimesh.load(path, process=False).geometry.values():
        material = geometry.visual.material
        image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
        if image is not None:
            sizes.append(image.size)
    return sizes


@pytest.mark.parametrize(("suffix", "side"), [(".gltf", ".bin"), (".obj", ".mtl")])
def test_side_files_of_an_odd_name_are_found_by_every_loader(tmp_path, suffix: str, side: str):
    """The mesh file keeps the user's name; the files beside it are named from it in ASCII
    letters, digits, '.', '_' and '-', so glTF URIs need no percent-encoding and trimesh,
    which does not decode them, finds the files too."""
    path = tmp_path / f"{ODD_STEM}{suffix}"
    mesh = two_material_mesh()
    written = save_mesh(mesh, path)
    image = f"{ODD_SIDE}_0_basecolor.png"
    assert [p.name for p in written] == [image, f"{ODD_SIDE}{side}", path.name]
    loaded = load_mesh(path)
    assert len(loaded.faces) == 4 and [m.name for m in loaded.materials] == ["painted", "plain"]
    np.testing.assert_array_equal(
        loaded.materials[0].base_color_texture, mesh.materials[0].base_color_texture
    )
    assert trimesh_textures(path) == [(8, 4)]
    if suffix == ".gltf":
        doc = json.loads(path.read_text())
        assert doc["buffers"][0]["uri"] == f"{ODD_SIDE}.bin" and doc["images"][0]["uri"] == image
    else:
        assert f"mtllib {ODD_SIDE}.mtl\n" in path.read_text()
        assert f"map_Kd {image}\n" in (tmp_path / f"{ODD_SIDE}.mtl").read_text()


def test_a_downsample_to_an_odd_gltf_name_is_valid_and_loads(tmp_path, capsys):
    """The whole command, checked by the Khronos glTF-Validator, trimesh and GeoScaler."""
    for name, data in obj(texture=png_bytes(np.tile(TEXTURE, (4, 4, 1)))).items():
        (tmp_path / name).write_bytes(data)
    out = tmp_path / f"{ODD_STEM}.gltf"
    argv = [a.replace("{in}", str(tmp_path)) for a in downsample("mesh.obj", str(out))]
    assert run(argv) == 0, capsys.readouterr().err
    written = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(ODD_SIDE))
    assert written == [f"{ODD_SIDE}.bin", f"{ODD_SIDE}_tex.png"]
    assert trimesh_textures(out) == [(8, 4)]
    assert load_mesh(out).materials[0].base_color_texture.shape == (4, 8, 3)
    try:
        _, reports = validate([out])
    except ValidatorMissing as missing:
        pytest.skip(str(missing))
    assert reports[str(out)]["errors"] == 0, reports[str(out)]["messages"]


def test_written_gltf_passes_the_loaders_checks_and_info_json_is_strict(tmp_path, capsys):
    """What GeoScaler writes it also reads, with every check above; info --json has no NaN."""
    path = tmp_path / "two.gltf"
    save_mesh(two_material_mesh(), path)
    doc = json.loads(path.read_text())
    assert doc["accessors"][0]["min"] == [0, 0, 0] and doc["accessors"][0]["max"] == [2, 1, 0]
    assert run(["info", str(path), "--json"]) == 0
    text = capsys.readouterr().out

    def refuse(name):
        raise AssertionError(f"{name} in info --json")

    info_doc = json.loads(text, parse_constant=refuse)
    assert info_doc["faces"] == 4


def test_a_downsample_whose_report_cannot_be_written_leaves_no_output(
    tmp_path, capsys, monkeypatch
):
    """The report is written after the mesh: when writing it fails, the mesh goes too."""
    import geoscaler.io
    import geoscaler.report.runner

    folder, out = tmp_path / "in", tmp_path / "out"
    folder.mkdir()
    out.mkdir()
    texture = np.random.default_rng(0).integers(0, 256, (32, 32, 3), np.uint8)
    for name, data in obj(texture=png_bytes(texture)).items():
        (folder / name).write_bytes(data)
    real = geoscaler.io.write_atomically

    def full_disk(path, write):
        if Path(path).suffix == ".json":
            raise geoscaler.io.atomic.GeoscalerError(f"{path}: writing it failed (disk full)")
        return real(path, write)

    monkeypatch.setattr(geoscaler.report.runner, "write_atomically", full_disk)
    argv = downsample("mesh.obj", "{out}/s.glb", "--report", "{out}/r.json")
    argv = [a.replace("{in}", str(folder)).replace("{out}", str(out)) for a in argv]
    assert run(argv) == 2
    assert "r.json: writing it failed" in capsys.readouterr().err
    assert list(out.iterdir()) == []


# ----------------------------------------------------------------------------- property test

NUMBER = re.compile(rb"-?\d+(\.\d+)?(e[-+]?\d+)?")
REPLACEMENTS = [b"0", b"-1", b"nan", b"1e30", b"99999", b"-99999", b"inf", b"x", b"3.5", b"1e-40"]


def mutate(data: bytes, rng: random.Random, text: bool) -> bytes:
    """One to four random edits: flipped bytes, a cut, a duplicated slice, an inserted run, or
    (for text) a number replaced by a hostile one."""
    data = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        kind = rng.choice(["flip", "cut", "duplicate", "insert", "number", "number"])
        if not data:
            break
        at = rng.randrange(len(data))
        if kind == "flip":
            data[at] ^= 1 << rng.randrange(8)
        elif kind == "cut":
            del data[at : at + rng.randint(1, 64)]
        elif kind == "duplicate":
            data[at:at] = data[at : at + rng.randint(1, 64)]
        elif kind == "insert":
            data[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        else:
            numbers = list(NUMBER.finditer(bytes(data)))
            if numbers:
                match = rng.choice(numbers)
                new = rng.choice(REPLACEMENTS) if text else str(rng.randint(0, 99999)).encode()
                data[match.start() : match.end()] = new
    return bytes(data)


HOSTILE_VALUES = [0, -1, 1, 2, 3, 4, 7, 12, 2**31, 1e30, -0.5, 0.5, "x", [], {}, [1, 2], None]


def mutate_document(doc: dict, rng: random.Random) -> None:
    """One to three values anywhere in a glTF document replaced by hostile ones (None: the
    key or item removed), or nudged by one."""
    for _ in range(rng.randint(1, 3)):
        places = []
        stack = [doc]
        while stack:
            node = stack.pop()
            keys = node.keys() if isinstance(node, dict) else range(len(node))
            for key in keys:
                places.append((node, key))
                if isinstance(node[key], dict | list):
                    stack.append(node[key])
        if not places:
            return
        node, key = rng.choice(places)
        value = rng.choice(HOSTILE_VALUES)
        if isinstance(node[key], int | float) and rng.random() < 0.3:
            node[key] = node[key] + rng.choice([-1, 1])
        elif value is None:
            del node[key]
        else:
            node[key] = value


def flip_bytes(data: bytes, rng: random.Random) -> bytes:
    """One to eight bits flipped: the length, and so every offset, stays."""
    out = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
    return bytes(out)


def valid_files() -> dict[str, dict[str, bytes]]:
    doc, blob = quad()
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = [1, 0.5, 0.25, 1]
    doc["nodes"] = [{"children": [1], "translation": [1, 2, 3]}, {"mesh": 0, "scale": [2, 2, 2]}]
    return {"glb": {"mesh.glb": glb(doc, blob)}, "obj": obj()}


@pytest.mark.parametrize("form", ["glb", "obj"])
def test_mutated_files_give_only_clean_outcomes(form: str, tmp_path, capsys):
    """200 seeded mutations of a valid file each: info succeeds with strict JSON, or refuses
    in one line with status 2; never a traceback or another status."""
    files = valid_files()[form]
    main_name = next(name for name in files if name.startswith("mesh."))
    rng = random.Random(16)
    outcomes = {0: 0, 2: 0}
    for trial in range(200):
        folder = tmp_path / str(trial)
        folder.mkdir()
        for name, data in files.items():
            if name == "mesh.glb" and trial % 3:  # the document or the bytes edited, repacked
                doc, blob = quad()
                if trial % 3 == 1:
                    mutate_document(doc, rng)
                else:  # positions, UVs and indices; the PNG's checksums catch its flips
                    geometry = doc["bufferViews"][3]["byteOffset"]
                    blob = flip_bytes(blob[:geometry], rng) + blob[geometry:]
                data = glb(doc, blob)
            elif name == main_name or rng.random() < 0.2:
                data = mutate(data, rng, text=name.endswith((".obj", ".mtl")))
            (folder / name).write_bytes(data)
        status = run(["info", str(folder / main_name), "--json"])
        captured = capsys.readouterr()
        assert status in outcomes, (trial, captured.err)
        outcomes[status] += 1
        if status == 0:
            json.loads(captured.out, parse_constant=lambda name: pytest.fail(f"{name} in JSON"))
        else:
            assert captured.err.startswith("geoscaler: error: ") and captured.err.count("\n") == 1
    assert outcomes[0] > 10 and outcomes[2] > 10  # the mutations reach both outcomes
