"""Gutters come from the UV layout: a texel is filled only where no face's footprint reaches it
at the mip levels the renderer can use, whatever views were cached."""

import math

import numpy as np
import pytest
import torch

from geoscaler.color import texture_to_linear
from geoscaler.mesh import Material, TexturedMesh, compute_vertex_normals, weld_points
from geoscaler.methods.direct import TexelModel
from geoscaler.optim.loop import LoopSetup, OptimizeConfig, optimize
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import Camera, sample_extent
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import build_mip_chain, fill_gutters
from geoscaler.render.views import ViewCache, ViewSet
from geoscaler.resize.filters import lanczos, output_sizes
from geoscaler.uv.uvmaps import face_max_levels, reachable_masks, reachable_texels


def quad(u_max: float = 1.0, texture_size: int = 64) -> TexturedMesh:
    """A square facing +z, corners (+-1, +-1, 0), mapped onto ``[0, u_max] x [0, 1]`` of the
    texture. In the unit scene its side is sqrt(2) (its corners are at distance 1)."""
    positions = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    uvs = np.array([[0, 0], [u_max, 0], [u_max, 1], [0, 1]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    points = weld_points(positions)
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, (texture_size, texture_size, 3), dtype=np.uint8)
    return TexturedMesh(
        positions, faces, uvs, compute_vertex_normals(positions, faces, points), points,
        np.zeros(2, np.int64), [Material("quad", texture)],
    )  # fmt: skip


def texels_read(cache: ViewCache, material: int = 0) -> torch.Tensor:
    """``(h, w)`` bool: level-0 texels some cached view's taps read, through any level."""
    layout = cache.layouts[material]
    usage = torch.zeros(layout.num_texels)
    for view in range(len(cache)):
        cache.find_taps(view)
        taps = cache.taps[view][material]
        usage.index_add_(0, taps.texel.long(), taps.weight.abs())
    ones = torch.ones(*layout.size, 1, requires_grad=True)
    chain = torch.cat([level.reshape(-1) for level in build_mip_chain(ones)])
    (grad,) = torch.autograd.grad((chain * usage).sum(), ones)
    return grad[..., 0] > 0


def test_a_faces_coarsest_level_follows_its_texel_density_and_the_sample_size():
    mesh = quad()
    faces = np.asarray(mesh.faces)
    # 64 texels over a side of sqrt(2): 45.25 texels a unit; 8 for the grazing stretch.
    # A sample 1/64 wide: log2(64 / sqrt 2 / 64 * 8) = 2.5, so trilinear reads levels 2 and 3.
    np.testing.assert_array_equal(face_max_levels(mesh, faces, (64, 64), 1 / 64), [3, 3])
    np.testing.assert_array_equal(face_max_levels(mesh, faces, (64, 64), 1 / 128), [2, 2])
    np.testing.assert_array_equal(face_max_levels(mesh, faces, (64, 64), 10.0), [6, 6])  # 1x1
    flat = np.array([[0, 1, 1]])  # no area: no view shows it
    np.testing.assert_array_equal(face_max_levels(mesh, flat, (64, 64), 1 / 64), [-1])


def test_a_chart_on_the_left_half_leaves_the_right_half_a_gutter():
    # Levels 0 and 1 (a sample 1/256 wide: bound 0.5): the chart's cells up to u = 0.5 (column
    # 32 touches it), their bilinear neighbours, and at level 1 the same in 2 x 2 blocks.
    reachable = reachable_texels(quad(u_max=0.5), 0, (64, 64), 1 / 256)
    columns = reachable.all(dim=0)
    assert torch.equal(reachable.any(dim=0), columns)  # every row alike
    expected = set(range(36)) | {62, 63}  # wrapping round: column -1 is 63
    assert {int(c) for c in torch.nonzero(columns)} == expected


def test_every_texel_a_view_reads_is_reachable():
    mesh = quad(u_max=0.5)
    evaluation = Evaluation(image_size=128)
    renderer = Renderer(mesh, "cpu", evaluation)
    cameras = [Camera((0.0, 0.0, 1.0), 2.4), Camera((0.3, -0.2, 1.0), 4.0)]
    cache = ViewCache(ViewSet(renderer, cameras), [(64, 64)], with_taps=True)
    read = texels_read(cache)
    extent = sample_extent(4.0 + 1.0, renderer.resolution)
    reachable = reachable_texels(mesh, 0, (64, 64), extent)
    assert read.any() and not reachable.all()
    assert not (read & ~reachable).any()


def test_a_layout_too_large_to_rasterise_counts_as_reaching_everything():
    mesh = quad(u_max=30000.0, texture_size=4)  # two faces over 30,000 repeats of the texture
    mesh.uvs[:, 1] *= 30000.0
    assert reachable_texels(mesh, 0, (8192, 8192), 1 / 64).all()  # 2 x 8192^2 cells to test


@pytest.mark.parametrize("pool", [1, 3])
def test_the_shipped_gutters_depend_only_on_the_layout(pool):
    mesh = quad(u_max=0.5, texture_size=512)  # 128 x 128 out, at the protocol's image size
    renderer = Renderer(mesh, "cpu", Evaluation(views=(0, 30)))
    sizes = output_sizes(mesh, 4)
    start = lanczos(mesh.materials[0].base_color_texture, 4)
    model = TexelModel([texture_to_linear(start)])
    cameras = [Camera((math.sin(a), 0.2, math.cos(a)), 2.0) for a in (0.0, 0.5, -0.5)][:pool]
    config = OptimizeConfig(steps=3, views_per_step=pool, validate_every=1, lr=0.05)
    validation = Validation(validation_view_sets(renderer, 2), sizes)
    result = optimize(renderer, model, config, validation, LoopSetup(training_cameras=cameras))
    (mask,) = reachable_masks(mesh, sizes, 4.0, renderer.resolution)  # farthest: far guards
    texture = result.textures[0]
    assert 0.5 < mask.float().mean() < 0.75  # the chart's half, and what its footprint reaches
    # the gutter is the fill of the reachable texels, so it is fixed by them and the layout
    assert torch.equal(texture, fill_gutters(texture, mask))
    assert not torch.equal(texture[~mask], texture_to_linear(start)[~mask])  # it was filled
