"""Cached lit views: a candidate rendered through sample taps is the lit render, values and
gradients, and its PSNR is protocol 2's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from mesh_support import pbr_demo, three_material_demo

from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import Camera, sample_training_cameras
from geoscaler.render.lit import LitScene, lit_materials, lit_scores
from geoscaler.render.lit_views import LitViews, map_sizes
from geoscaler.render.renderer import Renderer
from geoscaler.resize.filters import resize_channels

SMALL = Evaluation(image_size=48, reference_max_size=None)
CAMERAS = [Camera((0.3, -0.8, 0.5), 1.6), Camera((-0.6, 0.2, -0.7), 3.5)]


def smaller(mesh, factor=4):
    """``mesh`` with every map resized to a quarter per side (Lanczos, channels apart)."""
    from PIL import Image

    replacements = {}
    for pixels, _ in mesh.images():
        size = (pixels.shape[0] // factor, pixels.shape[1] // factor)
        replacements[id(pixels)] = resize_channels(pixels, size, Image.Resampling.LANCZOS)
    return mesh.with_images(replacements)


def cached(mesh, candidate, cameras=CAMERAS):
    scene = LitScene(Renderer(mesh, "cpu", SMALL))
    sizes = map_sizes(lit_materials(candidate, "cpu", encoded=False))
    views = LitViews(scene, lit_materials(mesh, "cpu"), sizes, cameras)
    while views.cache_next():
        pass
    return scene, views


def test_a_candidate_through_its_taps_is_its_lit_render_at_the_objects_pixels():
    mesh = pbr_demo(texture_size=64)
    candidate = smaller(mesh)
    scene, views = cached(mesh, candidate)
    materials = lit_materials(candidate, "cpu", encoded=False)
    for index, camera in enumerate(CAMERAS):
        full = scene.render(scene.view(camera), materials).reshape(-1, 3)
        pixels = views.views[index].pixels
        torch.testing.assert_close(views.colours(index, materials), full[pixels])
        reference = scene.render(scene.view(camera), lit_materials(mesh, "cpu"))
        torch.testing.assert_close(views.views[index].reference, reference.reshape(-1, 3)[pixels])


def test_each_material_reads_its_own_maps():
    mesh = three_material_demo()
    normal = np.zeros((32, 32, 3), np.uint8) + np.array([100, 160, 230], np.uint8)
    mesh.materials[1] = replace(mesh.materials[1], maps={**mesh.materials[1].maps})
    mesh.materials[1].maps["normalTexture"] = normal
    candidate = smaller(mesh, factor=2)
    scene, views = cached(mesh, candidate)
    materials = lit_materials(candidate, "cpu", encoded=False)
    full = scene.render(scene.view(CAMERAS[0]), materials).reshape(-1, 3)
    torch.testing.assert_close(views.colours(0, materials), full[views.views[0].pixels])


def test_the_gradient_through_the_taps_is_the_gradient_of_the_lit_render():
    mesh = pbr_demo(texture_size=32, subdivisions=4)
    candidate = smaller(mesh)
    scene, views = cached(mesh, candidate, CAMERAS[:1])
    reference = views.views[0].reference
    pixels = views.views[0].pixels

    def gradients(loss_of):
        materials = lit_materials(candidate, "cpu", encoded=False)
        tables = [chain.table.requires_grad_() for chain in materials[0].maps.values()]
        loss_of(materials).backward()
        return [t.grad for t in tables]

    through_taps = gradients(lambda m: (views.colours(0, m) - reference).square().sum())
    lit_view = scene.view(CAMERAS[0])
    rendered = gradients(
        lambda m: (scene.render(lit_view, m).reshape(-1, 3)[pixels] - reference).square().sum()
    )
    assert all(float(g.abs().max()) > 0 for g in through_taps)
    for mine, theirs in zip(through_taps, rendered, strict=True):
        torch.testing.assert_close(mine, theirs, rtol=1e-4, atol=1e-6)


def test_psnr_is_protocol_2s_score():
    mesh = pbr_demo(texture_size=64)
    candidate = smaller(mesh)
    cameras = sample_training_cameras(3, seed=5)
    _, views = cached(mesh, candidate, cameras)
    (scores,), _ = lit_scores(mesh, [candidate], cameras, "cpu", SMALL)
    mine = views.psnr(lit_materials(candidate, "cpu", encoded=False))
    np.testing.assert_allclose(mine, scores["psnr_fg"].numpy(), rtol=0, atol=1e-3)
    assert views.nbytes > 0 and len(views) == 3 and views.complete
