"""The OpenGL renderer of the app draws what the torch renderer draws (PROTOCOL.md).

Same mesh, same protocol camera, two implementations of one sampler: the GL image must match
the torch image at PSNR-fg >= 40 dB, and cover exactly the same pixels.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from app_support import gl_context, import_app_module
from conftest import mesh_params
from mesh_support import pbr_demo

from geoscaler.color import texture_to_linear
from geoscaler.io import load_mesh
from geoscaler.procedural import demo_mesh
from geoscaler.render.cameras import Camera, validation_cameras
from geoscaler.render.metrics import psnr_fg
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture
from geoscaler.resize.filters import reference_textures

AGREEMENT_DB = 40.0


@pytest.fixture(scope="module")
def ctx():
    context = gl_context()
    yield context
    context.release()


def both_renders(ctx, mesh, camera: Camera, textures=None, uvs=None):
    """``(gl image, gl foreground, torch image, torch foreground)`` of one view (float images),
    with ``textures`` (default: the protocol's reference maps) and ``uvs`` (default: the mesh's).
    """
    gl_renderer = import_app_module("gl_renderer")
    textures = reference_textures(mesh) if textures is None else textures
    gl = gl_renderer.GLRenderer(ctx, mesh)
    surface = gl_renderer.Surface(gl, textures, uvs)
    image, foreground = gl.render_image(camera, surface)
    surface.release()

    renderer = Renderer(mesh, "cpu")
    mips = [None if t is None else MipTexture(texture_to_linear(t)) for t in textures]
    gbuffer = renderer.rasterize(camera)
    torch_uvs = None if uvs is None else torch.from_numpy(uvs)
    reference = renderer.render(gbuffer, mips, torch_uvs)
    return (
        torch.from_numpy(image).float() / 255,
        torch.from_numpy(foreground),
        reference,
        renderer.foreground(gbuffer),
    )


def agreement(ctx, mesh, camera, textures=None, uvs=None) -> float:
    image, foreground, reference, torch_foreground = both_renders(ctx, mesh, camera, textures, uvs)
    assert torch.equal(foreground, torch_foreground) or (
        (foreground != torch_foreground).float().mean() < 1e-4
    ), "GL and torch cover different pixels"
    assert torch_foreground.any()
    return float(psnr_fg(image[None], reference[None], torch_foreground[None]))


@pytest.mark.parametrize("path", mesh_params())
def test_gl_matches_torch_on_every_development_mesh(ctx, path):
    mesh = load_mesh(path)
    view = 7  # a side view: both textures and silhouettes in frame
    assert agreement(ctx, mesh, validation_cameras()[view]) >= AGREEMENT_DB


@pytest.mark.parametrize("distance", [1.5, 2.4, 4.0], ids=["near", "validation", "far"])
def test_gl_matches_torch_on_the_demo_asset_near_and_far(ctx, distance):
    """Near views magnify texels (bilinear on level 0), far ones minify (coarse mip levels)."""
    mesh = demo_mesh(subdivisions=16, texture_size=512)
    assert agreement(ctx, mesh, validation_cameras(distance)[3]) >= AGREEMENT_DB


def test_gl_matches_torch_with_a_small_texture_and_moved_uvs(ctx):
    """A candidate as the app shows it: another texture size, UVs of its own (repeat wrap)."""
    mesh = demo_mesh(subdivisions=16, texture_size=512)
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, size=(96, 80, 3), dtype=np.uint8)  # odd mip sizes
    uvs = (mesh.uvs * 1.7 + 0.3).astype(np.float32)  # crosses tile borders
    assert agreement(ctx, mesh, validation_cameras()[11], [texture], uvs) >= AGREEMENT_DB


def test_a_flipped_texture_does_not_pass(ctx):
    """The check has teeth: the texture upside down in GL is far below the threshold."""
    gl_renderer = import_app_module("gl_renderer")
    mesh = demo_mesh(subdivisions=16, texture_size=256)
    camera = validation_cameras()[3]
    _, _, reference, foreground = both_renders(ctx, mesh, camera)
    gl = gl_renderer.GLRenderer(ctx, mesh)
    flipped = np.ascontiguousarray(mesh.materials[0].base_color_texture[::-1])
    image, _ = gl.render_image(camera, gl_renderer.Surface(gl, [flipped]))
    image = torch.from_numpy(image).float()[None] / 255
    assert float(psnr_fg(image, reference[None], foreground[None])) < 30.0


def test_a_pair_drawn_in_one_pass_is_two_single_renders(ctx):
    """``render_pair`` (the app's two views while the camera moves) draws the same pixels as
    ``render`` twice, with two textures of different sizes and UVs of their own."""
    gl_renderer = import_app_module("gl_renderer")
    mesh = demo_mesh(subdivisions=16, texture_size=256)
    gl = gl_renderer.GLRenderer(ctx, mesh, image_size=128)
    rng = np.random.default_rng(1)
    small = rng.integers(0, 256, size=(40, 56, 3), dtype=np.uint8)
    surfaces = (gl.reference_surface(), gl_renderer.Surface(gl, [small], mesh.uvs * 1.3 + 0.1))
    camera = validation_cameras()[5]
    for preview in (False, True):
        pair = gl.target_pair(preview)
        gl.render_pair(camera, surfaces, pair, pan=(0.1, -0.05))
        singles = []
        for surface, paired in zip(surfaces, pair, strict=True):
            single = gl.preview_target() if preview else gl.target()
            singles.append(gl.render(camera, surface, single, pan=(0.1, -0.05)).read())
            single.release()
            image, foreground = paired.read()
            assert np.array_equal(image, singles[-1][0])
            assert np.array_equal(foreground, singles[-1][1]) and foreground.mean() > 0.2
        assert not np.array_equal(singles[0][0], singles[1][0])  # two different pictures
        assert pair.targets[0].size == (64 if preview else 128)
        pair.release()


# ----------------------------------------------------------------------------- protocol 2, lit


def lit_agreement(ctx, mesh, camera: Camera) -> float:
    """PSNR-fg of the GL lit image against the torch lit image of one view."""
    from geoscaler.protocol import Evaluation
    from geoscaler.render.lit import LitScene, lit_materials

    gl_renderer = import_app_module("gl_renderer")
    gl = gl_renderer.GLRenderer(ctx, mesh)
    surface = gl_renderer.LitSurface(gl)
    image, foreground = gl.render_lit_image(camera, surface)
    surface.release()
    scene = LitScene(Renderer(mesh, "cpu", Evaluation(reference_max_size=None)))
    view = scene.view(camera)
    reference = scene.render(view, lit_materials(mesh, "cpu"))
    torch_foreground = scene.renderer.foreground(view.gbuffer)
    assert (torch.from_numpy(foreground) != torch_foreground).float().mean() < 1e-4
    assert torch_foreground.any()
    image = torch.from_numpy(image).float() / 255
    return float(psnr_fg(image[None], reference[None], torch_foreground[None]))


def pbr_mesh_params():
    return [p for p in mesh_params() if p.values[0] is None or p.id.startswith("ph_")]


@pytest.mark.parametrize("path", pbr_mesh_params())
def test_gl_lit_matches_torch_lit_on_the_pbr_development_meshes(ctx, path):
    mesh = load_mesh(path)
    for distance in (1.5, 4.0):
        assert lit_agreement(ctx, mesh, validation_cameras(distance)[7]) >= AGREEMENT_DB


def test_gl_lit_matches_torch_lit_with_a_bumpy_normal_map_and_its_scale(ctx):
    mesh = pbr_demo(subdivisions=16, seed=4)
    mesh.materials[0].properties["normalTexture"] = {"scale": 0.7}
    for view in (3, 40):
        assert lit_agreement(ctx, mesh, validation_cameras()[view]) >= AGREEMENT_DB


def test_gl_lit_matches_torch_lit_on_the_back_of_a_normal_mapped_quad(ctx):
    from dataclasses import replace

    from mesh_support import quad_mesh

    from geoscaler.mesh import Material

    rng = np.random.default_rng(6)
    normal = rng.integers(40, 216, (32, 32, 3), dtype=np.uint8)
    normal[..., 2] = 220
    base = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    material = Material("quad", base, maps={"normalTexture": normal})
    mesh = replace(quad_mesh(base), materials=[material])
    for direction in ((0.0, 0.3, 0.95), (0.0, 0.3, -0.95)):  # front, then back
        camera = Camera(tuple(np.asarray(direction) / np.linalg.norm(direction)), 2.4)
        assert lit_agreement(ctx, mesh, camera) >= AGREEMENT_DB
