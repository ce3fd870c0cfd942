"""Saving mesh files: round trips, what is written, and the outputs that are refused."""

from __future__ import annotations

import json
import os
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from mesh_support import (
    DROPPED_MAPS,
    FORMATS,
    TEXTURE,
    assert_same_mesh,
    corner_table,
    two_material_mesh,
    write_gltf,
    write_obj_asset,
)

from geoscaler.errors import GeoscalerError
from geoscaler.io import (
    check_output,
    check_outputs,
    gltf,
    load_mesh,
    output_files,
    save_mesh,
)

# ----------------------------------------------------------------------------- saving


@pytest.mark.parametrize("suffix", FORMATS)
def test_two_materials_round_trip(tmp_path: Path, suffix: str):
    mesh = two_material_mesh()
    written = save_mesh(mesh, tmp_path / f"two{suffix}")
    loaded = load_mesh(written[-1])
    assert corner_table(loaded) == corner_table(mesh)
    if suffix != ".obj":  # trimesh's OBJ reader regroups vertices by material
        assert_same_mesh(loaded, mesh)
    plain = loaded.materials[[m.name for m in loaded.materials].index("plain")]
    np.testing.assert_allclose(plain.base_color_factor, [0.2, 0.4, 0.6, 1.0], atol=1e-6)


def test_saving_never_overwrites_the_input(tmp_path: Path):
    folder = tmp_path / "asset"
    source = write_obj_asset(folder)
    (folder / "copy_tex.png").write_bytes((folder / "tex.png").read_bytes())
    (folder / "mesh.mtl").write_text("newmtl mat\nmap_Kd tex.png\nnorm copy_tex.png\n")
    (tmp_path / "alias").symlink_to(folder)
    mesh = load_mesh(source)
    before = {p: p.read_bytes() for p in folder.iterdir()}
    targets = [
        source,
        tmp_path / "alias" / "mesh.obj",  # the input, through a symbolic link
        folder / "copy.obj",  # would write copy_tex.png (its map_Kd), the input normal map
        folder / "mesh.OBJ",  # would write mesh.mtl, the input library
    ]
    for target in targets:
        with pytest.raises(GeoscalerError, match="read from"):
            save_mesh(mesh, target, overwrite=True)
    edited = mesh.with_texture(0, TEXTURE[:2])  # a downsampled copy still protects its input
    with pytest.raises(GeoscalerError, match="read from"):
        save_mesh(edited, source, overwrite=True)
    assert {p: p.read_bytes() for p in folder.iterdir()} == before


def test_saving_refuses_existing_outputs_unless_told(tmp_path: Path):
    mesh = two_material_mesh()
    first = save_mesh(mesh, tmp_path / "out.glb")
    with pytest.raises(GeoscalerError, match="already exist"):
        save_mesh(mesh, tmp_path / "out.glb")
    assert save_mesh(mesh, tmp_path / "out.glb", overwrite=True) == first
    assert sorted(tmp_path.iterdir()) == first


def test_saving_into_a_missing_or_unwritable_folder(tmp_path: Path):
    with pytest.raises(GeoscalerError, match="does not exist"):
        save_mesh(two_material_mesh(), tmp_path / "nowhere" / "out.obj")
    with pytest.raises(GeoscalerError, match="unsupported"):
        save_mesh(two_material_mesh(), tmp_path / "out.ply")
    if os.geteuid() == 0:
        pytest.skip("root can write into read-only folders")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    with pytest.raises(GeoscalerError, match="not writable"):
        save_mesh(two_material_mesh(), locked / "out.obj")


def test_obj_export_bakes_the_factor_into_the_texture(tmp_path: Path):
    white = np.full((2, 2, 3), 255, np.uint8)
    mesh = two_material_mesh().with_texture(0, white)
    mesh.materials[0].base_color_factor = np.float32([0.5, 0.5, 0.5, 1])
    obj = load_mesh(save_mesh(mesh, tmp_path / "baked.obj")[-1])
    np.testing.assert_array_equal(obj.materials[0].base_color_factor, 1)
    np.testing.assert_array_equal(obj.materials[0].base_color_texture, 188)  # sRGB of 0.5
    glb = load_mesh(save_mesh(mesh, tmp_path / "kept.glb")[-1])
    np.testing.assert_array_equal(glb.materials[0].base_color_factor, [0.5, 0.5, 0.5, 1])
    np.testing.assert_array_equal(glb.materials[0].base_color_texture, 255)


def test_gltf_export_writes_the_base_colour_factor_explicitly(tmp_path: Path):
    """An OBJ without Kd must not come out at trimesh's default 0.4 grey."""
    mesh = load_mesh(write_obj_asset(tmp_path / "in"))
    save_mesh(mesh, tmp_path / "out.gltf")
    doc = json.loads((tmp_path / "out.gltf").read_text())
    assert doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] == [1.0] * 4


@pytest.mark.filterwarnings(DROPPED_MAPS)
def test_obj_export_keeps_normal_maps_and_warns_about_the_rest(tmp_path: Path):
    material = {"normalTexture": {"index": 0}, "occlusionTexture": {"index": 0},
                "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}  # fmt: skip
    mesh = load_mesh(write_gltf(tmp_path / "in", np.zeros((3, 2)), material=material))
    with pytest.warns(UserWarning, match="occlusionTexture"):
        written = save_mesh(mesh, tmp_path / "out.obj")
    mtl = (tmp_path / "out.mtl").read_text().splitlines()
    # One image behind base colour and normal (embedded and unnamed: "image0"), written once.
    assert mtl[-2:] == ["map_Kd out_image0.png", "norm out_image0.png"]
    assert [p.name for p in written] == ["out_image0.png", "out.mtl", "out.obj"]
    reloaded = load_mesh(written[-1]).materials[0]
    assert list(reloaded.maps) == ["normalTexture"]
    np.testing.assert_array_equal(reloaded.maps["normalTexture"], TEXTURE)


# ----------------------------------------------------------------------------- output files


@pytest.mark.filterwarnings(DROPPED_MAPS)
@pytest.mark.parametrize("suffix", FORMATS)
def test_output_files_are_the_files_save_mesh_writes(tmp_path: Path, suffix: str):
    material = {"normalTexture": {"index": 0}, "occlusionTexture": {"index": 0},
                "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}  # fmt: skip
    mesh = load_mesh(write_gltf(tmp_path / "in", np.zeros((3, 2)), material=material))
    (tmp_path / "out").mkdir()
    planned = output_files(mesh, tmp_path / "out" / f"mesh{suffix}")
    assert not any((tmp_path / "out").iterdir())
    assert save_mesh(mesh, tmp_path / "out" / f"mesh{suffix}") == planned
    assert sorted((tmp_path / "out").iterdir()) == sorted(planned)
    with pytest.raises(GeoscalerError, match="unsupported"):
        output_files(mesh, tmp_path / "out" / "mesh.ply")


def test_output_files_warn_about_nothing():
    mesh = two_material_mesh()  # with a map that OBJ cannot hold: save_mesh would warn
    mesh.materials[0].maps["occlusionTexture"] = np.zeros((1, 1, 3), np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        names = [p.name for p in output_files(mesh, Path("out.obj"))]
    assert names == ["out_0_basecolor.png", "out.mtl", "out.obj"]


def test_the_writer_and_the_commands_refuse_with_the_same_words(tmp_path: Path):
    """save_mesh and check_output share one check: one message per mistake."""
    source = save_mesh(two_material_mesh(), tmp_path / "in.glb")[-1]
    mesh = load_mesh(source)
    (tmp_path / "taken.glb").write_bytes(b"keep")
    (tmp_path / "folder.glb").mkdir()
    mistakes = {
        source: "refusing to overwrite the input file (the mesh was read from it)",
        tmp_path / "taken.glb": "already exists; pass --force to replace it",
        tmp_path / "folder.glb": "is a folder; give an output file name",
        tmp_path / "missing" / "out.glb": "does not exist; create it first",
    }
    for target, words in mistakes.items():
        force = target == source
        with pytest.raises(GeoscalerError, match=re.escape(words)) as by_writer:
            save_mesh(mesh, target, overwrite=force)
        with pytest.raises(GeoscalerError) as by_command:
            check_output(target, force=force, inputs=mesh.source_files)
        assert str(by_command.value) == str(by_writer.value)
    with pytest.raises(GeoscalerError, match="already exist; pass --force to replace them"):
        check_outputs([tmp_path / "taken.glb", source], force=False)


def test_gltf_enums_are_named(tmp_path: Path):
    save_mesh(two_material_mesh(), tmp_path / "out.gltf")
    doc = json.loads((tmp_path / "out.gltf").read_text())
    assert {a["componentType"] for a in doc["accessors"]} == {gltf.FLOAT, gltf.UNSIGNED_SHORT}
    assert [v["target"] for v in doc["bufferViews"]] == [gltf.ARRAY_BUFFER] * 3 + [
        gltf.ELEMENT_ARRAY_BUFFER
    ] * 2
    assert all(p.get("mode", gltf.TRIANGLES) == gltf.TRIANGLES
               for p in doc["meshes"][0]["primitives"])  # fmt: skip


@pytest.mark.parametrize(("count", "component"), [(65534, 5123), (65535, 5125)])
def test_indices_are_16_bit_where_the_vertices_allow(tmp_path: Path, count: int, component: int):
    """Index 65535 is the primitive-restart value glTF forbids in 16-bit indices."""
    mesh = two_material_mesh()
    pad = count - len(mesh.positions)
    mesh.positions = np.concatenate([mesh.positions, np.zeros((pad, 3), np.float32)])
    mesh.uvs = np.concatenate([mesh.uvs, np.zeros((pad, 2), np.float32)])
    mesh.normals = np.concatenate([mesh.normals, np.tile(np.float32([0, 0, 1]), (pad, 1))])
    mesh.vertex_to_point = np.concatenate([mesh.vertex_to_point, np.zeros(pad, np.int64)])
    save_mesh(mesh, tmp_path / "out.gltf")
    doc = json.loads((tmp_path / "out.gltf").read_text())
    indices = [doc["accessors"][p["indices"]] for p in doc["meshes"][0]["primitives"]]
    assert [a["componentType"] for a in indices] == [component, component]
