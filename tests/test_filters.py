"""Specification of geoscaler.resize.filters: the protocol's baseline downsamplers."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.resize import filters
from geoscaler.resize.filters import (
    BASELINES,
    _box_float,
    _pbd_float,
    box,
    downsample_texture,
    pbd,
    reference_texture,
    reference_textures,
    target_size,
)

METHODS = sorted(BASELINES)


def _texture(height: int, width: int, channels: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, channels), dtype=np.uint8)


def _blocks(blocks: np.ndarray, scale: int) -> np.ndarray:
    """Each texel of ``blocks`` ``(h, w, C)`` repeated into a ``scale x scale`` block."""
    return np.repeat(np.repeat(blocks, scale, axis=0), scale, axis=1)


# ---------------------------------------------------------------- sizes and validation


@pytest.mark.parametrize(
    ("height", "width", "scale", "expected"),
    [
        (2048, 2048, 4, (512, 512)),
        (2048, 1024, 8, (256, 128)),
        (1000, 750, 8, (125, 94)),  # 93.75 -> 94
        (1000, 750, 4, (250, 188)),  # 187.5 rounds half up
        (10, 7, 2, (5, 4)),  # 3.5 -> 4
        (9, 9, 4, (2, 2)),  # 2.25 -> 2
        (5, 3, 3, (2, 1)),  # 1.67 -> 2, 1.0 -> 1
        (3, 3, 3, (1, 1)),
    ],
)
def test_target_size(height, width, scale, expected):
    assert target_size(height, width, scale) == expected
    assert target_size(height, width, np.int64(scale)) == expected


@pytest.mark.parametrize(
    ("scale", "message"),
    [
        (0, "scale 0: must be a whole number >= 2"),
        (1, "scale 1: must be a whole number >= 2"),
        (-4, "scale -4: must be a whole number >= 2"),
        (1.5, "scale 1.5: must be a whole number >= 2"),
        (4.0, "scale 4.0: must be a whole number >= 2"),
        (True, "scale True: must be a whole number >= 2"),
        ("4", "scale '4': must be a whole number >= 2"),
        (11, "scale 11 is larger than the 20 x 10 texture"),
    ],
)
def test_invalid_scales_raise(scale, message):
    with pytest.raises(GeoscalerError, match=message.replace(".", r"\.")):
        target_size(20, 10, scale)
    with pytest.raises(GeoscalerError, match=message.replace(".", r"\.")):
        downsample_texture(_texture(20, 10, 3), scale, "box")


def test_scale_equal_to_shorter_side_is_allowed():
    for method in METHODS:
        assert downsample_texture(_texture(20, 10, 3), 10, method).shape == (2, 1, 3)


def test_unknown_method_lists_known_ones():
    with pytest.raises(GeoscalerError, match="unknown downsampling method 'nearest'") as info:
        downsample_texture(_texture(8, 8, 3), 2, "nearest")
    for method in METHODS:
        assert method in str(info.value)


@pytest.mark.parametrize(
    "texture",
    [
        np.zeros((8, 8, 3), dtype=np.float32),
        np.zeros((8, 8), dtype=np.uint8),
        np.zeros((8, 8, 5), dtype=np.uint8),
        np.zeros((8, 8, 3), dtype=np.uint16),
    ],
)
@pytest.mark.parametrize("method", METHODS)
def test_invalid_textures_raise(texture, method):
    with pytest.raises(GeoscalerError, match="texture"):
        downsample_texture(texture, 2, method)


# ---------------------------------------------------------------- every method


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("channels", [1, 2, 3, 4])
@pytest.mark.parametrize(("height", "width", "scale"), [(64, 48, 4), (50, 37, 8), (33, 19, 2)])
def test_shape_dtype_and_channels_kept(method, channels, height, width, scale):
    result = downsample_texture(_texture(height, width, channels), scale, method)
    assert result.dtype == np.uint8
    assert result.shape == (*target_size(height, width, scale), channels)


@pytest.mark.parametrize("method", METHODS)
def test_alpha_is_resampled_and_colour_under_transparency_kept(method):
    # RGB constant, alpha 0 / 255 in 4 x 4 blocks: no method may premultiply (which would
    # darken or zero the colour) and alpha keeps its block pattern.
    alpha_blocks = np.array([[0, 255, 0], [255, 0, 255]], dtype=np.uint8)[..., None]
    texture = np.empty((8, 12, 4), dtype=np.uint8)
    texture[..., :3] = 200
    texture[..., 3:] = _blocks(alpha_blocks, 4)
    result = downsample_texture(texture, 4, method)
    assert result.shape == (2, 3, 4)
    assert (result[..., :3] == 200).all()
    if method in ("box", "pbd"):
        np.testing.assert_array_equal(result[..., 3:], alpha_blocks)
    else:  # interpolating filters blur across blocks: same ordering, not the same values
        assert (result[..., 3][alpha_blocks[..., 0] == 255] > 127).all()
        assert (result[..., 3][alpha_blocks[..., 0] == 0] < 128).all()


@pytest.mark.parametrize(
    ("method", "resample"),
    [("box", Image.BOX), ("bicubic", Image.BICUBIC), ("lanczos", Image.LANCZOS)],
)
def test_pillow_baselines_are_pillows_rgb_resize(method, resample):
    texture = _texture(50, 37, 3)
    expected = np.asarray(Image.fromarray(texture).resize((5, 6), resample))
    np.testing.assert_array_equal(downsample_texture(texture, 8, method), expected)


@pytest.mark.parametrize(
    ("method", "resample"),
    [("box", Image.BOX), ("bicubic", Image.BICUBIC), ("lanczos", Image.LANCZOS)],
)
def test_channels_resized_on_threads_are_the_channels_resized_one_by_one(
    method, resample, monkeypatch
):
    texture = _texture(50, 37, 4)
    expected = np.stack(
        [np.asarray(Image.fromarray(texture[..., c]).resize((5, 6), resample)) for c in range(4)],
        axis=-1,
    )
    monkeypatch.setattr(filters, "PARALLEL_TEXELS", 1)
    monkeypatch.setattr(filters.os, "cpu_count", lambda: 2)
    np.testing.assert_array_equal(downsample_texture(texture, 8, method), expected)


def test_float_planes_resized_on_threads_are_the_planes_resized_one_by_one(monkeypatch):
    values = np.random.default_rng(4).random((50, 37, 3), dtype=np.float32)
    expected = filters.resize_float(values, (6, 5), Image.LANCZOS)
    monkeypatch.setattr(filters, "PARALLEL_TEXELS", 1)
    monkeypatch.setattr(filters.os, "cpu_count", lambda: 2)
    np.testing.assert_array_equal(filters.resize_float(values, (6, 5), Image.LANCZOS), expected)


def test_a_texture_resized_again_the_same_way_is_not_resized_again(monkeypatch):
    texture, calls = _texture(64, 64, 3), []
    resize = filters.resize_channels
    monkeypatch.setattr(filters, "resize_channels", lambda *a: calls.append(a) or resize(*a))
    first, second = filters.lanczos(texture, 4), filters.lanczos(texture, 4)
    other_size, other_filter = filters.lanczos(texture, 2), filters.bicubic(texture, 4)
    assert len(calls) == 3
    np.testing.assert_array_equal(first, second)
    first[0, 0] = 255 - second[0, 0]  # each caller's own array
    np.testing.assert_array_equal(filters.lanczos(texture, 4), second)
    assert other_size.shape == (32, 32, 3) and not np.array_equal(other_filter, second)


def test_a_resized_entry_is_only_the_array_it_was_made_from():
    """An array may take the id of one that was freed: its entry is not the new array's."""
    memo, before, after = filters._Resized(), _texture(4, 4, 3), _texture(4, 4, 3, seed=1)
    memo.put(before, "lanczos", before[:2, :2].copy())
    memo.entries[(id(after), "lanczos")] = memo.entries.pop((id(before), "lanczos"))
    assert memo.get(after, "lanczos") is None


def test_an_entry_goes_with_its_original():
    memo, original = filters._Resized(), _texture(4, 4, 3)
    memo.put(original, "lanczos", original[:2, :2].copy())
    del original
    assert memo.entries == {}


def test_only_the_last_entries_are_kept():
    memo, arrays = filters._Resized(size=2), [_texture(2, 2, 1, seed=s) for s in range(3)]
    for array in arrays:
        memo.put(array, "how", array.copy())
    assert [memo.get(a, "how") is not None for a in arrays] == [False, True, True]


@pytest.mark.parametrize("method", METHODS)
def test_constant_texture_stays_constant(method):
    texture = np.full((37, 23, 4), (7, 123, 250, 90), dtype=np.uint8)
    result = downsample_texture(texture, 4, method)
    assert (result == texture[0, 0]).all()


# ---------------------------------------------------------------- PBD


@pytest.mark.parametrize(("height", "width", "scale"), [(64, 64, 4), (37, 23, 4), (11, 40, 3)])
def test_pbd_of_constant_is_that_constant(height, width, scale):
    for value in (0, 1, 128, 254, 255):
        texture = np.full((height, width, 1), value, dtype=np.uint8)
        assert (pbd(texture, scale) == value).all()


@pytest.mark.parametrize("scale", [2, 4])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_pbd_of_constant_blocks_is_box(scale, channels):
    blocks = _texture(9, 7, channels, seed=scale)
    texture = _blocks(blocks, scale)
    np.testing.assert_array_equal(pbd(texture, scale), box(texture, scale))
    np.testing.assert_array_equal(pbd(texture, scale), blocks)


def test_pbd_single_patch_keeps_mean_and_variance():
    # Output 2 x 2 = one patch: D = M + R (L - M), so D has the patch's high-res mean and
    # variance exactly (up to float rounding).
    values = np.random.default_rng(4).random((8, 8, 3)) * 0.5 + 0.25
    result = _pbd_float(values, (2, 2))
    np.testing.assert_allclose(result.mean(axis=(0, 1)), values.mean(axis=(0, 1)), atol=1e-12)
    np.testing.assert_allclose(result.var(axis=(0, 1)), values.var(axis=(0, 1)), atol=1e-12)
    assert (result.var(axis=(0, 1)) > _box_float(values, (2, 2)).var(axis=(0, 1))).all()


def test_pbd_is_sharper_than_box_and_keeps_the_mean():
    # Coarse structure plus texel-level detail that box averaging flattens.
    rng = np.random.default_rng(5)
    coarse = _blocks(rng.integers(64, 192, (8, 8, 3)), 8)
    texture = (coarse + rng.integers(-40, 41, coarse.shape)).astype(np.uint8)
    ours, reference = pbd(texture, 4).astype(float), box(texture, 4).astype(float)
    assert abs(ours.mean() - reference.mean()) < 0.5
    assert ours.std() > 1.05 * reference.std()


@pytest.mark.parametrize(("height", "width", "size"), [(50, 37, (6, 5)), (1000, 750, (125, 94))])
def test_box_float_matches_pillow_box(height, width, size):
    values = np.random.default_rng(7).random((height, width)).astype(np.float32)
    expected = np.asarray(Image.fromarray(values, mode="F").resize(size[::-1], Image.BOX))
    ours = _box_float(values[..., None].astype(np.float64), size)[..., 0]
    np.testing.assert_allclose(ours, expected, atol=1e-6)


def test_pbd_thin_outputs():
    texture = _texture(3, 50, 2)
    assert pbd(texture, 3).shape == (1, 17, 2)
    assert pbd(np.full((3, 3, 1), 42, dtype=np.uint8), 3).tolist() == [[[42]]]


# ---------------------------------------------------------------- reference texture


@pytest.mark.parametrize(
    ("height", "width", "expected"),
    [
        (4096, 30, (2048, 15)),
        (30, 4096, (15, 2048)),
        (4100, 10, (2048, 5)),  # 4.995 -> 5
        (4097, 3, (2048, 1)),  # 1.4996 -> 1
        (5000, 1, (2048, 1)),  # never below 1 texel
    ],
)
def test_reference_texture_reduces_the_longer_side_to_2048(height, width, expected):
    texture = _texture(height, width, 1)
    result = reference_texture(texture)
    assert result.shape == (*expected, 1) and result.dtype == np.uint8


def test_reference_texture_keeps_aspect_and_channels():
    texture = _texture(100, 75, 4)
    result = reference_texture(texture, max_size=64)
    assert result.shape == (64, 48, 4)
    expected = np.asarray(Image.fromarray(texture[..., 0]).resize((48, 64), Image.LANCZOS))
    np.testing.assert_array_equal(result[..., 0], expected)


@pytest.mark.parametrize(("height", "width"), [(2048, 2048), (2048, 100), (100, 75), (1, 1)])
def test_reference_texture_leaves_smaller_textures_unchanged(height, width):
    texture = _texture(height, width, 3)
    assert reference_texture(texture) is texture


def test_materials_showing_one_image_share_one_reference():
    from types import SimpleNamespace

    image, other = _texture(64, 64, 3), _texture(64, 64, 3, seed=1)
    materials = [SimpleNamespace(base_color_texture=t) for t in (image, None, image, other)]
    mesh = SimpleNamespace(materials=materials)
    first, untextured, second, third = reference_textures(mesh, max_size=32)
    assert untextured is None and first is second and third is not first
    assert first.shape == (32, 32, 3)
    np.testing.assert_array_equal(first, reference_texture(image, 32))
    assert reference_textures(mesh, max_size=None)[0] is image  # the product: the original
