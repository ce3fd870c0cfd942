"""Loading mesh files: the development meshes, every quirk and error case."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import mesh_params
from mesh_support import (
    DROPPED_MAPS,
    FORMATS,
    QUAD_OBJ,
    TEXTURE,
    assert_same_mesh,
    png_bytes,
    signed_volume,
    write_gltf,
    write_obj_asset,
)
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.io import image_to_texture, load_mesh, save_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.procedural import demo_mesh

# ----------------------------------------------------------------------------- dev meshes


@pytest.fixture(scope="module", params=mesh_params())
def dev_mesh(request) -> TexturedMesh:
    """Each development mesh, loaded once per module."""
    return load_mesh(request.param)


def test_dev_mesh_loads_with_consistent_arrays(dev_mesh: TexturedMesh):
    mesh = dev_mesh
    count = len(mesh.positions)
    assert mesh.positions.shape == (count, 3) and mesh.positions.dtype == np.float32
    assert mesh.uvs.shape == (count, 2) and mesh.uvs.dtype == np.float32
    assert mesh.normals.shape == (count, 3) and mesh.normals.dtype == np.float32
    assert mesh.faces.dtype == np.int64 and mesh.faces.min() >= 0 and mesh.faces.max() < count
    assert np.array_equal(np.unique(mesh.faces), np.arange(count)), "unreferenced vertices"
    assert mesh.face_material.max() < len(mesh.materials)
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1, atol=1e-5)
    # Vertex rows are distinct (position, UV, normal, attributes); points distinct positions.
    rows = np.concatenate([mesh.positions, mesh.uvs, mesh.normals, *mesh.attributes.values()], 1)
    assert len(np.unique(rows, axis=0)) == count
    assert len(np.unique(mesh.positions, axis=0)) == mesh.num_points
    np.testing.assert_array_equal(mesh.points()[mesh.vertex_to_point], mesh.positions)
    textures = [m.base_color_texture for m in mesh.materials if m.base_color_texture is not None]
    assert textures and all(t.dtype == np.uint8 and t.shape[2] in (3, 4) for t in textures)
    assert Path(mesh.source_path).resolve() in mesh.source_files
    assert all(Path(p).is_file() for p in mesh.source_files)


def test_dev_mesh_uv_convention_matches_texture_across_seams(dev_mesh: TexturedMesh):
    """Across a UV seam both vertices of a 3D point show the same colour, in our convention.

    "The same" is measured against two kinds of disagreement: the same pairs read with ``v``
    flipped (the glTF convention), and unrelated seam vertices read in ours. Either alone can
    be flat on a real mesh: on ycb_peach, whose atlas is mostly one empty colour, both flipped
    samples land in that emptiness and agree; on spot every seam runs through one flat colour,
    so unrelated seam vertices agree too. Were our convention the wrong one, the pairs would
    disagree like unrelated vertices while the flipped reading agreed, and this would fail.
    """
    mesh = dev_mesh
    texture = mesh.materials[mesh.face_material[0]].base_color_texture
    order = np.argsort(mesh.vertex_to_point, kind="stable")
    same = mesh.vertex_to_point[order[1:]] == mesh.vertex_to_point[order[:-1]]
    a, b = order[:-1][same], order[1:][same]

    def sample(uv: np.ndarray, flip: bool) -> np.ndarray:
        height, width = texture.shape[:2]
        u, v = np.mod(uv[:, 0], 1), np.mod(uv[:, 1], 1)
        rows = np.clip((((1 - v) if flip else v) * height).astype(int), 0, height - 1)
        return texture[rows, np.clip((u * width).astype(int), 0, width - 1)].astype(float)

    def disagreement(x: np.ndarray, y: np.ndarray, flip: bool = True) -> float:
        return float(np.abs(sample(mesh.uvs[x], flip) - sample(mesh.uvs[y], flip)).mean())

    strangers = b[np.random.default_rng(0).permutation(len(b))]
    ours = disagreement(a, b)
    assert ours < 0.5 * max(disagreement(a, b, flip=False), disagreement(a, strangers))


@pytest.mark.filterwarnings(DROPPED_MAPS)
@pytest.mark.parametrize("suffix", FORMATS)
def test_dev_mesh_round_trips(dev_mesh: TexturedMesh, suffix: str, tmp_path: Path):
    # A small texture keeps PNG encoding fast; it is also what a downsampler saves. PNG: the
    # texels come back exactly (a JPEG source's map would otherwise stay a lossy JPEG).
    small = np.ascontiguousarray(dev_mesh.materials[0].base_color_texture[::16, ::16])
    mesh = dev_mesh.with_texture(0, small)
    written = save_mesh(mesh, tmp_path / f"out{suffix}", image_format="png")
    assert written[-1] == tmp_path / f"out{suffix}"
    assert sorted(tmp_path.iterdir()) == sorted(written), "temporary files left behind"
    assert_same_mesh(load_mesh(written[-1]), mesh)


def test_dev_mesh_quirks():
    """What the development meshes are known to need (see each folder's meta.json)."""
    found = {p.values[0].parent.name: p.values[0] for p in mesh_params() if p.values[0]}
    if not found:
        pytest.skip("no development meshes")
    if "ycb_mug_ig" in found:  # MeshLab: Kd 0.75 beside map_Kd, Tr 1, duplicated v lines
        mug = load_mesh(found["ycb_mug_ig"])
        np.testing.assert_array_equal(mug.materials[0].base_color_factor, 1)
        v_lines = found["ycb_mug_ig"].read_text().count("\nv ")
        assert mug.num_points < v_lines  # repeated positions welded into one point
    if "spot" in found:  # UVs slightly outside [0, 1] are kept as they are
        spot = load_mesh(found["spot"])
        assert spot.uvs.min() < 0 and spot.uvs.max() > 1
    if "gso_chefmate_8_frypan" in found:  # a vn per face: flat shading, kept face by face
        pan = load_mesh(found["gso_chefmate_8_frypan"])
        corner_normals = pan.normals[pan.faces]
        np.testing.assert_array_equal(corner_normals, corner_normals[:, :1].repeat(3, axis=1))
        assert len(pan.positions) > 2 * len(pan.faces)  # corners weld only within a plane


# ----------------------------------------------------------------------------- textures


def palette_image(transparent: bool) -> Image.Image:
    image = Image.new("P", (2, 1))
    image.putpalette([255, 0, 0, 0, 0, 255])
    image.putpixel((1, 0), 1)
    if transparent:
        image.info["transparency"] = 1
    return image


@pytest.mark.parametrize(
    ("image", "expected"),
    [
        (Image.fromarray(np.array([[0, 128, 255]], np.uint8)), [[[0] * 3, [128] * 3, [255] * 3]]),
        (Image.fromarray(np.array([[[10, 200]]], np.uint8), "LA"), [[[10, 10, 10, 200]]]),
        (Image.new("1", (2, 1), 1), [[[255] * 3, [255] * 3]]),
        (palette_image(False), [[[255, 0, 0], [0, 0, 255]]]),
        (palette_image(True), [[[255, 0, 0, 255], [0, 0, 255, 0]]]),
        (
            Image.fromarray(np.array([[0, 257, 32896, 65535]], np.uint16)),
            [[[0] * 3, [1] * 3, [128] * 3, [255] * 3]],
        ),
        (
            Image.frombytes("I;16B", (2, 1), np.array([514, 65535], ">u2").tobytes()),
            [[[2] * 3, [255] * 3]],
        ),
        (Image.fromarray(np.array([[0, 65535]], np.int32), "I"), [[[0] * 3, [255] * 3]]),
        (Image.fromarray(np.array([[[1, 2, 3, 4]]], np.uint8), "RGBA"), [[[1, 2, 3, 4]]]),
    ],
    ids=["L", "LA", "1", "P", "P-transparent", "I;16", "I;16B", "I", "RGBA"],
)
def test_image_to_texture_converts_modes(image: Image.Image, expected: list):
    texture = image_to_texture(image)
    assert texture.dtype == np.uint8
    np.testing.assert_array_equal(texture, np.array(expected, dtype=np.uint8))


def test_image_to_texture_refuses_float_images():
    with pytest.raises(ValueError, match="'F'"):
        image_to_texture(Image.new("F", (1, 1)))


@pytest.mark.parametrize("mode", ["L", "LA", "P", "I;16", "RGBA"])
def test_texture_modes_load_through_obj(tmp_path: Path, mode: str):
    if mode == "I;16":
        image = Image.fromarray(np.array([[0, 65535], [257, 32896]], np.uint16))
        expected = [[0, 255], [1, 128]]
    else:
        image = Image.fromarray(TEXTURE).convert(mode)
        expected = None
    mesh = load_mesh(write_obj_asset(tmp_path, texture=image))
    texture = mesh.materials[0].base_color_texture
    assert texture.shape[2] == (4 if mode in ("LA", "RGBA") else 3)
    if expected is not None:
        np.testing.assert_array_equal(texture[..., 0], expected)


# ----------------------------------------------------------------------------- OBJ quirks


def test_obj_texture_is_the_colour_and_tr_is_ignored(tmp_path: Path):
    mtl = "newmtl mat\nKd 0.5 0.25 0.75\nTr 1.000000\nmap_Kd -s 1 1 1 tex.png   \n"
    mesh = load_mesh(write_obj_asset(tmp_path, mtl=mtl))
    np.testing.assert_array_equal(mesh.materials[0].base_color_factor, [1, 1, 1, 1])
    np.testing.assert_array_equal(mesh.materials[0].base_color_texture, TEXTURE)
    np.testing.assert_array_equal(mesh.uvs[mesh.faces[0]], [[0, 0], [1, 0], [1, 1]])


def test_obj_untextured_material_and_faces_without_material(tmp_path: Path):
    obj = QUAD_OBJ.replace("usemtl mat\n", "").replace(
        "f 1/1 3/3 4/4", "usemtl mat\nf 1/1 3/3 4/4\nusemtl red\nf 1/1 2/2 4/4"
    )
    mtl = "newmtl mat\nmap_Kd tex.png\nnewmtl red\nKd 0.8 0.1 0.2\nd 0.5\n"
    mesh = load_mesh(write_obj_asset(tmp_path, obj=obj, mtl=mtl))
    assert [m.name for m in mesh.materials] == ["mat", "red", "default"]
    np.testing.assert_allclose(mesh.materials[1].base_color_factor, [0.8, 0.1, 0.2, 0.5])
    assert mesh.materials[1].base_color_texture is None
    np.testing.assert_array_equal(mesh.face_material, [0, 1, 2])


def test_obj_split_at_every_corner_welds_to_points(tmp_path: Path):
    sphere = trimesh.creation.icosphere(subdivisions=1)
    corners = sphere.vertices[sphere.faces.ravel()]
    lines = ["mtllib mesh.mtl", "usemtl mat"]
    lines += [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in corners]
    lines += [f"vt {i / len(corners):.17g} 0.5" for i in range(len(corners))]
    lines += [f"f {3 * i + 1}/{3 * i + 1} {3 * i + 2}/{3 * i + 2} {3 * i + 3}/{3 * i + 3}"
              for i in range(len(sphere.faces))]  # fmt: skip
    mesh = load_mesh(write_obj_asset(tmp_path, obj="\n".join(lines) + "\n"))
    assert len(mesh.positions) == len(corners)
    assert mesh.num_points == len(sphere.vertices)
    np.testing.assert_array_equal(mesh.points()[mesh.vertex_to_point], mesh.positions)
    # No normals in the file: computed over welded points, so smooth across every seam.
    radial = mesh.positions / np.linalg.norm(mesh.positions, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", mesh.normals, radial).min() > 0.95


def test_obj_duplicate_vertices_with_same_uv_become_one(tmp_path: Path):
    obj = QUAD_OBJ.replace("v 0 1 0\n", "v 0 1 0\nv 0 0 0\n").replace("f 1/1 3/3", "f 5/1 3/3")
    mesh = load_mesh(write_obj_asset(tmp_path, obj=obj))
    assert len(mesh.positions) == 4 and mesh.num_points == 4


def test_obj_normals_come_from_the_file(tmp_path: Path):
    obj = QUAD_OBJ.replace("usemtl", "vn 0 3 4\nusemtl").replace("/1 ", "/1/1 ")
    obj = obj.replace("/2 ", "/2/1 ").replace("/3 ", "/3/1 ").replace("/3\n", "/3/1\n")
    obj = obj.replace("/4\n", "/4/1\n")
    mesh = load_mesh(write_obj_asset(tmp_path, obj=obj))
    np.testing.assert_allclose(mesh.normals, [[0, 0.6, 0.8]] * 4, atol=1e-6)


def test_obj_with_several_libraries_and_windows_paths(tmp_path: Path):
    obj = QUAD_OBJ.replace("mtllib mesh.mtl", "mtllib other.mtl mesh.mtl")
    path = write_obj_asset(tmp_path / "asset", obj=obj, mtl="newmtl mat\nmap_Kd maps\\tex.png\n")
    (tmp_path / "asset" / "other.mtl").write_text("newmtl unused\nKd 1 0 0\n")
    (tmp_path / "asset" / "maps").mkdir()
    (tmp_path / "asset" / "tex.png").rename(tmp_path / "asset" / "maps" / "tex.png")
    mesh = load_mesh(path)
    assert [m.name for m in mesh.materials] == ["mat"]
    np.testing.assert_array_equal(mesh.materials[0].base_color_texture, TEXTURE)


# ----------------------------------------------------------------------------- glTF


def test_gltf_uvs_are_flipped_into_the_opengl_convention(tmp_path: Path):
    texture = np.zeros((2, 2, 3), np.uint8)
    texture[0] = [255, 0, 0]  # top row red
    texture[1] = [0, 0, 255]
    gltf_uvs = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75]])  # glTF v = 0 is the top
    material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                         "baseColorFactor": [0.3, 0.5, 0.7, 1.0]}}  # fmt: skip
    mesh = load_mesh(write_gltf(tmp_path, gltf_uvs, texture, material))
    np.testing.assert_allclose(mesh.uvs, [[0.25, 0.75], [0.75, 0.75], [0.25, 0.25]], atol=1e-7)
    row = int((1 - mesh.uvs[0, 1]) * 2)  # texel row of vertex 0 in our convention
    np.testing.assert_array_equal(mesh.materials[0].base_color_texture[row, 0], [255, 0, 0])
    np.testing.assert_array_equal(
        mesh.materials[0].base_color_factor, np.float32([0.3, 0.5, 0.7, 1.0])
    )


def trimesh_box(factor: list[int], uv_seed: int) -> trimesh.Trimesh:
    box = trimesh.creation.box()
    uv = np.random.default_rng(uv_seed).random((len(box.vertices), 2))
    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.fromarray(TEXTURE), baseColorFactor=factor
    )
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return box


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_gltf_scene_graph_and_materials(tmp_path: Path, suffix: str):
    """Two parts, two materials, one placed by a mirroring transform (winding flipped back)."""
    scene = trimesh.Scene()
    scene.add_geometry(trimesh_box([51, 102, 153, 255], 0), node_name="a",
                       transform=trimesh.transformations.translation_matrix([3, 0, 0]))  # fmt: skip
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = [-3, 0, 0]
    scene.add_geometry(trimesh_box([255, 255, 255, 255], 1), node_name="b", transform=mirror)
    scene.export(tmp_path / f"scene{suffix}")
    mesh = load_mesh(tmp_path / f"scene{suffix}")
    assert len(mesh.materials) == 2 and len(mesh.faces) == 24
    factors = sorted(m.base_color_factor.tolist() for m in mesh.materials)
    np.testing.assert_allclose(factors, [[0.2, 0.4, 0.6, 1.0], [1.0, 1.0, 1.0, 1.0]], atol=1e-7)
    centres = sorted(
        mesh.positions[mesh.faces[mesh.face_material == k]].mean((0, 1))[0] for k in (0, 1)
    )
    np.testing.assert_allclose(centres, [-3, 3], atol=1e-6)
    assert signed_volume(mesh) == pytest.approx(2 * 6.0)  # both unit boxes outward-facing


def test_gltf_normals_follow_the_node_rotation(tmp_path: Path):
    box = trimesh_box([255, 255, 255, 255], 0)
    box.vertex_normals = box.vertices / np.linalg.norm(box.vertices, axis=1, keepdims=True)
    scene = trimesh.Scene()
    turn = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1])
    scene.add_geometry(box, transform=turn)
    scene.export(tmp_path / "box.glb", include_normals=True)
    mesh = load_mesh(tmp_path / "box.glb")
    expected = mesh.positions / np.linalg.norm(mesh.positions, axis=1, keepdims=True)
    np.testing.assert_allclose(mesh.normals, expected, atol=1e-6)


def test_missing_maps_other_than_base_colour_only_warn(tmp_path: Path):
    material = {"normalTexture": {"index": 1},
                "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}  # fmt: skip
    path = write_gltf(tmp_path / "gltf", np.zeros((3, 2)), material=material,
                      second_image_uri="gone_normal.png")  # fmt: skip
    with pytest.warns(UserWarning, match="gone_normal.png"):
        mesh = load_mesh(path)
    assert mesh.materials[0].maps == {} and "normalTexture" not in mesh.materials[0].properties
    grey = Image.fromarray(TEXTURE[..., 0])
    path = write_obj_asset(tmp_path / "obj", mtl="newmtl mat\nmap_Kd tex.png\nbump tex.png\n"
                           "map_Ke gone.png\n")  # fmt: skip
    (tmp_path / "obj" / "tex.png").write_bytes(png_bytes(grey))
    with pytest.warns(UserWarning) as caught:
        mesh = load_mesh(path)
    assert [str(w.message) for w in caught if "gone.png" in str(w.message)]
    # A grey bump map is a height map, not a normal map: kept under its MTL keyword, and the
    # one file behind map_Kd and bump is one array.
    material = mesh.materials[0]
    assert list(material.maps) == ["mtl:bump"]
    assert material.maps["mtl:bump"] is material.base_color_texture
    np.testing.assert_array_equal(material.base_color_texture, np.repeat(TEXTURE[..., :1], 3, 2))


def test_gltf_material_properties_survive_saving(tmp_path: Path):
    material = {
        "name": "fancy",
        "doubleSided": True,
        "alphaMode": "MASK",
        "alphaCutoff": 0.25,
        "normalTexture": {"index": 0, "scale": 0.5},
        "occlusionTexture": {"index": 0, "strength": 0.7},
        "extensions": {"KHR_materials_unlit": {}},
        "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0},
            "baseColorFactor": [0.3, 0.5, 0.7, 0.9],
            "metallicFactor": 0.1,
            "roughnessFactor": 0.8,
        },
    }
    source = load_mesh(write_gltf(tmp_path / "in", np.zeros((3, 2)), material=material))
    (tmp_path / "out").mkdir()
    save_mesh(source, tmp_path / "out" / "fancy.gltf")
    saved = json.loads((tmp_path / "out" / "fancy.gltf").read_text())
    written = saved["materials"][0]
    assert written["normalTexture"]["scale"] == 0.5
    assert written["occlusionTexture"]["strength"] == 0.7
    assert written["extensions"] == {"KHR_materials_unlit": {}}
    assert saved["extensionsUsed"] == ["KHR_materials_unlit"]
    assert (written["doubleSided"], written["alphaMode"], written["alphaCutoff"]) == (
        True, "MASK", 0.25
    )  # fmt: skip
    pbr = written["pbrMetallicRoughness"]
    assert (pbr["metallicFactor"], pbr["roughnessFactor"]) == (0.1, 0.8)
    np.testing.assert_allclose(pbr["baseColorFactor"], [0.3, 0.5, 0.7, 0.9], atol=1e-7)
    assert len(saved["images"]) == 1  # one image behind base colour, normal and occlusion
    assert len(saved["textures"]) == 1
    reloaded = load_mesh(tmp_path / "out" / "fancy.gltf").materials[0]
    assert list(reloaded.maps) == ["normalTexture", "occlusionTexture"]
    assert reloaded.maps["normalTexture"] is reloaded.base_color_texture
    assert reloaded.maps["occlusionTexture"] is reloaded.base_color_texture
    np.testing.assert_array_equal(reloaded.maps["normalTexture"], TEXTURE)


# ----------------------------------------------------------------------------- errors


def raw_file(name: str, data: bytes) -> Callable[[Path], Path]:
    def build(folder: Path) -> Path:
        (folder / name).write_bytes(data)
        return folder / name

    return build


def with_outside_texture(mtl_ref: Callable[[Path], str]) -> Callable[[Path], Path]:
    """An OBJ in ``folder/a/b`` whose MTL names an existing PNG in ``folder``."""

    def build(folder: Path) -> Path:
        (folder / "outside.png").write_bytes(png_bytes(TEXTURE))
        return write_obj_asset(folder / "a" / "b", mtl=f"newmtl mat\nmap_Kd {mtl_ref(folder)}\n")

    return build


def with_corrupt_texture(folder: Path) -> Path:
    path = write_obj_asset(folder)
    (folder / "tex.png").write_bytes(b"\x89PNG not really")
    return path


def with_base_color_info(info: dict) -> Callable[[Path], Path]:
    material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, **info}}}
    return lambda folder: write_gltf(folder, np.zeros((3, 2)), material=material)


NO_UV_OBJ = "\n".join(
    " ".join(word.split("/")[0] for word in line.split())
    for line in QUAD_OBJ.splitlines()
    if not line.startswith("vt")
)
OUTSIDE = "outside the mesh's folder"
# name -> (build the broken input in a folder, words the message must hold besides the name)
BROKEN_INPUTS: dict[str, tuple[Callable[[Path], Path], str]] = {
    "obj-no-uvs": (lambda d: write_obj_asset(d, obj=NO_UV_OBJ), "texture coordinates"),
    "obj-no-texture": (
        lambda d: write_obj_asset(d, mtl="newmtl mat\nKd 1 0 0\n"),
        "base-colour texture",
    ),
    "obj-missing-texture": (
        lambda d: write_obj_asset(d, mtl="newmtl mat\nmap_Kd gone.png\n"),
        "gone.png",
    ),
    "obj-escaping-texture": (with_outside_texture(lambda d: "../../outside.png"), OUTSIDE),
    "obj-absolute-texture": (with_outside_texture(lambda d: d / "outside.png"), OUTSIDE),
    "obj-missing-mtl": (
        lambda d: write_obj_asset(d, obj=QUAD_OBJ.replace("mesh.mtl", "gone.mtl")),
        "gone.mtl",
    ),
    "obj-corrupt-texture": (with_corrupt_texture, "tex.png"),
    "obj-no-faces": (lambda d: write_obj_asset(d, obj="v 0 0 0\nv 1 0 0\n"), "no triangles"),
    "gltf-missing-bin": (
        lambda d: write_gltf(d, np.zeros((3, 2)), buffer_uri="gone.bin"),
        "gone.bin",
    ),
    "gltf-missing-image": (
        lambda d: write_gltf(d, np.zeros((3, 2)), image_uri="gone%20.png"),
        "gone .png",
    ),
    "gltf-escaping-image": (
        lambda d: write_gltf(d, np.zeros((3, 2)), image_uri="../../etc/passwd"),
        OUTSIDE,
    ),
    "gltf-second-uv-set": (with_base_color_info({"texCoord": 1}), "TEXCOORD_1"),
    "gltf-uv-transform-zero-scale": (
        with_base_color_info({"extensions": {"KHR_texture_transform": {"scale": [0, 1]}}}),
        "scale of 0",
    ),
    "gltf-uv-transform-short-offset": (
        with_base_color_info({"extensions": {"KHR_texture_transform": {"offset": [1]}}}),
        "KHR_texture_transform.offset is [1], not 2 numbers",
    ),
    "gltf-uv-transform-second-uv-set": (
        with_base_color_info({"extensions": {"KHR_texture_transform": {"texCoord": 1}}}),
        "TEXCOORD_1",
    ),
    "gltf-bad-json": (raw_file("bad.gltf", b'{"asset": {"version": "2.0"}, "mesh'), "JSON"),
    "gltf-compressed": (
        raw_file(
            "c.gltf",
            b'{"asset": {"version": "2.0"}, "extensionsRequired": ["EXT_meshopt_compression"]}',
        ),
        "EXT_meshopt_compression",
    ),  # fmt: skip
    "glb-truncated": (raw_file("cut.glb", b"glTF\x02\x00\x00\x00" + bytes(range(64))), "GLB"),
    "glb-not-glb": (raw_file("noise.glb", bytes(range(256))), "GLB"),
    "unsupported-suffix": (raw_file("model.ply", b"ply\n"), ".ply"),
    "missing-file": (lambda d: d / "nowhere.obj", "no such file"),
}


@pytest.mark.parametrize("name", list(BROKEN_INPUTS))
def test_broken_input_raises_a_geoscaler_error_naming_the_file(tmp_path: Path, name: str):
    build, words = BROKEN_INPUTS[name]
    path = build(tmp_path)
    with pytest.raises(GeoscalerError) as info:
        load_mesh(path)
    assert path.name in str(info.value)
    assert words in str(info.value)


def test_obj_and_mtl_that_start_with_a_byte_order_mark_load(tmp_path):
    """Editors on Windows save UTF-8 with a BOM; ``mtllib`` must still be recognised."""
    bom = "\ufeff"
    path = write_obj_asset(tmp_path, obj=bom + QUAD_OBJ, mtl=bom + "newmtl mat\nmap_Kd tex.png\n")
    mesh = load_mesh(path)
    np.testing.assert_array_equal(mesh.materials[0].base_color_texture, TEXTURE)


def test_reading_a_mesh_imports_no_mesh_library(tmp_path: Path):
    """OBJ and glTF are read by the project's own readers: importing trimesh cost 0.7 to
    1.0 s of every OBJ job."""
    save_mesh(demo_mesh(subdivisions=1, texture_size=8), tmp_path / "mesh.glb")
    obj = write_obj_asset(tmp_path)
    probe = (
        "import sys\n"
        "from geoscaler.io import load_mesh\n"
        "import geoscaler.report.runner\n"
        "load_mesh(sys.argv[1])\n"
        "load_mesh(sys.argv[2])\n"
        "print('trimesh' in sys.modules)\n"
    )
    command = [sys.executable, "-c", probe, str(tmp_path / "mesh.glb"), str(obj)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    assert done.stdout == "False\n"
