"""GPU-style texture filtering: sRGB, mip chain, bilinear/trilinear taps, level of detail."""

import math

import numpy as np
import pytest
import torch

from geoscaler.color import (
    linear_to_srgb,
    linear_to_texture,
    srgb_to_linear,
    texture_to_linear,
    to_rgb,
)
from geoscaler.render import encoded as encoded_module
from geoscaler.render.encoded import EncodedMipTexture
from geoscaler.render.texture import (
    MipLayout,
    MipTexture,
    TapMatrix,
    UVFootprint,
    _merged_rows_by_sorting,
    _merged_rows_on_cpu,
    build_mip_chain,
    fill_gutters,
    mip_sizes,
    next_mip_level,
)


def grid_texture(height, width, channels=1, dtype=torch.float64):
    values = torch.arange(height * width * channels, dtype=dtype)
    return values.reshape(height, width, channels)


def uv_of_texel(row, col, height, width):
    """Texture coordinates of a texel centre (v grows upwards, row 0 is the top)."""
    return (col + 0.5) / width, 1 - (row + 0.5) / height


def test_srgb_round_trip_keeps_every_8bit_value():
    codes = torch.arange(256, dtype=torch.float64) / 255
    back = linear_to_srgb(srgb_to_linear(codes)) * 255
    assert torch.equal(back.round(), torch.arange(256, dtype=torch.float64))
    assert srgb_to_linear(torch.tensor(0.5)).item() == pytest.approx(0.214041, abs=1e-6)


def test_texture_conversion_round_trips_uint8():
    texture = np.random.default_rng(0).integers(0, 256, (5, 7, 4), dtype=np.uint8)
    linear = texture_to_linear(texture)
    assert linear.shape == (5, 7, 3)
    assert np.array_equal(linear_to_texture(linear), texture[..., :3])
    gray = texture_to_linear(texture[..., 0])
    assert torch.equal(gray[..., 0], gray[..., 2])


def test_decoding_a_texture_by_table_gives_the_formulas_float32_bits():
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(3, axis=2)
    formula = srgb_to_linear(torch.from_numpy(codes).float() / 255.0)
    decoded = texture_to_linear(codes)
    assert decoded.dtype == torch.float32 and torch.equal(decoded, formula)
    with pytest.raises(TypeError, match="8-bit"):
        texture_to_linear(codes.astype(np.float32))


def test_to_rgb_broadcasts_grey_and_drops_alpha():
    texture = np.random.default_rng(0).integers(0, 256, (5, 7, 4), dtype=np.uint8)
    for grey in (texture[..., 0], texture[..., :1], texture[..., :2]):  # (H, W), L, LA
        rgb = to_rgb(grey)
        assert rgb.shape == (5, 7, 3) and rgb.dtype == np.uint8
        assert all(np.array_equal(rgb[..., c], texture[..., 0]) for c in range(3))
    assert np.array_equal(to_rgb(texture), texture[..., :3])
    assert np.array_equal(to_rgb(texture[..., :3]), texture[..., :3])


def test_mip_sizes_halve_down_to_one():
    assert mip_sizes(4, 4) == [(4, 4), (2, 2), (1, 1)]
    assert mip_sizes(5, 3) == [(5, 3), (2, 1), (1, 1)]
    assert mip_sizes(1, 8) == [(1, 8), (1, 4), (1, 2), (1, 1)]


def test_mip_levels_are_two_by_two_box_averages():
    levels = build_mip_chain(grid_texture(4, 4))
    assert [tuple(level.shape[:2]) for level in levels] == [(4, 4), (2, 2), (1, 1)]
    assert levels[1][0, 0, 0].item() == (0 + 1 + 4 + 5) / 4
    assert levels[1][1, 1, 0].item() == (10 + 11 + 14 + 15) / 4
    assert levels[2][0, 0, 0].item() == 7.5
    odd = build_mip_chain(grid_texture(3, 3))
    assert odd[1][0, 0, 0].item() == (0 + 1 + 3 + 4) / 4  # the odd row and column drop out


def test_bilinear_at_texel_centres_returns_texels():
    texture = MipTexture(grid_texture(3, 4))
    rows, cols = torch.meshgrid(torch.arange(3), torch.arange(4), indexing="ij")
    u, v = uv_of_texel(rows.flatten().double(), cols.flatten().double(), 3, 4)
    values = texture.bilinear(u, v, torch.zeros(12, dtype=torch.long))
    torch.testing.assert_close(values[0], torch.arange(12, dtype=torch.float64), atol=1e-12, rtol=0)


def test_bilinear_hand_computed_values_and_repeat_addressing():
    texture = MipTexture(grid_texture(2, 2))  # rows [0, 1] top, [2, 3] bottom
    level0 = torch.zeros(4, dtype=torch.long)
    u = torch.tensor([0.5, 0.25 + 0.125, 1.25, 0.0], dtype=torch.float64)
    v = torch.tensor([0.5, 0.75, 0.75, 0.75], dtype=torch.float64)
    values = texture.bilinear(u, v, level0)[0]
    assert values[0].item() == 1.5  # centre: mean of all four
    assert values[1].item() == pytest.approx(0.25)  # a quarter texel right of texel 0
    assert values[2].item() == 0.0  # u = 1.25 repeats u = 0.25: texel 0
    assert values[3].item() == 0.5  # u = 0 straddles the seam: texels 0 and 1 (wrapped)


def test_taps_repeat_whole_tiles_away_on_every_level():
    """Repeat addressing: UVs whole tiles away, negative ones included, read the same int32
    texels with the same weights, on an odd-sized texture's levels 0 and 1."""
    layout = MipLayout(5, 7)
    generator = torch.Generator().manual_seed(0)
    u, v = torch.rand(2, 50, generator=generator)
    level = torch.tensor([0, 1] * 25)
    index, weight = layout.bilinear_taps(u, v, level)
    assert index.dtype == torch.int32
    assert index.min() >= 0 and index.max() < layout.num_texels
    assert ((index[:, level == 1] >= 35) & (index[:, level == 1] < 35 + 6)).all()  # 2 x 3
    for shift in (-3.0, 1.0, 7.0):
        moved_index, moved_weight = layout.bilinear_taps(u + shift, v - shift, level)
        assert torch.equal(moved_index, index)
        torch.testing.assert_close(moved_weight, weight, atol=1e-5, rtol=0)


def test_trilinear_blends_neighbouring_levels():
    texture = MipTexture(grid_texture(4, 4))
    u = torch.tensor([0.5, 0.5, 0.5], dtype=torch.float64)
    v = torch.tensor([0.5, 0.5, 0.5], dtype=torch.float64)
    lod = torch.tensor([0.0, 0.5, 7.0], dtype=torch.float64)
    values = texture.trilinear(u, v, lod)[0]
    level0 = (5 + 6 + 9 + 10) / 4
    level1 = 7.5  # the mean of the four 2 x 2 blocks around the centre
    assert values[0].item() == level0
    assert values[1].item() == pytest.approx((level0 + level1) / 2)
    assert values[2].item() == 7.5  # clamped to the 1 x 1 level


def test_trilinear_is_the_sum_of_its_taps_magnified_or_not():
    torch.manual_seed(1)
    texture = MipTexture(torch.rand(8, 16, 3, dtype=torch.float64))
    u, v = torch.rand(7, dtype=torch.float64), torch.rand(7, dtype=torch.float64)
    lod = torch.tensor([-2.0, -1e-9, 0.0, 0.25, 1.5, 3.0, 9.0], dtype=torch.float64)
    count, index, weight = texture.layout.trilinear_taps(u, v, lod)
    sample = torch.repeat_interleave(torch.arange(7), count.long())  # each tap's sample
    expected = torch.zeros(3, 7, dtype=torch.float64).index_add(
        1, sample, texture.texels[:, index] * weight
    )
    torch.testing.assert_close(texture.trilinear(u, v, lod), expected, atol=1e-12, rtol=0)
    level0 = texture.bilinear(u[:2], v[:2], torch.zeros(2, dtype=torch.int32))
    assert torch.equal(texture.trilinear(u, v, lod)[:, :2], level0)  # magnified: level 0 alone


def test_trilinear_taps_are_bilinear_on_two_levels_and_skip_the_unweighted_one():
    torch.manual_seed(2)
    layout = MipLayout(8, 16)
    u, v = torch.rand(5, dtype=torch.float64), torch.rand(5, dtype=torch.float64)
    # isotropic footprints whose levels of detail are -2, -1, 0.25, 1.5 and 9 (clamped: 4)
    scale = torch.tensor([0.25, 0.5, 2**0.25, 2**1.5, 2.0**9], dtype=torch.float64)
    zero = torch.zeros(5, dtype=torch.float64)
    count, index, weight = layout.taps(UVFootprint(u, v, scale / 16, zero, zero, scale / 8))
    assert count.tolist() == [4, 4, 8, 8, 4]  # the coarser level only where it has weight
    lod = layout.level_of_detail(scale / 16, zero, zero, scale / 8)
    fine, coarse, blend = layout.levels(lod)
    fine_index, fine_weight = layout.bilinear_taps(u, v, fine)
    coarse_index, coarse_weight = layout.bilinear_taps(u, v, coarse)
    expected_index = torch.cat([fine_index, coarse_index]).T  # (5, 8)
    expected_weight = torch.cat([fine_weight * (1 - blend), coarse_weight * blend]).T
    tapped = torch.arange(8) < count[:, None]  # sample by sample, fine level first
    assert torch.equal(index, expected_index[tapped])
    torch.testing.assert_close(weight, expected_weight[tapped], atol=1e-15, rtol=0)
    assert bool(expected_weight[~tapped].eq(0).all())  # what is skipped weighs nothing


def test_taps_of_rows_are_the_trilinear_taps_level_by_level():
    torch.manual_seed(3)
    layout = MipLayout(8, 16)
    u, v = torch.rand(5, dtype=torch.float64), torch.rand(5, dtype=torch.float64)
    scale = torch.tensor([0.25, 0.5, 2**0.25, 2**1.5, 2.0**9], dtype=torch.float64)  # lod -2..9
    zero = torch.zeros(5, dtype=torch.float64)
    footprint = UVFootprint(u, v, scale / 16, zero, zero, scale / 8)
    row = torch.tensor([0, 2, 1, 2, 0], dtype=torch.int32)  # samples 1 and 3 share row 2
    row_of_tap, texel, weight = layout.taps_of_rows(footprint, row)
    count, by_sample, sample_weight = layout.taps(footprint)
    four = torch.arange(4)
    first = torch.cumsum(count, 0) - count  # each sample's first tap, sample by sample
    # the finer level's four taps of every sample, then the coarser level's of samples 2, 3
    fine_taps = (first[:, None] + four).T.reshape(-1)
    coarse_taps = (first[[2, 3]] + 4 + four[:, None]).reshape(-1)
    order = torch.cat([fine_taps, coarse_taps])
    assert row_of_tap.tolist() == [*row.tolist() * 4, *row[[2, 3]].tolist() * 4]
    assert torch.equal(texel, by_sample[order])
    assert torch.equal(weight, sample_weight[order])


@pytest.mark.parametrize(
    ("jacobian", "expected"),
    [
        (((1, 0), (0, 1)), 0.0),
        (((2, 0), (0, 2)), 1.0),
        (((4, 0), (0, 1)), 2.0),  # anisotropic: the larger singular value decides
        (((0.25, 0), (0, 0.25)), -2.0),
        (
            ((3 * math.cos(0.3), -3 * math.sin(0.3)), (3 * math.sin(0.3), 3 * math.cos(0.3))),
            math.log2(3),
        ),
    ],
)
def test_level_of_detail_is_log2_of_the_largest_singular_value(jacobian, expected):
    texture = MipTexture(grid_texture(64, 32))
    (du_dx, du_dy), (dv_dx, dv_dy) = jacobian  # in texels per sample

    def column(value, size):
        return torch.tensor([value / size], dtype=torch.float64)

    lod = texture.level_of_detail(
        column(du_dx, 32), column(dv_dx, 64), column(du_dy, 32), column(dv_dy, 64)
    )
    assert lod.item() == pytest.approx(expected, abs=1e-9)


def test_sampling_is_differentiable_in_texels_and_uvs():
    torch.manual_seed(0)
    texels = torch.rand(4, 6, 3, dtype=torch.float64, requires_grad=True)
    # Positions and footprints away from texel-centre and level boundaries, where the
    # filter is smooth; the first three samples blend two levels, the last is magnified.
    u = torch.tensor([0.13, 0.41, 0.77, 0.62], dtype=torch.float64, requires_grad=True)
    v = torch.tensor([0.21, 0.58, 0.93, 0.36], dtype=torch.float64, requires_grad=True)
    du_dx = torch.tensor([0.21, 0.3, 0.45, 0.05], dtype=torch.float64, requires_grad=True)
    dv_dy = torch.tensor([0.3, 0.2, 0.05, 0.04], dtype=torch.float64, requires_grad=True)
    zero = torch.zeros(4, dtype=torch.float64)

    def sample(texels, u, v, du_dx, dv_dy):
        return MipTexture(texels).sample(UVFootprint(u, v, du_dx, zero, zero, dv_dy))

    assert torch.autograd.gradcheck(sample, (texels, u, v, du_dx, dv_dy))


def random_footprints(count, seed):
    """Samples all over a texture, magnified to minified beyond the coarsest level."""
    generator = torch.Generator().manual_seed(seed)
    u, v = torch.rand(2, count, generator=generator) * 3 - 1  # repeat addressing too
    scale = 2.0 ** (torch.rand(count, generator=generator) * 16 - 12)
    zero = torch.zeros(count)
    return UVFootprint(u, v, scale, zero, zero, scale * 0.7)


@pytest.mark.parametrize("shape", [(37, 64, 3), (64, 37, 4), (33, 20), (9, 6, 2), (1, 5, 3)])
def test_an_encoded_chain_samples_the_bits_of_the_float_chain_of_its_texture(shape):
    codes = np.random.default_rng(3).integers(0, 256, shape, dtype=np.uint8)
    encoded = EncodedMipTexture(codes)
    float_chain = MipTexture(texture_to_linear(codes))
    footprint = random_footprints(5000, seed=4)
    assert torch.equal(encoded.sample(footprint), float_chain.sample(footprint))
    fine_texels = shape[0] * shape[1]  # levels 1 and coarser are held, equal to the bit
    assert torch.equal(encoded.coarse, float_chain.texels[:, fine_texels:])


def test_an_encoded_chain_decodes_level_one_a_band_at_a_time(monkeypatch):
    codes = np.random.default_rng(5).integers(0, 256, (70, 24, 3), dtype=np.uint8)
    whole = EncodedMipTexture(codes).coarse
    monkeypatch.setattr(encoded_module, "ENCODED_BAND_TEXELS", 2 * 24 * 4)  # 4 rows of level 1
    assert torch.equal(EncodedMipTexture(codes).coarse, whole)


def test_an_encoded_chain_holds_its_textures_bytes_and_float_levels_past_the_first_only():
    codes = np.random.default_rng(6).integers(0, 256, (64, 32, 4), dtype=np.uint8)
    codes.flags.writeable = False  # as loaded textures are
    encoded = EncodedMipTexture(codes)
    assert encoded.codes.data_ptr() == codes.ctypes.data  # the array itself, not a copy
    assert encoded.coarse.shape == (3, (32 * 16 + 16 * 8 + 8 * 4 + 4 * 2 + 2 * 1 + 1))
    with pytest.raises(AttributeError, match="no float level 0"):
        encoded.texels  # noqa: B018


def test_an_encoded_chain_decodes_each_channel_by_its_own_table():
    codes = np.random.default_rng(7).integers(0, 256, (16, 8, 2), dtype=np.uint8)
    ramp = np.arange(256, dtype=np.float32) / 255
    decoding = [(1, ramp), (0, ramp * 2 - 1)]  # alpha first, then grey as a signed value
    encoded = EncodedMipTexture(codes, decoding=decoding)
    values = torch.from_numpy(np.stack([ramp[codes[..., 1]], ramp[codes[..., 0]] * 2 - 1], 2))
    footprint = random_footprints(2000, seed=8)
    assert torch.equal(encoded.sample(footprint), MipTexture(values).sample(footprint))


def test_the_next_mip_level_of_a_band_of_rows_is_that_band_of_the_next_level():
    level = torch.rand(20, 14, 3, generator=torch.Generator().manual_seed(9))
    below = next_mip_level(level)
    assert below.shape == (10, 7, 3)
    assert torch.equal(next_mip_level(level[6:12]), below[3:6])
    assert next_mip_level(level[:1]).shape == (1, 7, 3)  # a side of 1 is kept


def test_a_tap_matrix_sums_each_rows_weighted_texels_given_in_any_order():
    # Rows 0..3 of a 4-texel, 2-channel table; taps out of order, (0, 1) given twice, row 3
    # with no tap at all.
    row = torch.tensor([2, 0, 1, 0, 2, 0], dtype=torch.int32)
    texel = torch.tensor([3, 1, 0, 2, 3, 1], dtype=torch.int32)
    weight = torch.tensor([0.5, 0.25, 1.0, 0.5, 0.25, 0.25])
    table = torch.tensor([[1.0, 10.0], [2.0, 20.0], [4.0, 40.0], [8.0, 80.0]])
    taps = TapMatrix(row, texel, weight, (4, 4))
    expected = torch.tensor([[3.0, 30.0], [1.0, 10.0], [6.0, 60.0], [0.0, 0.0]])
    assert torch.equal(taps(table), expected)
    assert taps.texel.tolist() == [1, 2, 1, 0, 3, 3]  # by row, in the order given
    assert taps.nbytes == 5 * 4 + 6 * 4 + 6 * 4  # CSR, int32 indices (no transpose yet)


def test_merged_taps_sum_each_rows_taps_of_one_texel():
    # Row 0 reads texel 3 twice and texel 1 once, row 1 nothing, row 2 texel 2 twice; the taps
    # come in any row order.
    row = torch.tensor([0, 2, 0, 2, 0], dtype=torch.int32)
    texel = torch.tensor([3, 2, 1, 2, 3], dtype=torch.int32)
    weight = torch.tensor([0.5, 1.0, 0.25, 0.5, 0.25])
    merged = TapMatrix.merged(row, texel, weight, (3, 4))
    assert merged.texel.tolist() == [1, 3, 2]  # ascending within each row
    assert merged.weight.tolist() == [0.25, 0.75, 1.5]
    assert merged.matrix.crow_indices().tolist() == [0, 2, 2, 3]
    table = torch.tensor([[1.0, 10.0], [2.0, 20.0], [4.0, 40.0], [8.0, 80.0]])
    assert torch.equal(merged(table), TapMatrix(row, texel, weight, (3, 4))(table))


def test_merging_row_by_row_on_the_cpu_gives_what_sorting_every_tap_gives():
    generator = torch.Generator().manual_seed(0)
    row = torch.randint(0, 500, (20_000,), dtype=torch.int32, generator=generator)
    texel = torch.randint(0, 64, (20_000,), dtype=torch.int32, generator=generator)
    weight = torch.rand(20_000, generator=generator)
    kept = (row.clone(), texel.clone(), weight.clone())
    by_row = _merged_rows_on_cpu(row, texel, weight, (500, 64))
    by_sorting = _merged_rows_by_sorting(row, texel, weight, (500, 64))
    assert torch.equal(by_row[0], by_sorting[0])
    assert torch.equal(by_row[1], by_sorting[1])
    torch.testing.assert_close(by_row[2], by_sorting[2], rtol=1e-6, atol=1e-6)
    assert all(torch.equal(a, b) for a, b in zip((row, texel, weight), kept, strict=True))


def test_a_tap_matrix_is_differentiable_in_its_table():
    generator = torch.Generator().manual_seed(0)
    row = torch.randint(0, 5, (40,), generator=generator, dtype=torch.int32)
    texel = torch.randint(0, 7, (40,), generator=generator, dtype=torch.int32)
    weight = torch.rand(40, generator=generator, dtype=torch.float64)
    taps = TapMatrix(row, texel, weight, (5, 7))
    table = torch.rand(7, 3, generator=generator, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(taps, (table,))
    # the matrix and, since the backward pass, its transpose over the texels read
    read = len(set(texel.tolist()))
    assert taps.nbytes == (6 * 4 + 40 * (4 + 8)) + (read * 4 + (read + 1) * 4 + 40 * (4 + 8))


def test_a_tap_matrix_gradient_reaches_the_texels_read_and_its_memory_not_the_table_size():
    # 3 rows reading 3 texels of a million-texel table: the gradient is every tap's weight
    # times its row's gradient, at its texel, zero elsewhere; the transpose holds offsets for
    # the 2 texels read, not for the million.
    row = torch.tensor([0, 1, 1, 2], dtype=torch.int32)
    texel = torch.tensor([999_999, 5, 999_999, 5], dtype=torch.int32)
    weight = torch.tensor([0.5, 0.25, 0.75, 1.0])
    taps = TapMatrix(row, texel, weight, (3, 1_000_000))
    table = torch.zeros(1_000_000, 2, requires_grad=True)
    taps(table).backward(torch.tensor([[1.0, 2.0], [4.0, 8.0], [16.0, 32.0]]))
    expected = torch.zeros(1_000_000, 2)
    expected[5] = torch.tensor([0.25 * 4 + 1.0 * 16, 0.25 * 8 + 1.0 * 32])
    expected[999_999] = torch.tensor([0.5 * 1 + 0.75 * 4, 0.5 * 2 + 0.75 * 8])
    assert torch.equal(table.grad, expected)
    assert taps.nbytes == (4 * 4 + 4 * 8) + (2 * 4 + 3 * 4 + 4 * 8)


def test_srgb_conversions_are_differentiable():
    x = torch.tensor([0.001, 0.02, 0.3, 0.8], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(srgb_to_linear, (x,))
    assert torch.autograd.gradcheck(linear_to_srgb, (x,))


def test_gutter_fill_keeps_the_kept_texels_and_fills_the_rest():
    texture = torch.rand(6, 5, 3)
    keep = torch.zeros(6, 5, dtype=torch.bool)
    keep[1:3, 1:4] = True
    filled = fill_gutters(texture, keep)
    assert torch.equal(filled[keep], texture[keep])
    assert torch.isfinite(filled).all()
    keep_colours = texture[keep]
    low, high = keep_colours.min(0).values, keep_colours.max(0).values
    assert ((filled >= low - 1e-6) & (filled <= high + 1e-6)).all()  # averages of keep texels


def test_a_single_kept_texel_colours_everything():
    texture = torch.zeros(4, 4, 3)
    texture[2, 1] = torch.tensor([0.2, 0.5, 0.9])
    keep = torch.zeros(4, 4, dtype=torch.bool)
    keep[2, 1] = True
    filled = fill_gutters(texture, keep)
    torch.testing.assert_close(filled, texture[2, 1].expand(4, 4, 3))
