"""A base colour under ``KHR_texture_transform``: sampled through its transform, written back
with its own UVs and the extension kept."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import small_renderer
from corners import world_corners
from io_assets import document
from mesh_support import write_gltf

import geoscaler.cli
from geoscaler.errors import GeoscalerError
from geoscaler.io import load_mesh, save_mesh
from geoscaler.io.texture_transform import transform_matrix
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import Camera

EXTENSION = "KHR_texture_transform"
GLTF_UVS = np.float32([[0.1, 0.9], [0.7, 0.8], [0.2, 0.15]])  # glTF's v runs down
# A mirror (as Blender writes it), a turn and an offset, all at once.
TRANSFORM = {"offset": [0.25, -0.5], "rotation": math.pi / 6, "scale": [-1.0, 1.5]}
TEXTURE = (np.random.default_rng(3).random((32, 32, 3)) * 255).astype(np.uint8)


def transformed_material(transform: dict) -> dict:
    info = {"index": 0, "extensions": {EXTENSION: transform}}
    return {"pbrMetallicRoughness": {"baseColorTexture": info}}


def spec_transform(gltf_uvs: np.ndarray, transform: dict) -> np.ndarray:
    """The extension's ``T R S uv`` in glTF's UV space, written out per coordinate."""
    x = gltf_uvs[:, 0] * transform["scale"][0]
    y = gltf_uvs[:, 1] * transform["scale"][1]
    cos, sin = math.cos(transform["rotation"]), math.sin(transform["rotation"])
    return np.stack([cos * x + sin * y + transform["offset"][0],
                     -sin * x + cos * y + transform["offset"][1]], axis=1)  # fmt: skip


@pytest.mark.parametrize(
    ("transform", "ours", "expected"),
    [
        ({"offset": [0.5, 0.0]}, [0.25, 0.75], [0.75, 0.75]),
        ({"offset": [0.0, 0.25]}, [0.25, 0.75], [0.25, 0.5]),  # glTF's +v is our -v
        ({"scale": [-1.0, 1.0]}, [0.25, 0.75], [-0.25, 0.75]),  # a mirror in u
        ({"scale": [1.0, 2.0]}, [0.25, 0.75], [0.25, 0.5]),  # glTF (0.25, 0.25) -> (0.25, 0.5)
        ({"rotation": math.pi / 2}, [1.0, 1.0], [0.0, 2.0]),  # glTF (1, 0) -> (0, -1)
    ],
)
def test_the_transform_in_our_uv_convention(transform, ours, expected):
    matrix = transform_matrix({"extensions": {EXTENSION: transform}}, "test")
    np.testing.assert_allclose(matrix @ [*ours, 1.0], [*expected, 1.0], atol=1e-12)


def test_no_extension_is_no_transform():
    assert transform_matrix({"index": 0}, "test") is None


def test_a_transformed_base_colour_loads_with_the_uvs_it_is_sampled_at(tmp_path):
    mesh = load_mesh(write_gltf(tmp_path, GLTF_UVS, TEXTURE, transformed_material(TRANSFORM)))
    sampled = spec_transform(GLTF_UVS.astype(np.float64), TRANSFORM)
    expected = np.c_[sampled[:, 0], 1.0 - sampled[:, 1]]
    np.testing.assert_allclose(mesh.uvs[mesh.faces[0]], expected, atol=1e-6)


def test_a_transformed_base_colour_renders_as_its_uvs_transformed_by_hand(tmp_path):
    transformed = load_mesh(
        write_gltf(tmp_path / "a", GLTF_UVS, TEXTURE, transformed_material(TRANSFORM))
    )
    by_hand = load_mesh(write_gltf(tmp_path / "b", spec_transform(GLTF_UVS, TRANSFORM), TEXTURE))
    renders = []
    for mesh in (transformed, by_hand):
        renderer = small_renderer(mesh)
        for camera in (Camera((0.0, 0.0, 1.0), 2.4), Camera((0.3, 0.2, 0.93), 1.5)):
            gbuffer = renderer.rasterize(camera)
            renders.append(renderer.render(gbuffer, renderer.reference_textures()))
    for a, b in zip(renders[:2], renders[2:], strict=True):
        assert a.abs().max() > 0.05  # the triangle is in view
        np.testing.assert_allclose(a.numpy(), b.numpy(), atol=1e-5)


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_saving_keeps_the_files_uvs_and_its_transform(tmp_path, suffix):
    source = write_gltf(tmp_path / "in", GLTF_UVS, TEXTURE, transformed_material(TRANSFORM))
    mesh = load_mesh(source)
    out = tmp_path / f"out{suffix}"
    save_mesh(mesh, out)
    doc = document(out)
    info = doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]
    assert info["extensions"] == {EXTENSION: TRANSFORM}
    assert EXTENSION in doc["extensionsUsed"]
    again = load_mesh(out)
    np.testing.assert_allclose(again.uvs, mesh.uvs, atol=1e-6)
    np.testing.assert_allclose(file_uvs(out)[0], GLTF_UVS, atol=1e-6)


def file_uvs(path) -> np.ndarray:
    """``(F, 3, 2)`` UVs of a glTF file's face corners as the file holds them (``v`` down)."""
    uvs = world_corners(path).uvs
    return np.stack([uvs[..., 0], 1.0 - uvs[..., 1]], axis=-1)


def test_a_vertex_of_two_materials_with_different_transforms_is_split_on_writing(tmp_path):
    """Two materials share every vertex (one position, one UV as sampled); the file holds each
    vertex twice, with the UV each material's transform expects."""
    mesh = load_mesh(write_gltf(tmp_path, GLTF_UVS, TEXTURE, transformed_material(TRANSFORM)))
    untransformed = replace(mesh.materials[0], name="plain", properties={})
    doubled = replace(
        mesh,
        faces=np.concatenate([mesh.faces, mesh.faces[:, ::-1]]),
        face_material=np.array([0, 1]),
        materials=[mesh.materials[0], untransformed],
    )
    out = tmp_path / "out.glb"
    save_mesh(doubled, out)
    assert document(out)["accessors"][0]["count"] == 6  # POSITION
    written = file_uvs(out)
    np.testing.assert_allclose(written[0], GLTF_UVS, atol=1e-6)
    sampled = spec_transform(GLTF_UVS.astype(np.float64), TRANSFORM)
    np.testing.assert_allclose(written[1], sampled[::-1], atol=1e-6)


@pytest.mark.parametrize(
    "method", [["--method", "lanczos"], ["--method", "direct", "--steps", "1"]]
)
def test_downsampling_a_transformed_base_colour(tmp_path, method):
    source = write_gltf(tmp_path / "in", GLTF_UVS, TEXTURE, transformed_material(TRANSFORM))
    out = tmp_path / "out.gltf"
    status = geoscaler.cli.main(
        ["downsample", str(source), "--scale", "4", *method, "-o", str(out)],
        evaluation=Evaluation.quick((0,)),
        optimize={"pool_views": 1, "views_per_step": 1},
    )
    assert status == 0
    info = document(out)["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]
    assert info["extensions"] == {EXTENSION: TRANSFORM}
    np.testing.assert_allclose(load_mesh(out).uvs, load_mesh(source).uvs, atol=1e-6)


def test_the_layout_of_a_transformed_material_is_kept_with_its_reason(tmp_path):
    source = write_gltf(tmp_path / "in", GLTF_UVS, TEXTURE, transformed_material(TRANSFORM))
    out = tmp_path / "out.glb"
    report = tmp_path / "report.json"
    status = geoscaler.cli.main(
        ["downsample", str(source), "--scale", "4", "--method", "direct", "--uv", "repack",
         "--steps", "1", "-o", str(out), "--report", str(report)],
        evaluation=Evaluation.quick((0,)),
        optimize={"pool_views": 1, "views_per_step": 1},
    )  # fmt: skip
    assert status == 0
    kept = json.loads(report.read_text())["details"]["layout"]["kept"]
    assert kept == {"material_0": "baseColorTexture has a KHR_texture_transform"}


def test_a_transform_on_the_specular_glossiness_diffuse_is_refused(tmp_path):
    info = {"index": 0, "extensions": {EXTENSION: TRANSFORM}}
    material = {"extensions": {"KHR_materials_pbrSpecularGlossiness": {"diffuseTexture": info}}}
    with pytest.raises(GeoscalerError, match="diffuse texture"):
        load_mesh(write_gltf(tmp_path, GLTF_UVS, TEXTURE, material))
