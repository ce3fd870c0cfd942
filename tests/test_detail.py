"""The detail each chart's texels lose at the output size (geoscaler.uv.detail)."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_support import mesh_of

from geoscaler.mesh import Material, TexturedMesh
from geoscaler.uv.detail import LostDetail, block_variance, interior_texels, lost_detail

CHECKER, FLAT = 0, 1


def two_quads() -> TexturedMesh:
    """Chart 0 (faces 0, 1) on UV [0, 0.5]^2 over a 2-texel checker; chart 1 (faces 2, 3) on UV
    [0.53, 0.97]^2 over flat grey, the texture black around it: a 32 x 32 texture."""
    boxes = [(0.0, 0.5), (0.53, 0.97)]
    positions, uvs, faces = [], [], []
    for index, (low, high) in enumerate(boxes):
        base = len(uvs)
        for u, v in ((low, low), (high, low), (high, high), (low, high)):
            uvs.append((u, v))
            positions.append((u, v, float(index)))
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    texture = np.zeros((32, 32, 3), np.uint8)
    rows, cols = np.mgrid[16:32, 0:16]
    texture[16:32, 0:16] = (((rows // 2 + cols // 2) % 2) * 255)[..., None]  # u, v < 0.5
    texture[1:15, 17:31] = 128  # u, v in [0.53, 0.97]
    positions, faces = np.array(positions, np.float32), np.array(faces, np.int64)
    material = Material("quads", texture)
    uvs = np.array(uvs, np.float32)
    return mesh_of(positions, faces, uvs, np.zeros(4, np.int64), [material], np.arange(8))


def test_block_variance_is_what_a_box_filter_discards_of_one_octave_finer():
    checker = (np.indices((4, 4)).sum(axis=0) % 2 * 255).astype(np.uint8)
    image = np.repeat(checker[..., None], 3, axis=2)
    # each output texel holds two black and two white texels: 0.25 a channel
    np.testing.assert_allclose(block_variance(image, (2, 2)), np.full((2, 2), 0.75), atol=1e-6)
    np.testing.assert_allclose(block_variance(np.full((4, 4, 3), 90, np.uint8), (2, 2)), 0.0)


@pytest.mark.parametrize("channels", [2, 4])
def test_alpha_is_no_detail(channels):
    image = np.full((4, 4, channels), 200, np.uint8)
    image[..., -1] = (np.indices((4, 4)).sum(axis=0) % 2 * 255).astype(np.uint8)
    np.testing.assert_allclose(block_variance(image, (2, 2)), 0.0, atol=1e-6)


def test_detail_more_than_one_octave_finer_is_not_counted():
    checker = (np.indices((8, 8)).sum(axis=0) % 2 * 255).astype(np.uint8)
    image = np.repeat(checker[..., None], 3, axis=2)
    # one octave finer than 2 x 2 is 4 x 4, where the 1-texel checker is flat grey
    np.testing.assert_allclose(block_variance(image, (2, 2)), 0.0, atol=1e-6)


def test_interior_texels_leave_out_the_border_of_the_charts():
    corners = np.array([[[0, 0], [0.5, 0], [0.5, 0.5]], [[0, 0], [0.5, 0.5], [0, 0.5]]])
    texel, face = interior_texels(corners, 8)
    # the charts cover the 4 x 4 texels at the bottom left (rows 4-7, columns 0-3)
    assert sorted(set(texel.tolist())) == [5 * 8 + 1, 5 * 8 + 2, 6 * 8 + 1, 6 * 8 + 2]
    assert set(face.tolist()) == {0, 1}


def test_a_chart_over_print_loses_detail_and_one_of_flat_colour_none():
    mesh = two_quads()
    lost = lost_detail(mesh, [mesh.materials[0].base_color_texture], [(8, 8)])
    charts = np.array([CHECKER, CHECKER, FLAT, FLAT])
    # the flat chart's border texels average the black beside it: left out, it loses nothing
    np.testing.assert_allclose(lost.per_chart(charts, 2), [0.75, 0.0], atol=1e-6)


def test_a_material_without_a_map_or_a_square_output_is_not_measured():
    mesh = two_quads()
    texture = mesh.materials[0].base_color_texture
    for references, sizes in (([None], [(8, 8)]), ([texture], [None]), ([texture], [(8, 4)])):
        lost = lost_detail(mesh, references, sizes)
        assert lost.texels.sum() == 0 and lost.energy.sum() == 0


def test_charts_without_interior_texels_weigh_as_the_median_chart():
    lost = LostDetail(energy=np.array([2.0, 0.0, 9.0, 0.0]), texels=np.array([1.0, 1, 3, 0]))
    charts = np.array([0, 0, 1, 2])
    # chart 0: 2 / 2 texels; chart 1: 9 / 3; chart 2 none: the median of 1 and 3
    np.testing.assert_allclose(lost.per_chart(charts, 3), [1.0, 3.0, 2.0])


def test_nothing_measured_weighs_every_chart_the_same():
    lost = LostDetail(energy=np.zeros(3), texels=np.zeros(3))
    np.testing.assert_array_equal(lost.per_chart(np.array([0, 1, 1]), 2), [1.0, 1.0])


def test_a_texture_that_loses_nothing_weighs_every_chart_the_same():
    mesh = two_quads()
    texture = mesh.materials[0].base_color_texture
    # at its own size nothing is lost: the charts are then weighed by their samples alone
    lost = lost_detail(mesh, [texture], [(32, 32)])
    assert lost.texels.sum() > 0 and lost.energy.sum() == 0
    np.testing.assert_array_equal(lost.per_chart(np.array([0, 0, 1, 1]), 2), [1.0, 1.0])


@pytest.mark.parametrize("size", [(8, 8), (16, 16)])
def test_texels_counted_lie_inside_the_charts(size):
    mesh = two_quads()
    lost = lost_detail(mesh, [mesh.materials[0].base_color_texture], [size])
    assert lost.texels.sum() > 0
    assert (lost.energy >= 0).all()
