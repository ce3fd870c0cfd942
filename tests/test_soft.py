"""The paper's soft rasteriser (geoscaler.render.soft): SoftRas / PyTorch3D semantics on small
analytic scenes, its gradients, its bounded-memory machinery against an untiled reference, and the
training loop's soft option."""

import math

import numpy as np
import pytest
import torch
from mesh_support import quad_mesh, three_material_demo

from geoscaler.color import quantize_linear, texture_to_linear
from geoscaler.methods.direct import TexelModel
from geoscaler.optim.loop import OptimizeConfig, optimize
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import Camera
from geoscaler.render.raster import GBuffer, rasterize
from geoscaler.render.renderer import Renderer
from geoscaler.render.soft import (
    EPS,
    SoftFragments,
    SoftRenderer,
    SoftSettings,
    interpolate,
    soft_rasterize,
)
from geoscaler.render.views import training_views
from geoscaler.resize.filters import lanczos, output_sizes, reference_textures

F64 = torch.float64
DEPTH_RANGE = (1.0, 100.0)


def sigmoid(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x))


def facing(corners_ndc, depth=1.0) -> torch.Tensor:
    """``(V, 4)`` clip positions of NDC points at view depth ``depth`` (``w``), ``z = 0``."""
    xy = torch.as_tensor(corners_ndc, dtype=F64)
    w = torch.full((len(xy), 1), float(depth), dtype=F64)
    return torch.cat([xy * w, torch.zeros_like(w), w], dim=1)


def grid(points, resolution: int):
    """NDC of grid corners given in sample units (corner g sits at ``-1 + g * 2 / res``)."""
    return [(-1 + 2 * x / resolution, -1 + 2 * y / resolution) for x, y in points]


def blend(fragments: SoftFragments, faces: torch.Tensor, colours: torch.Tensor) -> torch.Tensor:
    """``(samples, C)`` blended per-vertex ``colours`` (background black)."""
    values = interpolate(fragments, faces, colours) * fragments.weight
    image = values.new_zeros(values.shape[0], fragments.resolution**2)
    return image.index_add(1, fragments.sample.long(), values).T


# ----------------------------------------------------------------------------- coverage


def test_soft_coverage_converges_to_the_hard_coverage_as_sigma_shrinks():
    """Two triangles facing the camera, edges on sample boundaries or at slope +-2 through
    grid corners, so no sample centre lies closer than 0.2236 samples to an edge."""
    res = 32
    corners = grid([(4, 4), (14, 4), (14, 24), (18, 6), (28, 6), (18, 26)], res)
    clip, faces = facing(corners), torch.tensor([[0, 1, 2], [3, 4, 5]])
    hard = rasterize(clip, faces, res).coverage().to(F64)
    mismatch = []
    for sigma in (1e-2, 1e-3, 1e-4, 1e-5):
        soft = soft_rasterize(clip, faces, res, DEPTH_RANGE, SoftSettings(sigma=sigma), F64)
        difference = (soft.coverage() - hard).abs()
        mismatch.append(float(difference.mean()))
    assert all(a > b for a, b in zip(mismatch, mismatch[1:], strict=False)), mismatch
    # the nearest samples sit at squared distance (0.2236 * 2 / 32)^2 = 1.95e-4: sigmoid(-19.5)
    assert mismatch[-1] < 1e-9 and difference.max() < 1e-8  # measured 6.4e-11 and 3.3e-9
    assert mismatch[0] > 0.05  # sigma 1e-2 blurs over a third of the frame


def test_a_triangles_soft_coverage_is_the_sigmoid_of_its_squared_distance():
    """One triangle, corners (-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5) in NDC; 16 x 16 samples
    (centres at odd multiples of 1/16)."""
    res, sigma = 16, 1e-2
    clip = facing([(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5)])
    settings = SoftSettings(sigma=sigma)
    fragments = soft_rasterize(clip, torch.tensor([[0, 1, 2]]), res, DEPTH_RANGE, settings, F64)
    alpha = fragments.coverage()

    def at(x: float, y: float) -> float:  # NDC -> alpha of that sample
        col, row = round((x + 1) * res / 2 - 0.5), round((1 - y) * res / 2 - 0.5)
        return float(alpha[row, col])

    step = 2 / res
    below = [(-3 / 16, -0.5 - k * step - step / 2) for k in range(2)]  # under the bottom edge
    for x, y in below:
        assert at(x, y) == pytest.approx(sigmoid(-((y + 0.5) ** 2) / sigma), rel=1e-12)
    corner = (0.5 + 1 / 16, -0.5 - 1 / 16)  # beyond the corner (0.5, -0.5): distance to it
    d2 = 2 * (1 / 16) ** 2
    assert at(*corner) == pytest.approx(sigmoid(-d2 / sigma), rel=1e-12)
    hypotenuse = (3 / 16, 1 / 16)  # beyond x + y = 0: distance (x + y) / sqrt 2
    assert at(*hypotenuse) == pytest.approx(sigmoid(-((4 / 16) ** 2 / 2) / sigma), rel=1e-12)
    inside = (-7 / 16, -5 / 16)  # nearest edge: the left one, x = -0.5
    assert at(*inside) == pytest.approx(sigmoid((1 / 16) ** 2 / sigma), rel=1e-12)
    # beyond the blur radius (squared distance log(1e4 - 1) sigma) nothing is drawn
    radius = math.sqrt(settings.radius)
    assert at(-3 / 16, -0.5 - radius - step) == 0.0


# ----------------------------------------------------------------------------- depth blend


@pytest.mark.parametrize("sigma", [1e-4, 1e-2])
def test_a_nearer_opaque_triangle_dominates_a_farther_one_as_gamma_shrinks(sigma):
    """The same screen triangle at view depths 2 (red) and 3 (blue), both covering the sample
    at (1/16, -1/16) of a 16 x 16 grid; its nearest edge is the bottom one, 7/16 away."""
    res = 16
    corners = [(-0.9, -0.5), (0.9, -0.5), (0.0, 0.9)]
    clip = torch.cat([facing(corners, 2.0), facing(corners, 3.0)])
    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])
    colours = torch.tensor([[1.0, 0, 0]] * 3 + [[0, 0, 1.0]] * 3, dtype=F64)
    sample = 8 * res + 8  # row 8, column 8: NDC (1/16, -1/16)
    p = sigmoid((7 / 16) ** 2 / sigma)  # inside both
    near, far = [(DEPTH_RANGE[1] - z) / (DEPTH_RANGE[1] - DEPTH_RANGE[0]) for z in (2.0, 3.0)]
    red = []
    for gamma in (1.0, 1e-1, 1e-2, 1e-3, 1e-4):
        settings = SoftSettings(sigma=sigma, gamma=gamma)
        fragments = soft_rasterize(clip, faces, res, DEPTH_RANGE, settings, F64)
        colour = blend(fragments, faces, colours)[sample]
        w_near, w_far = p, p * math.exp((far - near) / gamma)
        delta = max(math.exp((EPS - near) / gamma), EPS)
        total = w_near + w_far + delta
        assert colour.tolist() == pytest.approx([w_near / total, 0, w_far / total], rel=1e-9)
        red.append(float(colour[0]))
    assert all(a < b for a, b in zip(red, red[1:], strict=False))
    assert red[-1] > 1 - 1e-9  # opaque: no blue, and the background's floor is 1e-10


# ----------------------------------------------------------------------------- gradients


def test_gradients_reach_texels_and_vertex_uvs():
    """gradcheck in float64: a 4 x 4 image of a slanted quad (two triangles), a 4 x 4 texture."""
    generator = torch.Generator().manual_seed(3)
    mesh = quad_mesh(np.zeros((4, 4, 3), dtype=np.uint8))
    soft = SoftRenderer(
        mesh, "cpu", Evaluation(image_size=4, supersample=1), SoftSettings(sigma=1e-3), dtype=F64
    )
    fragments = soft.rasterize(Camera((0.3, 0.2, 0.93), 2.0))
    assert fragments.num_entries > 16  # several triangles per sample: the blend is exercised
    texture = (0.2 + 0.6 * torch.rand(4, 4, 3, generator=generator, dtype=F64)).requires_grad_()
    uvs = torch.tensor([[0.03, 0.05], [0.91, 0.02], [0.97, 0.93], [0.06, 0.88]], dtype=F64)
    uvs.requires_grad_()

    def render(texture, uvs):
        return soft.render(fragments, [texture], uvs)

    assert torch.autograd.gradcheck(render, (texture, uvs), eps=1e-6, atol=1e-8)
    render(texture, uvs).sum().backward()
    assert (texture.grad != 0).sum() > 8 and (uvs.grad != 0).all()


# ----------------------------------------------------------------------------- tiles


def reference_fragments(clip, faces, res, settings):
    """An untiled, unchunked reference: every sample against every triangle (numpy float64),
    the formulas of the module docstring written out plainly. Returns ``(alpha, entries,
    binding)``: ``(res * res,)`` coverage, a dict ``(sample, face) -> (weight, (3,) bary)`` and
    the number of samples with more candidates than K."""
    clip, faces = clip.numpy(), faces.numpy()
    step = 2.0 / res
    cols, rows = np.meshgrid(np.arange(res), np.arange(res))
    px = ((cols + 0.5) * step - 1.0).reshape(-1, 1)
    py = (1.0 - (rows + 0.5) * step).reshape(-1, 1)
    w = clip[faces][..., 3]
    x, y = clip[faces][..., 0] / w, clip[faces][..., 1] / w

    def cross(ax, ay, bx, by):
        return ax * by - ay * bx

    area = cross(x[:, 1] - x[:, 0], y[:, 1] - y[:, 0], x[:, 2] - x[:, 0], y[:, 2] - y[:, 0])
    i, j = [1, 2, 0], [2, 0, 1]  # l_k: the area of (p, corner k + 1, corner k + 2)
    dx, dy = x - px[..., None], y - py[..., None]  # (P, F, 3): corners seen from the sample
    lam = np.stack(
        [cross(dx[..., i[k]], dy[..., i[k]], dx[..., j[k]], dy[..., j[k]]) for k in range(3)]
    )
    lam /= area  # (3, P, F)
    inside = (lam > 0).all(0)
    d2 = np.full(inside.shape, np.inf)
    for k in range(3):
        ax, ay, bx, by = x[:, k], y[:, k], x[:, (k + 1) % 3], y[:, (k + 1) % 3]
        ex, ey = bx - ax, by - ay
        t = np.clip(((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey), 0, 1)
        d2 = np.minimum(d2, (px - ax - t * ex) ** 2 + (py - ay - t * ey) ** 2)
    bary = np.maximum(lam / w.T[:, None, :], 0)
    bary /= bary.sum(0)
    depth = (bary * w.T[:, None, :]).sum(0)
    valid = inside | (d2 < settings.radius)
    znear, zfar = DEPTH_RANGE
    alpha, entries, binding = np.zeros(res * res), {}, 0
    for p in range(res * res):
        candidates = sorted(np.nonzero(valid[p])[0], key=lambda f: depth[p, f])
        binding += len(candidates) > settings.faces_per_pixel
        chosen = candidates[: settings.faces_per_pixel]
        if not chosen:
            continue
        prob = [sigmoid((d2 if inside[p, f] else -d2)[p, f] / settings.sigma) for f in chosen]
        alpha[p] = 1 - np.prod([1 - q for q in prob])
        z_inv = [(zfar - depth[p, f]) / (zfar - znear) for f in chosen]
        top = max(max(z_inv), EPS)
        num = [q * math.exp((z - top) / settings.gamma) for q, z in zip(prob, z_inv, strict=True)]
        delta = max(math.exp((EPS - top) / settings.gamma), EPS)
        for f, n in zip(chosen, num, strict=True):
            if n > 0:
                entries[p, f] = (n / (sum(num) + delta), bary[:, p, f])
    return alpha, entries, binding


def overlapping_triangles(count: int = 14, seed: int = 5):
    """Random triangles in NDC at random (per corner) view depths: they overlap, most samples
    see several, and depths never tie."""
    rng = np.random.default_rng(seed)
    ndc = rng.uniform(-0.95, 0.95, size=(count * 3, 2))
    w = rng.uniform(1.5, 3.0, size=(count * 3, 1))
    clip = np.concatenate([ndc * w, np.zeros_like(w), w], axis=1)
    return torch.from_numpy(clip), torch.arange(count * 3).view(count, 3)


@pytest.mark.parametrize("tile,chunk", [(4, 64), (8, 1000), (32, 1 << 20)])
def test_tiles_and_chunks_give_the_untiled_reference(tile, chunk):
    res, settings = 24, SoftSettings(sigma=3e-3, gamma=1e-2, faces_per_pixel=3)
    clip, faces = overlapping_triangles()
    fragments = soft_rasterize(clip, faces, res, DEPTH_RANGE, settings, F64, tile, chunk)
    alpha, entries, binding = reference_fragments(clip, faces, res, settings)
    assert len(entries) > 1.5 * res * res  # several candidates per sample ...
    assert binding > res  # ... and K = 3 leaves some out
    columns = (fragments.sample, fragments.face, fragments.weight, fragments.bary.T)
    found = {(int(s), int(f)): (float(w), b) for s, f, w, b in zip(*columns, strict=True)}
    assert found.keys() == entries.keys()
    for key, (weight, bary) in entries.items():
        assert found[key][0] == pytest.approx(weight, rel=1e-12, abs=1e-15)
        assert found[key][1].numpy() == pytest.approx(bary, abs=1e-12)
    assert fragments.coverage().reshape(-1).numpy() == pytest.approx(alpha, abs=1e-12)
    colours = torch.rand(len(clip), 3, generator=torch.Generator().manual_seed(1), dtype=F64)
    image = torch.zeros(res * res, 3, dtype=F64)
    for (s, f), (weight, bary) in entries.items():
        image[s] += weight * (torch.from_numpy(bary)[:, None] * colours[faces[f]]).sum(0)
    assert torch.allclose(blend(fragments, faces, colours), image, atol=1e-12, rtol=0)


def test_each_sample_keeps_at_most_k_candidates_the_nearest_in_depth():
    res, settings = 24, SoftSettings(sigma=3e-3, gamma=1e-2, faces_per_pixel=2)
    clip, faces = overlapping_triangles()
    fragments = soft_rasterize(clip, faces, res, DEPTH_RANGE, settings, F64, tile=4)
    assert torch.bincount(fragments.sample.long()).max() <= 2
    assert (torch.diff(fragments.sample) >= 0).all()  # ordered by sample


# ----------------------------------------------------------------------------- the renderer


def test_with_a_vanishing_blur_it_renders_what_the_exact_renderer_renders():
    """Same cameras, image size and supersampling: a magnified texture (both read level 0
    bilinearly), so only the blur could tell them apart."""
    index = np.arange(4)
    board = ((index[:, None] + index[None, :]) % 2 * 200 + 30).astype(np.uint8)
    mesh = quad_mesh(np.repeat(board[..., None], 3, axis=2))
    evaluation = Evaluation(image_size=24, supersample=2)
    exact = Renderer(mesh, "cpu", evaluation)
    soft = SoftRenderer(mesh, "cpu", evaluation, SoftSettings(sigma=1e-9, faces_per_pixel=1))
    camera = Camera((0.3, -0.4, math.sqrt(0.75)), 2.0)
    gbuffer = exact.rasterize(camera)
    expected = exact.render(gbuffer, exact.reference_textures())
    fragments = soft.rasterize(camera)
    assert torch.equal(soft.foreground(fragments), exact.foreground(gbuffer))
    image = soft.render(fragments, soft.reference_textures())
    assert torch.allclose(image, expected, atol=1e-4)  # float32 rounding at the diagonal
    # mip chains are read at level 0 only, so the renderer's textures work as they are
    assert torch.allclose(soft.render(fragments, exact.reference_textures()), image, atol=1e-7)


def test_the_default_settings_are_pytorch3ds():
    settings = SoftSettings()
    assert (settings.sigma, settings.gamma, settings.faces_per_pixel) == (1e-4, 1e-4, 8)
    assert settings.radius == pytest.approx(math.log(1 / 1e-4 - 1) * 1e-4)
    assert settings.depth_range == (1.0, 100.0) and settings.supersample is None
    with pytest.raises(ValueError):
        SoftSettings(sigma=0)


def test_cached_taps_render_what_the_soft_renderer_renders_with_several_materials():
    """With the mesh's UVs a soft render is fixed taps of texels (summed per pixel and texel),
    for textured, tinted and untextured materials alike."""
    mesh = three_material_demo()
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=32))
    cameras = [Camera((0.6, 0.0, 0.8), 2.4), Camera((0.0, -1.0, 0.0), 1.5)]
    sizes = [(8, 8), (16, 8), None]
    soft = SoftSettings(sigma=1e-3)
    cached = training_views(renderer, cameras, sizes, True, soft)
    general = training_views(renderer, cameras, sizes, False, soft)
    textures = [torch.rand(8, 8, 3), torch.rand(16, 8, 3), None]
    for view in range(2):
        cached.views.cache_next()
        general.views.cache_next()
        torch.testing.assert_close(
            cached.render(view, textures, None),
            general.render(view, textures, None),
            atol=2e-6,
            rtol=0,
        )
        fragments = cached.views.gbuffers[view]
        assert isinstance(fragments, SoftFragments)
        taps = sum(len(t.texel) for t in cached.taps[view] if t is not None)
        assert taps < 4 * fragments.num_entries / 2  # summed per (pixel, texel)


# ----------------------------------------------------------------------------- training


@pytest.fixture(scope="module")
def scene():
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=32, views=(0, 20, 40)))
    views = validation_view_sets(renderer, guard_views=1)
    for view_set in views.values():
        while view_set.cache_next():
            pass
    return mesh, renderer, views


def train(scene, renderer_name: str, steps: int = 3):
    mesh, renderer, views = scene
    start = lanczos(reference_textures(mesh)[0], 4)
    model = TexelModel([texture_to_linear(start)])
    config = OptimizeConfig(
        steps=steps,
        pool_views=4,
        views_per_step=2,
        validate_every=steps,
        ssim_weight=0.0,
        training_renderer=renderer_name,
        soft=SoftSettings(sigma=1e-3),
    )
    validation = Validation(views, output_sizes(mesh, 4))
    return optimize(renderer, model, config, validation), validation


def test_soft_training_trains_and_validates_on_the_exact_renderer(scene):
    result, validation = train(scene, "soft")
    assert result.steps == 3 and result.training_views == 4
    assert all(math.isfinite(loss["loss"]) and loss["loss"] > 0 for loss in result.history)
    # validation stayed exact: its views are G-buffers, and its figure for what ships is the
    # loop's own
    assert all(isinstance(g, GBuffer) for s in validation.sets.values() for g in s.views.gbuffers)
    shipped = [quantize_linear(t) for t in result.textures]
    assert validation.psnr(shipped, None)["Q"] == pytest.approx(result.best_psnr, abs=1e-4)


def test_soft_training_moves_the_texture_differently_from_exact_training(scene):
    soft, _ = train(scene, "soft", steps=2)
    exact, _ = train(scene, "exact", steps=2)
    assert soft.history[0]["loss"] != pytest.approx(exact.history[0]["loss"], rel=1e-3)


def test_an_unknown_training_renderer_is_refused():
    with pytest.raises(ValueError, match="exact or soft"):
        OptimizeConfig(training_renderer="nvdiffrast")
