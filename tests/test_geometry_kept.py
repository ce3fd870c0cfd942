"""What `geoscaler downsample` writes keeps the input's geometry, corner by corner.

Every face corner of the output stands where the input's does in world space, with the same
shading normal, tangent, vertex colour and second UV set, and (where the layout is kept) the
same UVs, to float precision. Both files are read by :mod:`corners`, which welds nothing, so a
loader that merged vertices and averaged their normals (rounding off hard edges) is seen.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import mesh_params
from corners import Corners, matched_faces, world_corners
from io_assets import FLOAT, UNSIGNED_SHORT, _Blob, encode, smooth

import geoscaler.cli
from geoscaler.io import load_mesh, save_mesh
from geoscaler.methods import MethodResult
from geoscaler.pipeline.downsampling import export
from geoscaler.procedural import scan_mesh
from geoscaler.protocol import Evaluation
from geoscaler.resize.sizes import size_plan
from geoscaler.uv.atlas import repack

ONE_VIEW = Evaluation.quick((0,))
# One cached training view and one step: the geometry written does not depend on how long the
# textures were trained.
ONE_STEP = {"pool_views": 1, "views_per_step": 1, "validate_every": 1}
METHODS = {
    "lanczos": ["--method", "lanczos"],
    "direct-keep": ["--method", "direct", "--uv", "keep", "--steps", "1"],
    "direct-repack": ["--method", "direct", "--uv", "repack", "--steps", "1"],
}
FLOAT_PRECISION = 1e-6  # relative to the mesh's extent for positions; absolute for unit vectors


def downsample(mesh: Path, out: Path, method: str) -> Path:
    status = geoscaler.cli.main(
        ["downsample", str(mesh), "--scale", "4", *METHODS[method], "-o", str(out),
         "--report", str(out.with_suffix(".report.json"))],
        evaluation=ONE_VIEW,
        optimize=ONE_STEP,
    )  # fmt: skip
    assert status == 0
    return out


def assert_corners_kept(before: Corners, out: Path) -> None:
    """Every attribute of every corner of ``before`` that the format of ``out`` can hold is in
    ``out`` (OBJ holds no tangents, colours or second UVs). The UVs, and the tangents that
    follow them, may differ only where the report says a new layout shipped (a viewer computes
    tangents where a file has none)."""
    after = world_corners(out)
    order, corner = matched_faces(before, after)

    def assert_kept(values: np.ndarray, written: np.ndarray | None, atol: float) -> None:
        assert written is not None
        kept = np.take_along_axis(values[order], corner[:, :, None], axis=1)
        np.testing.assert_allclose(kept, written, rtol=0, atol=atol)

    extent = float(np.ptp(before.positions.reshape(-1, 3), axis=0).max())
    assert_kept(before.positions, after.positions, FLOAT_PRECISION * extent)
    if before.normals is not None:
        assert_kept(before.normals, after.normals, FLOAT_PRECISION)
    new_layout = repacked(out.with_suffix(".report.json"))
    if not new_layout:
        assert_kept(before.uvs, after.uvs, FLOAT_PRECISION)
    if out.suffix == ".obj":
        assert after.tangents is None and after.attributes == {}
        return
    if before.tangents is not None and not (new_layout and after.tangents is None):
        assert_kept(before.tangents, after.tangents, FLOAT_PRECISION)
    assert after.attributes.keys() == before.attributes.keys()
    for name, values in before.attributes.items():
        assert_kept(values, after.attributes[name], FLOAT_PRECISION)


def repacked(report: Path) -> bool:
    """Whether the downsample shipped a new UV layout: the method's result on a layout other
    than the mesh's own."""
    document = json.loads(report.read_text())
    details = document["details"]
    return details.get("layout_used", "keep") != "keep" and details["shipped"] == document["method"]


# A box with hard edges: each side its own four corners, sharing positions and UVs with the
# sides beside it but not their normals, as an exporter writes flat-shaded panels whose UVs
# run on across the edges.
SIDES = [  # (normal, tangent): the side's plane is spanned by the tangent and their cross
    ((1, 0, 0), (0, 0, -1)), ((-1, 0, 0), (0, 0, 1)), ((0, 1, 0), (1, 0, 0)),
    ((0, -1, 0), (1, 0, 0)), ((0, 0, 1), (1, 0, 0)), ((0, 0, -1), (-1, 0, 0)),
]  # fmt: skip


def hard_box() -> dict[str, np.ndarray]:
    """Per-vertex arrays of the box, 24 vertices: positions (cube corners), normals,
    tangents, colours, two UV sets (glTF's v down) and 36 indices. The UVs are a function of
    the position, so the three corners at each cube corner share position and UV."""
    rows: dict[str, list] = {k: [] for k in ("POSITION", "NORMAL", "TANGENT", "COLOR_0",
                                              "TEXCOORD_0", "TEXCOORD_1")}  # fmt: skip
    indices = []
    for side, (normal, tangent) in enumerate(SIDES):
        n, t = np.array(normal, float), np.array(tangent, float)
        b = np.cross(n, t)
        start = len(rows["POSITION"])
        for u, v in ((0, 0), (1, 0), (1, 1), (0, 1)):
            rows["POSITION"].append(n + (2 * u - 1) * t + (2 * v - 1) * b)
            rows["NORMAL"].append(n)
            rows["TANGENT"].append([*t, 1.0 if side % 2 else -1.0])
            rows["COLOR_0"].append([0.2 * side % 1, u, v, 1.0])
            x, y, z = rows["POSITION"][-1]
            rows["TEXCOORD_0"].append([0.5 + 0.3 * x + 0.1 * z, 0.5 - 0.3 * y - 0.05 * z])
            rows["TEXCOORD_1"].append([0.5 * u, 0.25 * side / 6 + 0.5 * v])
        indices += [start, start + 1, start + 2, start, start + 2, start + 3]
    arrays = {k: np.array(v, np.float32) for k, v in rows.items()}
    arrays["indices"] = np.array(indices, np.uint16)
    return arrays


PLAIN = ("POSITION", "NORMAL", "TEXCOORD_0")
"""The attributes of a plain export (Poly Haven's): whatever else a vertex carries (a
tangent, a colour) may tell the sides' corners apart and hide a weld by position and UV."""
EVERY = (*PLAIN, "TANGENT", "COLOR_0", "TEXCOORD_1")


def write_hard_boxes(folder: Path, names: tuple[str, ...] = EVERY) -> Path:
    """``boxes.gltf``: the box with the attributes ``names`` under three nodes (plain;
    turned, scaled unevenly and moved, below a parent; mirrored), with a base colour and a
    normal map."""
    box, blob = hard_box(), _Blob()
    attributes = {}
    for name in names:
        values = box[name]
        kind = {2: "VEC2", 3: "VEC3", 4: "VEC4"}[values.shape[1]]
        bounds = {"min": values.min(0).tolist(), "max": values.max(0).tolist()}
        attributes[name] = blob.accessor(values, kind, FLOAT, **(bounds if name ==
                                                                   "POSITION" else {}))  # fmt: skip
    indices = blob.accessor(box["indices"], "SCALAR", UNSIGNED_SHORT)
    normal_map = np.dstack([smooth(64, 64, 5)[..., :2], np.full((64, 64), 255, np.uint8)])
    images = {"colour.png": encode(smooth(64, 64, 6), "PNG"), "normal.png": encode(normal_map,
                                                                                    "PNG")}
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 3]}],
        "nodes": [
            {"mesh": 0},
            {"translation": [4, 0, 0], "children": [2]},
            {"mesh": 0, "rotation": [0.0, 0.3826834, 0.0, 0.9238795], "scale": [1, 2, 0.5]},
            {"mesh": 0, "translation": [0, 4, 0], "scale": [-1, 1, 1]},
        ],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": indices,
                                    "material": 0}]}],
        "materials": [{"name": "panel", "pbrMetallicRoughness": {"baseColorTexture":
                       {"index": 0}}, "normalTexture": {"index": 1}}],
        "textures": [{"source": 0}, {"source": 1}],
        "images": [{"uri": name} for name in images],
        "buffers": [{"byteLength": len(blob.data), "uri": "boxes.bin"}],
        "bufferViews": blob.views,
        "accessors": blob.accessors,
    }  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "boxes.bin").write_bytes(blob.data)
    for name, data in images.items():
        (folder / name).write_bytes(data)
    (folder / "boxes.gltf").write_text(json.dumps(doc))
    return folder / "boxes.gltf"


def write_hard_box_obj(folder: Path) -> Path:
    """``box.obj``: the box with shared ``v`` and ``vt`` lists and a ``vn`` per side, so
    corners of one position and UV differ only in their ``vn`` index."""
    box = hard_box()
    positions, index = np.unique(box["POSITION"], axis=0, return_inverse=True)
    uvs, uv_index = np.unique(box["TEXCOORD_0"], axis=0, return_inverse=True)
    lines = ["mtllib box.mtl"]
    lines += [f"v {x:g} {y:g} {z:g}" for x, y, z in positions]
    lines += [f"vt {u:g} {1 - v:g}" for u, v in uvs]
    lines += [f"vn {x:g} {y:g} {z:g}" for (x, y, z), _ in SIDES]
    lines.append("usemtl panel")
    for a, b, c in box["indices"].reshape(-1, 3):
        corners = [f"{index.ravel()[k] + 1}/{uv_index.ravel()[k] + 1}/{k // 4 + 1}"
                   for k in (a, b, c)]  # fmt: skip
        lines.append("f " + " ".join(corners))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "box.obj").write_text("\n".join(lines) + "\n")
    (folder / "box.mtl").write_text("newmtl panel\nmap_Kd colour.png\n")
    (folder / "colour.png").write_bytes(encode(smooth(64, 64, 6), "PNG"))
    return folder / "box.obj"


SOURCES = {
    "gltf": write_hard_boxes,
    "plain-gltf": lambda folder: write_hard_boxes(folder, PLAIN),
    "obj": write_hard_box_obj,
}


@pytest.mark.parametrize("method", list(METHODS))
@pytest.mark.parametrize("suffix", [".glb", ".obj"])
@pytest.mark.parametrize("source", list(SOURCES))
def test_hard_edged_boxes_keep_every_corner(tmp_path, source, suffix, method):
    mesh = SOURCES[source](tmp_path / "in")
    out = downsample(mesh, tmp_path / f"out{suffix}", method)
    before = world_corners(mesh)
    assert before.normals is not None
    assert_corners_kept(before, out)


def test_the_boxes_hard_edges_are_what_the_test_sees(tmp_path):
    """Every face corner of the boxes shares its position and UV with corners of the two other
    sides that meet there, whose normals are at right angles to its own: a loader that welds
    by position and UV alone turns all of them."""
    corners = world_corners(write_hard_boxes(tmp_path, PLAIN))
    rows = np.concatenate([corners.positions, corners.uvs], axis=2).reshape(-1, 5)
    normals = corners.normals.reshape(-1, 3)
    _, group = np.unique(rows.round(6), axis=0, return_inverse=True)
    assert group.max() + 1 == 3 * 8  # 3 nodes x 8 cube corners
    for g in range(3 * 8):
        assert len(np.unique(normals[group.ravel() == g].round(6), axis=0)) == 3


@pytest.fixture(scope="module")
def demo_asset(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("demo") / "pebble.glb"
    save_mesh(scan_mesh(level=3, texture_size=256), path)
    return path


@pytest.mark.parametrize("method", list(METHODS))
def test_the_demo_asset_keeps_every_corner(tmp_path, demo_asset, method):
    out = downsample(demo_asset, tmp_path / "out.glb", method)
    assert_corners_kept(world_corners(demo_asset), out)


@pytest.mark.parametrize("method", list(METHODS))
@pytest.mark.parametrize("mesh", mesh_params())
def test_every_development_mesh_keeps_every_corner(tmp_path, mesh, method):
    out = downsample(mesh, tmp_path / f"out{mesh.suffix if mesh.suffix != '.gltf' else '.glb'}",
                     method)  # fmt: skip
    assert_corners_kept(world_corners(mesh), out)


def test_a_repacked_layout_keeps_every_corner_but_its_uvs(tmp_path):
    """A new layout written as the job writes it (the export of a result carrying the atlas):
    new UVs, every other corner attribute as it was; the boxes' normal map keeps their charts
    from turning, so the tangents stay valid and are kept."""
    source = write_hard_boxes(tmp_path / "in", EVERY)
    mesh = load_mesh(source)
    every_face = [torch.arange(len(mesh.faces)).repeat_interleave(20)]
    atlas = repack(mesh, [(16, 16)], every_face, 256)
    assert atlas.moved
    texture = np.zeros((16, 16, 3), np.uint8)
    out = tmp_path / "out.glb"
    export(mesh, MethodResult([texture], atlas.uvs, layout=atlas), out, size_plan({"all": 4}, {}),
           "direct")  # fmt: skip
    before, after = world_corners(source), world_corners(out)
    order, corner = matched_faces(before, after, by_uv=False)

    def kept(values: np.ndarray) -> np.ndarray:
        return np.take_along_axis(values[order], corner[:, :, None], axis=1)

    np.testing.assert_allclose(kept(before.positions), after.positions, atol=1e-5)
    for name in ("normals", "tangents"):
        np.testing.assert_allclose(kept(getattr(before, name)), getattr(after, name), atol=1e-6)
    for name, values in before.attributes.items():
        np.testing.assert_allclose(kept(values), after.attributes[name], atol=1e-6)
    assert np.abs(kept(before.uvs) - after.uvs).max() > 0.1  # the new layout is written
