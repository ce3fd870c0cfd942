"""Protocol 2's lit shading: the glTF BRDF by hand, its gradients, the normal map's frame."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from mesh_support import quad_mesh

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import Material
from geoscaler.protocol import AMBIENT_RADIANCE, Evaluation
from geoscaler.render.cameras import Camera
from geoscaler.render.lit import (
    Light,
    LitScene,
    LitView,
    Surface,
    _material_surface,
    camera_lights,
    lit_materials,
    lit_scores,
    shade,
    shading_normal,
    vertex_tangents,
)
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture, UVFootprint

UP = torch.tensor([[0.0], [0.0], [1.0]], dtype=torch.float64)
HEAD_ON = [Light((0.0, 0.0, 1.0), 2.0)]  # the key light's irradiance, along the normal


def surface(color=(1.0, 1.0, 1.0), metallic=0.0, roughness=1.0, normal=UP) -> Surface:
    one = torch.ones(1, dtype=torch.float64)
    return Surface(
        torch.tensor(color, dtype=torch.float64)[:, None],
        metallic * one,
        roughness * one,
        one,
        torch.zeros(3, 1, dtype=torch.float64),
        normal,
    )


def test_a_white_lambertian_facing_the_light_and_the_eye():
    # n = v = l, r = 1 (a = 1): D = 1/pi, Vis = 0.5 / (1 + 1), F = F0 = 0.04, so
    # f = 0.96 / pi + 0.04 / (4 pi) = 0.97 / pi; ambient 0.15 (1 + 0.04).
    radiance = shade(surface(), UP, HEAD_ON)
    expected = 2.0 * 0.97 / math.pi + AMBIENT_RADIANCE * 1.04
    torch.testing.assert_close(radiance, torch.full((3, 1), expected, dtype=torch.float64))


def test_a_white_surface_facing_the_camera_comes_to_about_0_8_under_the_protocols_lights():
    camera = Camera((0.0, 0.0, 1.0), 2.4)
    radiance = shade(surface(), UP, camera_lights(camera))
    assert 0.75 < float(radiance[0, 0]) < 0.85


def test_a_metal_reflects_its_colour_and_nothing_diffuse():
    # m = 1: c_diff = 0, F0 = C; n = v = l, a = 1: f = C D Vis = C / (4 pi); ambient 0.15 C.
    color = (1.0, 0.5, 0.2)
    radiance = shade(surface(color, metallic=1.0), UP, HEAD_ON)
    expected = torch.tensor(color, dtype=torch.float64) * (2.0 / (4 * math.pi) + 0.15)
    torch.testing.assert_close(radiance[:, 0], expected)


def test_a_smooth_dielectrics_highlight_by_hand():
    # Black dielectric, r = 0.3 (a = 0.09), eye along n, light 10 degrees off it.
    theta = math.radians(10)
    light = [Light((math.sin(theta), 0.0, math.cos(theta)), 2.0)]
    nl, nv = math.cos(theta), 1.0
    half = np.array([math.sin(theta), 0.0, 1.0 + math.cos(theta)])
    half /= np.linalg.norm(half)
    nh, vh = half[2], half[2]
    a2 = 0.09**2
    fresnel = 0.04 + 0.96 * (1 - vh) ** 5
    d = a2 / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    vis = 0.5 / (nl * math.sqrt(nv * nv * (1 - a2) + a2) + nv * math.sqrt(nl * nl * (1 - a2) + a2))
    expected = 2.0 * fresnel * d * vis * nl + AMBIENT_RADIANCE * 0.04
    radiance = shade(surface((0.0, 0.0, 0.0), roughness=0.3), UP, light)
    torch.testing.assert_close(radiance, torch.full((3, 1), expected, dtype=torch.float64))
    assert expected > 0.2  # a bright highlight from a black surface


def test_radiance_is_clamped_to_one_and_roughness_to_its_floor():
    bright = shade(surface(roughness=0.0), UP, HEAD_ON)  # a mirror-like highlight
    torch.testing.assert_close(bright, torch.ones(3, 1, dtype=torch.float64))
    floor = shade(surface((0.0, 0.0, 0.0), roughness=0.0), UP, [Light((0.6, 0.0, 0.8), 2.0)])
    at_floor = shade(surface((0.0, 0.0, 0.0), roughness=0.05), UP, [Light((0.6, 0.0, 0.8), 2.0)])
    torch.testing.assert_close(floor, at_floor)


def test_shading_has_gradients_in_every_input():
    torch.manual_seed(0)
    count = 5
    base = torch.rand(3, count, dtype=torch.float64) * 0.5 + 0.1
    metallic = torch.rand(count, dtype=torch.float64) * 0.8 + 0.1
    roughness = torch.rand(count, dtype=torch.float64) * 0.7 + 0.2
    occlusion = torch.rand(count, dtype=torch.float64) * 0.8 + 0.1
    emissive = torch.rand(3, count, dtype=torch.float64) * 0.05
    normal = torch.nn.functional.normalize(
        torch.randn(3, count, dtype=torch.float64) * 0.2 + UP, dim=0
    )
    view = torch.nn.functional.normalize(torch.tensor([[0.1], [0.2], [1.0]]).double(), dim=0)
    lights = [Light((0.0, 0.6, 0.8), 0.5), Light((0.48, 0.0, 0.6 * 1.3333333333333333), 0.3)]
    inputs = [t.requires_grad_() for t in (base, metallic, roughness, occlusion, emissive, normal)]

    def radiance(*values):
        return shade(Surface(*values), view.expand(3, count), lights)

    assert torch.autograd.gradcheck(radiance, inputs)


def test_the_normal_map_frame_has_gradients_in_the_texel():
    torch.manual_seed(1)
    count = 4
    geometric = torch.randn(3, count, dtype=torch.float64) * 0.1 + UP
    tangent = torch.tensor([[1.0], [0.1], [0.0]], dtype=torch.float64).expand(3, count)
    handedness = torch.tensor([1.0, -1.0, 1.0, 1.0], dtype=torch.float64)
    texel = (torch.rand(3, count, dtype=torch.float64) * 0.4 + 0.3).requires_grad_()
    view = UP.expand(3, count)

    def normal(t):
        return shading_normal(geometric, tangent, handedness, view, t, 0.8)

    assert torch.autograd.gradcheck(normal, [texel])


def frame(count: int = 1):
    ones = torch.ones(count)
    x = torch.tensor([[1.0], [0.0], [0.0]]).expand(3, count)
    return UP.float().expand(3, count), x, ones


def test_a_flat_normal_map_is_no_map_and_green_tilts_towards_the_bitangent():
    geometric, tangent, handedness = frame()
    view = UP.float()
    flat = torch.tensor([[0.5], [0.5], [1.0]])
    torch.testing.assert_close(
        shading_normal(geometric, tangent, handedness, view, flat), geometric
    )
    green_up = torch.tensor([[0.5], [0.75], [0.75]])  # t = (0, 0.5, 0.5): 45 degrees towards +B
    tilted = shading_normal(geometric, tangent, handedness, view, green_up)
    b = 1 / math.sqrt(2)
    torch.testing.assert_close(tilted, torch.tensor([[0.0], [b], [b]]))
    mirrored = shading_normal(geometric, tangent, -handedness, view, green_up)
    torch.testing.assert_close(mirrored, torch.tensor([[0.0], [-b], [b]]))


def test_the_back_of_a_surface_is_shaded_with_its_frame_turned_round():
    geometric, tangent, handedness = frame()
    behind = -UP.float()
    green_up = torch.tensor([[0.5], [0.75], [0.75]])
    normal = shading_normal(geometric, tangent, handedness, behind, green_up)
    b = 1 / math.sqrt(2)
    torch.testing.assert_close(normal, torch.tensor([[0.0], [-b], [-b]]))  # -(B + N) / sqrt 2
    red_right = torch.tensor([[0.75], [0.5], [0.75]])
    normal = shading_normal(geometric, tangent, handedness, behind, red_right)
    torch.testing.assert_close(normal, torch.tensor([[-b], [0.0], [-b]]))  # -(T + N) / sqrt 2


def test_tangents_follow_u_and_their_sign_says_which_way_v_runs():
    mesh = quad_mesh(np.zeros((4, 4, 3), np.uint8))
    tangents = vertex_tangents(mesh.positions, mesh.faces, mesh.uvs, mesh.normals)
    np.testing.assert_allclose(tangents, np.tile([1.0, 0.0, 0.0, 1.0], (4, 1)), atol=1e-6)
    flipped_v = mesh.uvs * np.array([1.0, -1.0], np.float32)
    tangents = vertex_tangents(mesh.positions, mesh.faces, flipped_v, mesh.normals)
    np.testing.assert_allclose(tangents, np.tile([1.0, 0.0, 0.0, -1.0], (4, 1)), atol=1e-6)
    no_area = np.zeros_like(mesh.uvs)
    tangents = vertex_tangents(mesh.positions, mesh.faces, no_area, mesh.normals)
    np.testing.assert_allclose(tangents, np.tile([1.0, 0.0, 0.0, 1.0], (4, 1)))


def pbr_quad(normal_rgb=(128, 128, 255), roughness=200, metallic=0) -> tuple:
    base = np.full((8, 8, 3), 180, np.uint8)
    arm = np.zeros((8, 8, 3), np.uint8)
    arm[..., 0], arm[..., 1], arm[..., 2] = 255, roughness, metallic
    normal = np.zeros((8, 8, 3), np.uint8)
    normal[...] = normal_rgb
    mesh = quad_mesh(base)
    material = Material(
        "pbr",
        base,
        properties={"pbrMetallicRoughness": {"metallicFactor": 1.0}, "normalTexture": {}},
        maps={"metallicRoughnessTexture": arm, "normalTexture": normal},
    )
    return replace(mesh, materials=[material])


HEAD_ON_CAMERA = Camera((0.0, 0.0, 1.0), 2.4)
SMALL = Evaluation(image_size=16, reference_max_size=None)


def lit_image(mesh) -> torch.Tensor:
    scene = LitScene(Renderer(mesh, "cpu", SMALL))
    return scene.render(scene.view(HEAD_ON_CAMERA), lit_materials(mesh, "cpu"))


def test_a_flat_normal_map_renders_as_no_map():
    mesh = pbr_quad()
    without = replace(
        mesh, materials=[replace(mesh.materials[0], maps=dict(mesh.materials[0].maps))]
    )
    del without.materials[0].maps["normalTexture"]
    # 255 encodes z = 1 and 128 encodes 1/255 in x and y: within a thousandth of flat.
    torch.testing.assert_close(lit_image(mesh), lit_image(without), atol=2e-3, rtol=0)


def test_green_up_turns_the_quad_towards_the_key_light_above_it():
    # The key light comes from above and left of the eye (the weaker fill from below right):
    # a normal tilted up (+green: towards increasing v on this quad) catches more light than
    # one tilted down, one tilted left (-red) more than one tilted right.
    up, down = (lit_image(pbr_quad((128, g, 230))).mean() for g in (200, 56))
    left, right = (lit_image(pbr_quad((r, 128, 230))).mean() for r in (56, 200))
    assert up > down + 0.02
    assert left > right + 0.02


def test_the_lit_render_has_gradients_in_every_map():
    mesh = pbr_quad()
    mesh.materials[0].maps["occlusionTexture"] = np.full((4, 4, 1), 200, np.uint8)
    mesh.materials[0].maps["emissiveTexture"] = np.full((4, 4, 3), 20, np.uint8)
    mesh.materials[0].properties["emissiveFactor"] = [0.5, 0.5, 0.5]
    scene = LitScene(Renderer(mesh, "cpu", Evaluation(image_size=4, reference_max_size=None)))
    view = scene.view(HEAD_ON_CAMERA)
    view64 = LitView(
        view.gbuffer,
        UVFootprint(*(t.double() for t in view.footprint)),
        *(t.double() for t in (view.view, view.geometric, view.tangent, view.handedness)),
        view.material,
        view.lights,
    )
    reference = lit_materials(mesh, "cpu", encoded=False)[0]
    slots = list(reference.maps)
    assert len(slots) == 5
    torch.manual_seed(2)
    texels = [
        (torch.rand(4, 4, 3, dtype=torch.float64) * 0.5 + 0.25).requires_grad_() for _ in slots
    ]

    def radiance(*tables):
        maps = {slot: MipTexture(t) for slot, t in zip(slots, tables, strict=True)}
        material = replace(reference, maps=maps)
        return shade(_material_surface(view64, material, None), view64.view, view64.lights)

    assert torch.autograd.gradcheck(radiance, texels)


def test_maps_on_another_uv_set_are_refused_with_the_way_out():
    mesh = pbr_quad()
    mesh.materials[0].properties["normalTexture"] = {"texCoord": 1}
    with pytest.raises(GeoscalerError, match="normalTexture.*--protocol 1"):
        lit_materials(mesh, "cpu")


def test_scores_of_the_original_itself_are_perfect_and_a_changed_map_scores_lower():
    mesh = pbr_quad(roughness=120)
    darker = mesh.with_images(
        {
            id(mesh.materials[0].maps["metallicRoughnessTexture"]): (
                np.dstack([np.full((8, 8), 255), np.full((8, 8), 60), np.zeros((8, 8))]).astype(
                    np.uint8
                )
            )
        }
    )
    (same, changed), foreground = lit_scores(mesh, [mesh, darker], [HEAD_ON_CAMERA], "cpu")
    assert math.isinf(float(same["psnr_fg"][0]))
    assert float(changed["psnr_fg"][0]) < 40
    assert foreground.shape == (1,) and foreground[0] > 1000  # the quad fills much of the view


def test_a_mesh_whose_maps_lit_renders_cannot_read_defaults_to_protocol_1():
    from geoscaler.render.lit import default_protocol

    mesh = pbr_quad()
    assert default_protocol(mesh) == 2
    mesh.materials[0].properties["normalTexture"] = {"texCoord": 1}
    assert default_protocol(mesh) == 1
