"""Specification of geoscaler.resize.maps: every texture class resized as what it holds.

Tolerances are those of 8-bit storage. A normal-map code ``q`` decodes to ``2 q / 255 - 1``,
so rounding an exact vector to the nearest code moves each component by at most 1/255.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.resize import maps
from geoscaler.resize.maps import (
    COLOR,
    DATA,
    METHOD_NAMES,
    NORMAL,
    TEXTURE_CLASSES,
    alpha_coverage,
    normal_shortening,
    resize_map,
    texture_class,
    toksvig_roughness,
)

HALF_STEP = 1 / 255
"""Largest change of a decoded normal component from rounding to the nearest 8-bit code."""


def encode_normals(vectors: np.ndarray) -> np.ndarray:
    """``(..., 3)`` unit vectors -> uint8 codes ``round((n + 1) 255 / 2)``."""
    return np.floor((vectors + 1) * 127.5 + 0.5).astype(np.uint8)


def decode_normals(codes: np.ndarray) -> np.ndarray:
    """uint8 codes -> ``(..., 3)`` float64 vectors ``2 q / 255 - 1`` (not normalised)."""
    return codes[..., :3] * (2 / 255) - 1


def unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def block_mean(values: np.ndarray, block: tuple[int, int]) -> np.ndarray:
    """``(H, W, C)`` -> ``(H / by, W / bx, C)``: the mean of each ``by x bx`` block."""
    height, width, channels = values.shape
    by, bx = block
    return values.reshape(height // by, by, width // bx, bx, channels).mean(axis=(1, 3))


def height_field_normals(height: int, width: int) -> np.ndarray:
    """``(height, width, 3)`` uint8 normal map of ``z = 0.3 sin(x / 3) cos(y / 5)`` (texel
    units): ``n = normalise(-dz/dx, -dz/dy, 1)``, a smooth field with bumps of all slopes."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    dzdx = 0.1 * np.cos(x / 3) * np.cos(y / 5)
    dzdy = -0.06 * np.sin(x / 3) * np.sin(y / 5)
    return encode_normals(unit(np.stack([-dzdx * 8, -dzdy * 8, np.ones_like(x)], axis=-1)))


def tilted_quad_normals(height: int, width: int, angle: float) -> np.ndarray:
    """A 2 x 2-periodic normal map: each 2 x 2 cell holds the normal tilted by ``angle`` to +x,
    -x, +y and -y. Its 2 x 2 mean points straight up with length ``cos(angle)``."""
    s, c = np.sin(angle), np.cos(angle)
    cell = np.array([[[s, 0, c], [-s, 0, c]], [[0, s, c], [0, -s, c]]])
    return encode_normals(np.tile(cell, (height // 2, width // 2, 1)))


# ----------------------------------------------------------------------------- slots


@pytest.mark.parametrize(
    ("slot", "kind"),
    [
        ("baseColorTexture", COLOR),
        ("emissiveTexture", COLOR),
        ("normalTexture", NORMAL),
        ("metallicRoughnessTexture", DATA),
        ("occlusionTexture", DATA),
        ("KHR_materials_clearcoat/clearcoatNormalTexture", NORMAL),
        ("KHR_materials_clearcoat/clearcoatTexture", DATA),
        ("KHR_materials_clearcoat/clearcoatRoughnessTexture", DATA),
        ("KHR_materials_sheen/sheenColorTexture", COLOR),
        ("KHR_materials_sheen/sheenRoughnessTexture", DATA),
        ("KHR_materials_specular/specularColorTexture", COLOR),
        ("KHR_materials_specular/specularTexture", DATA),
        ("KHR_materials_transmission/transmissionTexture", DATA),
        ("KHR_materials_volume/thicknessTexture", DATA),
        ("KHR_materials_diffuse_transmission/diffuseTransmissionColorTexture", COLOR),
        ("KHR_materials_anisotropy/anisotropyTexture", DATA),
        ("KHR_materials_pbrSpecularGlossiness/diffuseTexture", COLOR),
        ("KHR_materials_pbrSpecularGlossiness/specularGlossinessTexture", COLOR),
    ],
)
def test_each_slot_has_the_class_of_what_it_holds(slot, kind):
    assert texture_class(slot) == kind


def test_every_class_names_its_method_for_reports():
    assert TEXTURE_CLASSES == ("color", "normal", "data")
    assert METHOD_NAMES == {
        "color": "Lanczos in linear light",
        "normal": "vector average, renormalised",
        "data": "Lanczos per channel",
    }


# ----------------------------------------------------------------------------- normals


@pytest.mark.parametrize("size", [(10, 8), (5, 5), (7, 3), (1, 1)])
def test_a_constant_normal_map_keeps_its_direction_at_unit_length(size):
    direction = unit(np.array([0.3, -0.2, 0.93]))
    pixels = np.broadcast_to(encode_normals(direction), (40, 30, 3)).copy()
    result = resize_map(pixels, size, NORMAL)
    assert result.shape == (*size, 3)
    assert np.ptp(result.reshape(-1, 3), axis=0).max() == 0  # still constant
    # The only change: the 8-bit input renormalised, then rounded again: one code at most.
    assert np.abs(result.astype(int) - pixels[0, 0]).max() <= 1
    decoded = decode_normals(result[0, 0])
    # Rounding moves each component by at most HALF_STEP, the length by sqrt(3) HALF_STEP.
    assert abs(np.linalg.norm(decoded) - 1) <= np.sqrt(3) * HALF_STEP
    assert np.abs(decoded - direction).max() <= 2 * HALF_STEP  # input and output rounding


@pytest.mark.parametrize(("size", "block"), [((8, 12), (4, 4)), ((4, 24), (8, 2))])
def test_a_bumpy_normal_map_filters_to_the_renormalised_mean_of_its_unit_vectors(size, block):
    pixels = height_field_normals(32, 48)
    expected = unit(block_mean(unit(decode_normals(pixels)), block))
    result = resize_map(pixels, size, NORMAL)
    assert result.shape == (*size, 3)
    assert np.abs(decode_normals(result) - expected).max() <= HALF_STEP + 1e-6
    assert 0.1 < 1 - expected[..., 2].min()  # the field is bumpy: footprints do tilt


def test_normals_that_cancel_average_to_straight_up_and_a_fourth_channel_is_data():
    pixels = tilted_quad_normals(16, 16, np.radians(40))
    extra = np.random.default_rng(3).integers(0, 256, (16, 16, 1), dtype=np.uint8)
    result = resize_map(np.concatenate([pixels, extra], axis=-1), (8, 8), NORMAL)
    assert (result[..., :3] == (128, 128, 255)).all()  # (0, 0, 1) encoded
    lanczos = np.asarray(Image.fromarray(extra[..., 0]).resize((8, 8), Image.Resampling.LANCZOS))
    assert (result[..., 3] == lanczos).all()


def test_normal_shortening_is_the_length_of_the_mean_unit_vector():
    constant = np.broadcast_to(encode_normals(unit(np.array([0.3, -0.2, 0.93]))), (12, 20, 3))
    assert np.abs(normal_shortening(constant, (3, 5)) - 1).max() <= 1e-6

    bumpy = tilted_quad_normals(12, 20, np.radians(40))
    shortening = normal_shortening(bumpy, (6, 10))
    expected = np.linalg.norm(block_mean(unit(decode_normals(bumpy)), (2, 2)), axis=-1)
    assert shortening.shape == (6, 10) and shortening.dtype == np.float32
    assert np.abs(shortening - expected).max() <= 1e-6
    assert np.abs(shortening - np.cos(np.radians(40))).max() <= 0.005  # 8-bit input

    field = height_field_normals(32, 48)
    expected = np.linalg.norm(block_mean(unit(decode_normals(field)), (4, 4)), axis=-1)
    assert np.abs(normal_shortening(field, (8, 12)) - expected).max() <= 1e-6
    assert (normal_shortening(field, (32, 48)) == 1).all()


# ----------------------------------------------------------------------------- data


def test_data_channels_never_mix():
    rng = np.random.default_rng(1)
    pixels = np.empty((1000, 750, 3), np.uint8)
    pixels[..., 0] = rng.integers(0, 256, (1000, 750))  # occlusion: a pattern
    pixels[..., 1] = 17  # roughness: constant
    pixels[..., 2] = 250  # metallic: constant
    result = resize_map(pixels, (125, 94), DATA)
    assert (result[..., 1] == 17).all() and (result[..., 2] == 250).all()
    alone = Image.fromarray(pixels[..., 0]).resize((94, 125), Image.Resampling.LANCZOS)
    assert (result[..., 0] == np.asarray(alone)).all()  # R as if it were the only channel


# ----------------------------------------------------------------------------- colour


def checkerboard(size: int) -> np.ndarray:
    """``(size, size)`` uint8 of alternating 0 and 255, one texel per square."""
    y, x = np.mgrid[0:size, 0:size]
    return np.where((x + y) % 2 == 0, 255, 0).astype(np.uint8)


def test_colour_is_filtered_in_linear_light():
    board = checkerboard(64)
    result = resize_map(np.stack([board] * 3, axis=-1), (32, 32), COLOR)
    # Linear mean 0.5 encodes to sRGB 187.5...; Lanczos' support is clipped at the border.
    assert (result[6:-6, 6:-6] == 188).all()
    assert 185 <= result.min() and result.max() <= 190  # the border, within 3 codes
    stored = np.asarray(Image.fromarray(board).resize((32, 32), Image.Resampling.LANCZOS))
    assert set(np.unique(stored[6:-6, 6:-6])) <= {127, 128}  # the stored values: too dark


def test_alpha_is_linear_coverage_filtered_apart_from_colour():
    board = checkerboard(64)
    grey_alpha = np.stack([board, board], axis=-1)
    result = resize_map(grey_alpha, (16, 16), COLOR)
    assert (result[4:-4, 4:-4, 0] == 188).all()  # grey is sRGB
    assert (result[4:-4, 4:-4, 1] == 128).all()  # alpha is not: round(255 / 2)

    hidden = np.zeros((64, 64, 4), np.uint8)
    hidden[..., :3] = (200, 30, 90)  # colour under fully transparent texels
    assert (resize_map(hidden, (16, 8), COLOR) == (200, 30, 90, 0)).all()  # not premultiplied


def sparse_mask(size: int) -> np.ndarray:
    """``(size, size)`` uint8 alpha: 30 % of the texels opaque at random, like foliage."""
    return np.where(np.random.default_rng(7).random((size, size)) < 0.3, 255, 0).astype(np.uint8)


def soft_mask(size: int) -> np.ndarray:
    """``(size, size)`` uint8 alpha: thin soft-edged blades of grass, alpha up to 1."""
    y, x = np.mgrid[0:size, 0:size]
    blades = np.abs(np.sin(x * 0.9 + 0.2 * np.sin(y * 0.3)))
    return np.floor(255 * np.clip((blades - 0.7) / 0.25, 0, 1) + 0.5).astype(np.uint8)


@pytest.mark.parametrize("mask", [sparse_mask, soft_mask])
@pytest.mark.parametrize("cutoff", [0.5, 0.3])
@pytest.mark.parametrize("scale", [4, 8])
def test_a_mask_keeps_its_coverage(mask, cutoff, scale):
    pixels = np.full((128, 128, 4), 180, np.uint8)
    pixels[..., 3] = mask(128)
    size = (128 // scale, 128 // scale)
    before = alpha_coverage(pixels[..., 3], cutoff)
    kept = resize_map(pixels, size, COLOR, alpha_cutoff=cutoff)
    plain = resize_map(pixels, size, COLOR)
    # Within half an output texel: the nearest count of texels to the input's share.
    assert abs(alpha_coverage(kept[..., 3], cutoff) - before) <= 0.5 / kept[..., 3].size
    assert abs(alpha_coverage(plain[..., 3], cutoff) - before) > 0.1  # plain filtering loses it
    assert (kept[..., :3] == plain[..., :3]).all()  # only alpha changes


def test_a_cutoff_nothing_or_everything_passes_leaves_alpha_alone():
    pixels = np.full((32, 32, 2), 90, np.uint8)
    pixels[..., 1] = sparse_mask(32)
    plain = resize_map(pixels, (8, 8), COLOR)
    for cutoff in (0.0, 1.5):
        assert (resize_map(pixels, (8, 8), COLOR, alpha_cutoff=cutoff) == plain).all()
    assert alpha_coverage(np.array([127, 128, 255], np.uint8), 0.5) == 2 / 3  # 128 / 255 >= 0.5


# ----------------------------------------------------------------------------- sizes


@pytest.mark.parametrize("kind", TEXTURE_CLASSES)
@pytest.mark.parametrize(("shape", "size"), [((1000, 750), (125, 94)), ((4096, 512), (1024, 128))])
def test_non_integer_and_anisotropic_ratios_work_for_every_class(kind, shape, size):
    # A constant map stays that constant, whatever the ratio (a normal: a unit vector's code).
    value = (
        (*encode_normals(unit(np.array([0.3, -0.2, 0.93]))), 77)
        if kind == NORMAL
        else (140, 90, 230, 77)
    )
    pixels = np.broadcast_to(np.array(value, np.uint8), (*shape, 4)).copy()
    result = resize_map(pixels, size, kind)
    assert result.shape == (*size, 4) and result.dtype == np.uint8
    assert np.abs(result.astype(int) - value).max() <= (1 if kind == NORMAL else 0)


@pytest.mark.parametrize("kind", TEXTURE_CLASSES)
def test_the_same_size_gives_an_unchanged_copy(kind):
    pixels = np.random.default_rng(2).integers(0, 256, (9, 7, 3), dtype=np.uint8)
    result = resize_map(pixels, (9, 7), kind)
    assert result is not pixels and (result == pixels).all()


@pytest.mark.parametrize("size", [(65, 32), (64, 33), (0, 16), (16, -1), (16,), (16.5, 8)])
def test_upscaling_and_sizes_below_one_texel_are_refused(size):
    with pytest.raises(GeoscalerError, match=r"64 x 32 color map to .*up to 64 x 32"):
        resize_map(np.zeros((64, 32, 3), np.uint8), size, COLOR)


def test_bad_maps_classes_and_cutoffs_are_refused():
    rgb = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(GeoscalerError, match="normal map: .*C = 3 or 4"):
        resize_map(np.zeros((8, 8, 1), np.uint8), (4, 4), NORMAL)
    with pytest.raises(GeoscalerError, match="color map: .*uint8"):
        resize_map(rgb.astype(np.float32), (4, 4), COLOR)
    with pytest.raises(GeoscalerError, match="unknown texture class 'albedo'"):
        resize_map(rgb, (4, 4), "albedo")
    with pytest.raises(GeoscalerError, match="alphaCutoff -0.5"):
        resize_map(rgb, (4, 4), COLOR, alpha_cutoff=-0.5)


# ----------------------------------------------------------------------------- memory


@pytest.mark.parametrize("kind", TEXTURE_CLASSES)
def test_working_in_row_bands_changes_no_value(kind, monkeypatch):
    pixels = np.random.default_rng(5).integers(0, 256, (200, 120, 4), dtype=np.uint8)
    whole = resize_map(pixels, (37, 31), kind, alpha_cutoff=0.5)  # default: one 256-row band
    monkeypatch.setattr(maps, "_BAND", 7)
    assert (resize_map(pixels, (37, 31), kind, alpha_cutoff=0.5) == whole).all()


# ----------------------------------------------------------------------------- Toksvig roughness


def test_toksvig_widens_roughness_by_what_a_bumpy_normal_map_loses():
    bumpy = tilted_quad_normals(12, 20, np.radians(30))
    shortening = normal_shortening(bumpy, (6, 10))
    packed = np.zeros((6, 10, 3), np.uint8)
    packed[..., 0], packed[..., 1], packed[..., 2] = 200, 128, 30
    widened = toksvig_roughness(packed, shortening)
    s = shortening.astype(np.float64)
    expected = np.round(((128 / 255) ** 4 + 2 * (1 - s) / s) ** 0.25 * 255)
    assert (widened[..., 1] == expected).all()
    assert (
        abs(
            int(widened[0, 0, 1])
            - round((0.5**4 + 2 * (1 / np.cos(np.radians(30)) - 1)) ** 0.25 * 255)
        )
        <= 1
    )
    assert (widened[..., [0, 2]] == packed[..., [0, 2]]).all()  # occlusion, metallic kept


def test_toksvig_leaves_flat_normals_grey_maps_and_zero_factors_alone():
    packed = np.random.default_rng(3).integers(0, 256, (6, 10, 3), dtype=np.uint8)
    flat = np.ones((3, 5), np.float32)
    assert (toksvig_roughness(packed, flat) == packed).all()  # resampled to 6 x 10, still flat
    bumpy = np.full((6, 10), 0.5, np.float32)
    assert (toksvig_roughness(packed[..., :1], bumpy) == packed[..., :1]).all()
    assert (toksvig_roughness(packed, bumpy, roughness_factor=0.0) == packed).all()
    widened = toksvig_roughness(packed, bumpy, roughness_factor=0.5)
    assert (widened[..., 1] >= packed[..., 1]).all()
    assert (widened[..., 1] == 255).sum() > 0  # a^2 capped at 1: r = 1 is G = 255 / 0.5, clipped
