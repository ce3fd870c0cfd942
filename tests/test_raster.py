"""The rasteriser on analytic scenes: coverage, perspective-correct interpolation, occlusion."""

import math

import numpy as np
import torch

from geoscaler.render.cameras import Camera
from geoscaler.render.raster import rasterize

CAMERA = Camera((0.0, 0.0, 1.0), 2.4)
TAN = math.tan(math.radians(22.5))


def clip_of(positions, camera=CAMERA) -> torch.Tensor:
    homogeneous = np.concatenate([np.asarray(positions, float), np.ones((len(positions), 1))], 1)
    return torch.from_numpy(homogeneous @ camera.clip_matrix().T)


def quad(half: float, z: float = 0.0):
    positions = [[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]]
    return positions, torch.tensor([[0, 1, 2], [0, 2, 3]])


def sample_centres_ndc(resolution):
    centres = (np.arange(resolution) + 0.5) * 2 / resolution - 1
    return centres, -centres  # x grows right, y grows down the rows


def test_facing_quad_covers_exactly_the_predicted_samples():
    resolution = 64
    positions, faces = quad(0.5)
    gbuffer = rasterize(clip_of(positions), faces, resolution)
    xs, ys = sample_centres_ndc(resolution)
    half_ndc = 0.5 / (2.4 * TAN)
    expected = (np.abs(ys)[:, None] <= half_ndc) & (np.abs(xs)[None, :] <= half_ndc)
    assert np.array_equal(gbuffer.coverage().numpy(), expected)
    assert expected.sum() == 32 * 32


def test_interpolated_positions_reproduce_the_quad():
    resolution = 64
    positions, faces = quad(0.5, z=0.3)
    gbuffer = rasterize(clip_of(positions), faces, resolution)
    b, _, _ = gbuffer.barycentrics()
    corners = torch.tensor(positions, dtype=torch.float32)[faces[gbuffer.tri_ids.long()]]
    points = (b.T[..., None] * corners).sum(1)
    sx, sy = gbuffer.sample_ndc()
    depth = 2.4 - 0.3
    expected = torch.stack([sx * depth * TAN, sy * depth * TAN, torch.full_like(sx, 0.3)], 1)
    torch.testing.assert_close(points, expected, atol=2e-6, rtol=0)


def test_tilted_plane_barycentrics_are_perspective_correct():
    resolution = 48
    # A plane tilted about the x axis: z = 0.6 y. Along each view ray the point on the plane
    # is known in closed form; affine (screen-space) interpolation would miss it.
    positions = [[-0.8, -0.8, -0.48], [0.8, -0.8, -0.48], [0.8, 0.8, 0.48], [-0.8, 0.8, 0.48]]
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    gbuffer = rasterize(clip_of(positions), faces, resolution)
    b, _, _ = gbuffer.barycentrics()
    corners = torch.tensor(positions, dtype=torch.float64)[faces[gbuffer.tri_ids.long()]]
    points = (b.T.double()[..., None] * corners).sum(1)
    sx, sy = (t.double() for t in gbuffer.sample_ndc())
    t = 2.4 / (1 + 0.6 * sy * TAN)  # eye-space depth where the ray meets z = 0.6 y
    expected = torch.stack([sx * t * TAN, sy * t * TAN, 2.4 - t], 1)
    torch.testing.assert_close(points, expected, atol=1e-5, rtol=0)


def test_barycentric_derivatives_match_uv_steps_on_a_facing_quad():
    resolution = 32
    positions, faces = quad(0.5)
    gbuffer = rasterize(clip_of(positions), faces, resolution)
    _, db_dx, db_dy = gbuffer.barycentrics()
    corners = torch.tensor(positions, dtype=torch.float32)[faces[gbuffer.tri_ids.long()]]
    dx = (db_dx.T[..., None] * corners).sum(1)
    dy = (db_dy.T[..., None] * corners).sum(1)
    world_per_sample = 2.0 / resolution * 2.4 * TAN
    torch.testing.assert_close(dx[:, 0], torch.full_like(dx[:, 0], world_per_sample))
    torch.testing.assert_close(dy[:, 1], torch.full_like(dy[:, 1], -world_per_sample))
    torch.testing.assert_close(dx[:, 1], torch.zeros_like(dx[:, 1]), atol=1e-6, rtol=0)


def test_derivatives_match_finite_differences_under_perspective():
    positions = [[-0.9, -0.7, -0.6], [0.9, -0.5, 0.1], [0.1, 0.9, 0.7]]
    faces = torch.tensor([[0, 1, 2]])
    fine, coarse = 256, 64
    gbuffer = rasterize(clip_of(positions), faces, coarse)
    b, db_dx, _ = gbuffer.barycentrics()
    # The same scene at 4x resolution: coarse sample (r, c) lies at fine position (4r+2, 4c+2),
    # midway between fine samples, so their differences are central differences there.
    dense = rasterize(clip_of(positions), faces, fine)
    bf, _, _ = dense.barycentrics()
    grid = torch.full((3, fine * fine), float("nan"))
    grid[:, dense.pixels.long()] = bf
    grid = grid.view(3, fine, fine)
    rows = gbuffer.pixels.long() // coarse * 4 + 1
    cols = gbuffer.pixels.long() % coarse * 4 + 1
    right = (grid[:, rows, cols + 1] + grid[:, rows + 1, cols + 1]) / 2
    left = (grid[:, rows, cols] + grid[:, rows + 1, cols]) / 2
    central = (right - left) * 4
    ok = ~central.isnan().any(0)
    assert ok.sum() > 500
    torch.testing.assert_close(central[:, ok], db_dx[:, ok], atol=1e-4, rtol=1e-3)
    assert torch.allclose(b.sum(0), torch.ones(b.shape[1]), atol=1e-6)


def test_occlusion_keeps_the_nearer_triangle_whatever_the_order():
    far_positions, _ = quad(0.6, z=-0.2)
    near_positions, _ = quad(0.3, z=0.4)
    positions = far_positions + near_positions
    faces = torch.tensor([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    for order in (faces, faces.flip(0)):
        gbuffer = rasterize(clip_of(positions), order, 64)
        seen = order[gbuffer.tri_ids.long()].min(1).values >= 4
        sx, sy = gbuffer.sample_ndc()
        inner = 0.3 / ((2.4 - 0.4) * TAN)
        in_near = (sx.abs() <= inner) & (sy.abs() <= inner)
        assert torch.equal(seen, in_near)


def test_a_fine_mesh_has_no_cracks_between_triangles():
    # A 30 x 30 grid of randomly jittered triangles that overfills the view.
    rng = np.random.default_rng(0)
    n = 31
    xs, ys = np.meshgrid(np.linspace(-1.5, 1.5, n), np.linspace(-1.5, 1.5, n))
    jitter = rng.uniform(-0.03, 0.03, size=(n, n, 2))
    jitter[[0, -1]] = 0
    jitter[:, [0, -1]] = 0
    points = np.stack([xs + jitter[..., 0], ys + jitter[..., 1], np.zeros_like(xs)], -1)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).reshape(-1, 3)
    gbuffer = rasterize(clip_of(points.reshape(-1, 3)), torch.from_numpy(faces), 200)
    assert gbuffer.coverage().all()


def test_rasterisation_is_deterministic_and_compact():
    positions, faces = quad(0.5)
    first = rasterize(clip_of(positions), faces, 64)
    second = rasterize(clip_of(positions), faces, 64)
    assert torch.equal(first.pixels, second.pixels) and torch.equal(first.tri_ids, second.tri_ids)
    assert first.nbytes == first.num_samples * 8 + 2 * 9 * 4
    assert torch.equal(first.pixels, first.pixels.sort().values)


def test_triangles_behind_the_camera_are_not_drawn():
    positions, faces = quad(0.5, z=3.0)  # behind the eye at z = 2.4
    assert rasterize(clip_of(positions), faces, 32).num_samples == 0
