"""The asset as it ships: every map at its class's size, shared images resized once and kept
shared, maps the rule does not shrink shipped as they came, the learned method's shared base
colour one texture."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_support import mesh_of

from geoscaler.errors import GeoscalerError
from geoscaler.io.images import (
    ENCODING_SECONDS_PER_TEXEL,
    LARGE_ENCODING_SECONDS_PER_TEXEL,
    encoding_seconds,
)
from geoscaler.mesh import Material, SourceImage, TexturedMesh
from geoscaler.methods import MethodOptions, RunContext, run_method
from geoscaler.pipeline.shipping import (
    RESIZE_SECONDS_PER_TEXEL,
    TOKSVIG,
    export_seconds,
    relayout_seconds,
    ship_asset,
    toksvig_maps,
)
from geoscaler.protocol import Evaluation
from geoscaler.render.renderer import Renderer
from geoscaler.resize.maps import METHOD_NAMES
from geoscaler.resize.sizes import SizePlan, SizeRule, size_plan
from geoscaler.uv.bake import BAKE_SECONDS_PER_SAMPLE

RNG = np.random.default_rng(7)


def _image(height: int, width: int, channels: int = 3) -> np.ndarray:
    pixels = RNG.integers(0, 256, (height, width, channels), dtype=np.uint8)
    pixels.flags.writeable = False
    return pixels


def _source(pixels: np.ndarray, name: str) -> SourceImage:
    return SourceImage(pixels, "image/png", b"x" * 100, name)


def shared_pbr_mesh() -> TexturedMesh:
    """Two quads side by side, two materials showing one base-colour image (each on its own
    half of it) and one normal map; the first also has a metallic-roughness map."""
    base, normal, rough = _image(64, 64), _image(32, 32), _image(64, 64)
    positions = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=np.float32
    )
    uvs = np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1], [1, 0], [1, 1]], dtype=np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]], dtype=np.int64)
    sources = {
        "baseColorTexture": _source(base, "base"),
        "normalTexture": _source(normal, "normal"),
    }
    first = Material(
        "left",
        base,
        maps={"normalTexture": normal, "metallicRoughnessTexture": rough},
        sources={**sources, "metallicRoughnessTexture": _source(rough, "rough")},
    )
    second = Material("right", base, maps={"normalTexture": normal}, sources=dict(sources))
    return mesh_of(positions, faces, uvs, np.array([0, 0, 1, 1]), [first, second])


def test_every_map_ships_at_its_class_size_and_shared_maps_stay_shared():
    mesh = shared_pbr_mesh()
    base = mesh.materials[0].base_color_texture
    made = np.zeros((16, 16, 3), np.uint8)
    out, shipped = ship_asset(mesh, size_plan({"all": 4, "normal": 2}, {}), [made, made], "direct")
    left, right = out.materials
    assert left.base_color_texture is made and right.base_color_texture is made
    assert left.maps["normalTexture"] is right.maps["normalTexture"]
    assert left.maps["normalTexture"].shape == (16, 16, 3)
    assert left.maps["metallicRoughnessTexture"].shape == (16, 16, 3)
    assert [(m.kind, m.method) for m in shipped] == [
        ("color", "direct"),
        ("normal", METHOD_NAMES["normal"]),
        ("data", f"{METHOD_NAMES['data']}, {TOKSVIG}"),  # its material's normal map shrank
    ]
    assert shipped[0].slots == ["left/baseColorTexture", "right/baseColorTexture"]
    assert shipped[1].slots == ["left/normalTexture", "right/normalTexture"]
    assert [m.memory_before / m.memory_after for m in shipped] == [16, 4, 16]
    assert mesh.materials[0].base_color_texture is base  # the input is left as it was


def test_a_map_its_rule_does_not_shrink_ships_as_it_came():
    mesh = shared_pbr_mesh()
    normal = mesh.materials[0].maps["normalTexture"]
    keep_normals = SizePlan(SizeRule(scale=4), SizeRule(max_size=4096), SizeRule(scale=4))
    made = np.zeros((16, 16, 3), np.uint8)
    out, shipped = ship_asset(mesh, keep_normals, [made, made], "lanczos")
    assert out.materials[1].maps["normalTexture"] is normal
    assert shipped[1].method == "kept" and shipped[1].size_after == (32, 32)


def test_direct_optimises_one_texture_for_materials_that_share_an_image():
    mesh = shared_pbr_mesh()
    evaluation = Evaluation(image_size=64, views=(0, 7), reference_max_size=None)
    renderer = Renderer(mesh, "cpu", evaluation)
    options = MethodOptions(device="cpu", steps=2, settings={"optimize": {"pool_views": 2}})
    result = run_method("direct", mesh, 4, options, RunContext(renderer))
    left, right = result.textures
    assert left.shape == (16, 16, 3)
    np.testing.assert_array_equal(left, right)


@pytest.mark.parametrize("scale", [2, 4])
def test_texture_memory_falls_by_the_scale_squared(scale):
    mesh = shared_pbr_mesh()
    size = 64 // scale
    made = np.zeros((size, size, 3), np.uint8)
    _, shipped = ship_asset(mesh, size_plan({"all": scale}, {}), [made, made], "box")
    before = sum(m.memory_before for m in shipped)
    after = sum(m.memory_after for m in shipped)
    assert before / after == scale**2


def test_the_network_does_not_warp_uvs_that_other_maps_read():
    mesh = shared_pbr_mesh()
    options = MethodOptions(device="cpu", steps=1, settings={"variant": "full"})
    with pytest.raises(GeoscalerError, match="would no longer line up: use --variant base"):
        run_method("geoscaler", mesh, 4, options)


def jpeg_asset(emissive: bool = False) -> TexturedMesh:
    """:func:`shared_pbr_mesh` as a JPEG asset comes in: one JPEG source per image, shared;
    with ``emissive``, the first material also has an emissive (colour) map."""
    mesh = shared_pbr_mesh()
    if emissive:
        glow = _image(64, 64)
        mesh.materials[0].maps["emissiveTexture"] = glow
        mesh.materials[0].sources["emissiveTexture"] = _source(glow, "glow")
    jpeg = {}
    for material in mesh.materials:
        material.sources = {
            slot: jpeg.setdefault(id(s), SourceImage(s.pixels, "image/jpeg", s.data, s.name))
            for slot, s in material.sources.items()
        }
    return mesh


def test_the_base_colour_and_smaller_normal_and_data_maps_ship_lossless():
    mesh = jpeg_asset(emissive=True)
    made = np.zeros((16, 16, 3), np.uint8)
    out, _ = ship_asset(mesh, size_plan({"all": 4}, {}), [made, made], "direct")
    left, right = out.materials
    for slot in ("baseColorTexture", "normalTexture", "metallicRoughnessTexture"):
        assert left.sources[slot].mime == "image/png", slot
    assert left.sources["baseColorTexture"] is right.sources["baseColorTexture"]
    assert left.sources["normalTexture"] is right.sources["normalTexture"]
    assert left.sources["emissiveTexture"].mime == "image/jpeg"  # a colour map keeps its format


def test_maps_the_plan_keeps_at_their_size_keep_their_format_and_bytes():
    mesh = jpeg_asset()
    made = np.zeros((16, 16, 3), np.uint8)
    out, shipped = ship_asset(
        mesh, SizePlan(SizeRule(4), SizeRule(), SizeRule(4)), [made, made], "direct"
    )
    normal = out.materials[0].sources["normalTexture"]
    assert normal.mime == "image/jpeg"
    assert out.materials[0].maps["normalTexture"] is normal.pixels  # written verbatim
    assert out.materials[0].sources["metallicRoughnessTexture"].mime == "image/png"


def test_toksvig_widens_the_roughness_of_materials_whose_normal_map_got_smaller():
    mesh = shared_pbr_mesh()  # random texels: a bumpy normal map
    made = np.zeros((16, 16, 3), np.uint8)
    plan = size_plan({"all": 4}, {})
    plain, _ = ship_asset(mesh, plan, [made, made], "direct", toksvig=False)
    widened, shipped = ship_asset(mesh, plan, [made, made], "direct")
    before = plain.materials[0].maps["metallicRoughnessTexture"]
    after = widened.materials[0].maps["metallicRoughnessTexture"]
    assert (after[..., 1] >= before[..., 1]).all() and (after[..., 1] > before[..., 1]).any()
    assert (after[..., [0, 2]] == before[..., [0, 2]]).all()
    assert shipped[2].pixels is after and shipped[2].method.endswith(TOKSVIG)
    again = plain.with_images(toksvig_maps(mesh, plain))
    assert (again.materials[0].maps["metallicRoughnessTexture"] == after).all()


def test_toksvig_leaves_roughness_alone_where_the_normal_map_is_kept_or_the_layout_is_new():
    mesh = shared_pbr_mesh()
    made = np.zeros((16, 16, 3), np.uint8)
    keep_normals = SizePlan(SizeRule(4), SizeRule(), SizeRule(4))
    kept, shipped = ship_asset(mesh, keep_normals, [made, made], "direct")
    assert shipped[2].method == METHOD_NAMES["data"]
    rough = mesh.materials[0].maps["metallicRoughnessTexture"]
    rebaked = np.zeros((16, 16, 3), np.uint8)
    plan = size_plan({"all": 4}, {})
    new_layout, _ = ship_asset(mesh, plan, [made, made], "d", {id(rough): (rebaked, "re-baked")})
    assert new_layout.materials[0].maps["metallicRoughnessTexture"] is rebaked
    mesh.materials[0].properties["normalTexture"] = {"texCoord": 1}  # another UV set
    _, shipped = ship_asset(mesh, plan, [made, made], "direct")
    assert shipped[2].method == METHOD_NAMES["data"]


def test_the_export_is_priced_by_the_texels_it_encodes_and_the_maps_it_resizes():
    mesh = shared_pbr_mesh()  # base colour 64, normal 32, metallic-roughness 64 a side
    plan = size_plan({"all": 4, "normal": 2}, {})  # each ships at 16 a side
    encoded = 3 * 16 * 16 * ENCODING_SECONDS_PER_TEXEL
    resized = (32 * 32 + 64 * 64) * RESIZE_SECONDS_PER_TEXEL  # not the base colour: the method's
    assert export_seconds(mesh, plan, None) == pytest.approx(encoded + resized)


def test_a_map_shipped_as_it_came_costs_the_export_nothing_unless_it_changes_format():
    mesh = shared_pbr_mesh()
    keep_normals = SizePlan(SizeRule(scale=4), SizeRule(max_size=4096), SizeRule(scale=4))
    base_and_data = 2 * 16 * 16 * ENCODING_SECONDS_PER_TEXEL + 64 * 64 * RESIZE_SECONDS_PER_TEXEL
    assert export_seconds(mesh, keep_normals, None) == pytest.approx(base_and_data)
    assert export_seconds(mesh, keep_normals, "png") == pytest.approx(base_and_data)
    normal_as_jpeg = 32 * 32 * ENCODING_SECONDS_PER_TEXEL  # a PNG source written as JPEG
    assert export_seconds(mesh, keep_normals, "jpeg") == pytest.approx(
        base_and_data + normal_as_jpeg
    )


def test_large_images_are_priced_at_the_encoders_rate_without_png_optimize():
    assert encoding_seconds(1024, 1024) == 1024 * 1024 * ENCODING_SECONDS_PER_TEXEL
    assert encoding_seconds(1024, 1025) == 1024 * 1025 * LARGE_ENCODING_SECONDS_PER_TEXEL


def test_a_new_layouts_rebake_is_priced_by_the_samples_of_every_other_map():
    """The normal map (32 -> 16) is baked at 2 samples a side, the metallic-roughness map
    (64 -> 16) at 4; the base colour is the method's own."""
    mesh = shared_pbr_mesh()
    samples = (16 * 2) ** 2 + (16 * 4) ** 2
    plan = size_plan({"all": 4, "normal": 2}, {})
    assert relayout_seconds(mesh, plan) == pytest.approx(samples * BAKE_SECONDS_PER_SAMPLE)
