"""Rendering per PROTOCOL.md: unlit texture x factor, level of detail, 2 x 2 resolve."""

import math

import numpy as np
import pytest
import torch
from mesh_support import HALF, quad_mesh, three_material_demo

from geoscaler.color import linear_to_srgb, srgb_to_linear, texture_to_linear
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import Camera, validation_cameras
from geoscaler.render.encoded import EncodedMipTexture
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture

TAN = math.tan(math.radians(22.5))


def checker(size: int, cell: int = 1) -> np.ndarray:
    index = np.arange(size) // cell
    board = ((index[:, None] + index[None, :]) % 2 * 255).astype(np.uint8)
    return np.repeat(board[..., None], 3, axis=2)


def front(distance: float) -> Camera:
    return Camera((0.0, 0.0, 1.0), distance)


def test_constant_texture_renders_its_colour_times_the_factor():
    texture = np.full((8, 8, 3), [200, 100, 50], dtype=np.uint8)
    renderer = Renderer(
        quad_mesh(texture, factor=(0.5, 1.0, 1.0, 1.0)), "cpu", Evaluation(image_size=64)
    )
    gbuffer = renderer.rasterize(front(2.4))
    image = renderer.render(gbuffer, renderer.reference_textures())
    inside = renderer.foreground(gbuffer)
    expected_linear = srgb_to_linear(torch.tensor([200, 100, 50]) / 255.0) * torch.tensor(
        [0.5, 1, 1]
    )
    # Interior pixels (all four samples covered) show exactly the shaded colour.
    core = image[24:40, 24:40].reshape(-1, 3)
    torch.testing.assert_close(core, linear_to_srgb(expected_linear).expand_as(core))
    assert image[~inside].abs().max() == 0  # black background
    assert inside.sum() > 0 and (~inside).sum() > 0


def test_foreground_is_any_covered_sample():
    renderer = Renderer(quad_mesh(checker(4)), "cpu", Evaluation(image_size=32))
    gbuffer = renderer.rasterize(front(2.4))
    coverage = gbuffer.coverage().view(32, 2, 32, 2).any(3).any(1)
    assert torch.equal(renderer.foreground(gbuffer), coverage)


def footprint_lod(renderer: Renderer, camera: Camera, texture: MipTexture) -> torch.Tensor:
    footprint = renderer.footprint(renderer.rasterize(camera))
    return texture.level_of_detail(
        footprint.du_dx, footprint.dv_dx, footprint.du_dy, footprint.dv_dy
    )


@pytest.mark.parametrize("distance", [1.5, 2.4, 4.0])
def test_level_of_detail_follows_the_analytic_jacobian(distance):
    size = 256
    renderer = Renderer(quad_mesh(checker(size)), "cpu", Evaluation(image_size=64))
    texture = renderer.reference_textures()[0]
    # A facing quad of side 2 HALF spans size texels; one sample step covers
    # 2 / resolution NDC = (2 / resolution) D tan(22.5) world units.
    texels_per_sample = size / (2 * HALF) * (2 / renderer.resolution) * distance * TAN
    lod = footprint_lod(renderer, front(distance), texture)
    torch.testing.assert_close(lod, torch.full_like(lod, math.log2(texels_per_sample)))


def test_minified_checker_renders_as_its_mip_average():
    # Texel-sized checker: every level from 1 down is uniform grey 0.5 in linear light.
    renderer = Renderer(quad_mesh(checker(256)), "cpu", Evaluation(image_size=64))
    gbuffer = renderer.rasterize(front(2.4))
    image = renderer.render(gbuffer, renderer.reference_textures())
    grey = linear_to_srgb(torch.tensor(0.5)).item()
    torch.testing.assert_close(image[24:40, 24:40], torch.full((16, 16, 3), grey))


def test_magnified_texture_uses_level_zero_bilinear():
    # 4 x 4 texels seen at 1.5: texels are magnified, so every sample is a level-0 bilinear tap.
    renderer = Renderer(quad_mesh(checker(4)), "cpu", Evaluation(image_size=128))
    gbuffer = renderer.rasterize(front(1.5))
    texture = renderer.reference_textures()[0]
    assert footprint_lod(renderer, front(1.5), texture).max() < 0
    footprint = renderer.footprint(gbuffer)
    level0 = torch.zeros(gbuffer.num_samples, dtype=torch.long)
    expected = linear_to_srgb(
        renderer.resolve(gbuffer, texture.bilinear(footprint.u, footprint.v, level0))
    )
    image = renderer.render(gbuffer, [texture])
    assert torch.equal(image, expected)
    assert image.max() > 0.95 and image.min() < 0.15  # the texels stay distinct, not averaged


def test_render_is_differentiable_in_texels_and_uvs():
    mesh = quad_mesh(checker(4))
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=6))
    gbuffer = renderer.rasterize(Camera((0.3, 0.2, 0.93), 2.0))
    texels = torch.rand(4, 4, 3, dtype=torch.float64, requires_grad=True)
    uvs = renderer.uvs.double().mul(0.9).add(0.03).requires_grad_(True)

    def image(texels, uvs):
        return renderer.resolve(gbuffer, renderer.shade(gbuffer, [MipTexture(texels)], uvs))

    assert torch.autograd.gradcheck(image, (texels, uvs), atol=1e-5)


def test_demo_asset_renders_deterministically_with_multi_chart_uvs():
    mesh = demo_mesh(subdivisions=8, texture_size=128)
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=64))
    camera = validation_cameras()[7]
    first = renderer.render(renderer.rasterize(camera), renderer.reference_textures())
    second = renderer.render(renderer.rasterize(camera), renderer.reference_textures())
    assert torch.equal(first, second)
    assert renderer.foreground(renderer.rasterize(camera)).float().mean() > 0.3


def test_references_keep_the_originals_8bit_texels_once_and_render_as_float_chains_do():
    mesh = three_material_demo()  # materials 0 and 1 show one image, 2 none
    image = mesh.materials[0].base_color_texture
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=48))
    chains = renderer.reference_textures()
    assert isinstance(chains[0], EncodedMipTexture) and chains[1] is chains[0]
    assert chains[2] is None
    assert chains[0].codes.data_ptr() == image.ctypes.data  # the image itself, no float level 0
    floats = [MipTexture(texture_to_linear(image))] * 2 + [None]
    for camera in validation_cameras()[:3]:
        gbuffer = renderer.rasterize(camera)
        assert torch.equal(renderer.render_reference(gbuffer), renderer.render(gbuffer, floats))


def test_a_layout_given_per_face_corner_renders_as_per_vertex_uvs_do():
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=32))
    gbuffer = renderer.rasterize(validation_cameras()[2])
    textures = renderer.reference_textures()
    moved = renderer.uvs * 0.5 + 0.25
    corners = moved[renderer.faces]  # (F, 3, 2): a cut layout's form
    assert torch.equal(
        renderer.render(gbuffer, textures, corners), renderer.render(gbuffer, textures, moved)
    )
    relaid = renderer.relaid(corners.numpy())
    assert len(relaid.mesh.uvs) == len(mesh.uvs)  # corners that agree split no vertex
    assert torch.equal(relaid.render(gbuffer, textures), renderer.render(gbuffer, textures, moved))
