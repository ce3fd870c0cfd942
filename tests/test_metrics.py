"""Specification of geoscaler.render.metrics: PSNR and SSIM as PROTOCOL.md defines them."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.data import astronaut
from skimage.metrics import structural_similarity

from geoscaler.render.metrics import (
    METRIC_NAMES,
    SSIMLoss,
    evaluate,
    mean_metrics,
    psnr_fg,
    psnr_full,
    ssim_fg,
    ssim_full,
    ssim_map,
)

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _random_pair(n: int = 2, h: int = 32, w: int = 40, dtype=torch.float64, seed: int = 0):
    """Random reference in [0, 1] and a noisy image of it, ``(n, h, w, 3)`` each."""
    rng = _rng(seed)
    reference = rng.random((n, h, w, 3))
    image = np.clip(reference + rng.normal(0.0, 0.1, reference.shape), 0.0, 1.0)
    return torch.tensor(image, dtype=dtype), torch.tensor(reference, dtype=dtype)


def _natural_pair(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 96 x 112 crop of skimage's astronaut and a blurred, noisy, shifted version of it."""
    reference = astronaut()[120:216, 160:272].astype(np.float64) / 255.0
    blurred = (reference + np.roll(reference, 1, axis=0) + np.roll(reference, 1, axis=1)) / 3.0
    noise = _rng(seed).normal(0.0, 0.03, reference.shape)
    return np.clip(blurred + noise + 0.02, 0.0, 1.0), reference


def _skimage_ssim(image: np.ndarray, reference: np.ndarray, full: bool = False):
    return structural_similarity(
        image,
        reference,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1,
        channel_axis=-1,
        full=full,
    )


# ---------------------------------------------------------------- PSNR


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_identical_views_give_infinite_psnr_and_unit_ssim(device, dtype):
    _, reference = _random_pair(dtype=dtype)
    reference = reference.to(device)
    fg = torch.ones(reference.shape[:3], dtype=torch.bool, device=device)
    result = evaluate(reference.clone(), reference, fg)
    assert set(result) == set(METRIC_NAMES)
    for values in result.values():
        assert values.shape == (2,) and values.dtype == dtype and values.device.type == device
    assert torch.isinf(result["psnr_fg"]).all() and (result["psnr_fg"] > 0).all()
    assert torch.isinf(result["psnr_full"]).all()
    assert torch.equal(result["ssim_full"].cpu(), torch.ones(2, dtype=dtype))
    assert torch.equal(result["ssim_fg"].cpu(), torch.ones(2, dtype=dtype))


def test_constant_offset_of_a_tenth_is_20_db():
    reference = torch.rand(3, 16, 16, 3, dtype=torch.float64) * 0.9
    image = reference + 0.1
    fg = torch.rand(3, 16, 16) < 0.5
    twenty = torch.full((3,), 20.0, dtype=torch.float64)
    assert torch.allclose(psnr_full(image, reference), twenty, rtol=0, atol=1e-9)
    assert torch.allclose(psnr_fg(image, reference, fg), twenty, rtol=0, atol=1e-9)


def test_psnr_of_known_error_distribution():
    # Half the values off by 0.1, half by 0.2 (sign alternating): MSE = 0.025, PSNR = 16.0206 dB.
    reference = torch.full((1, 8, 8, 3), 0.5, dtype=torch.float64)
    error = torch.tensor([0.1, -0.2], dtype=torch.float64).repeat(96).view(1, 8, 8, 3)
    expected = 10.0 * math.log10(1.0 / 0.025)
    assert psnr_full(reference + error, reference).item() == pytest.approx(expected, abs=1e-9)


def test_psnr_fg_ignores_background_exactly():
    reference = torch.zeros(2, 12, 10, 3, dtype=torch.float64)
    fg = torch.zeros(2, 12, 10, dtype=torch.bool)
    fg[0, 2:6, 3:8] = True
    fg[1, 5:, :] = True
    # Off by 0.1 in the foreground, by 0.7 in the background.
    image = torch.where(fg[..., None], 0.1, 0.7).to(torch.float64).expand(-1, -1, -1, 3)
    assert torch.allclose(psnr_fg(image, reference, fg), torch.tensor([20.0, 20.0]).double())
    fraction = fg.double().mean(dim=(1, 2))
    mse = fraction * 0.01 + (1 - fraction) * 0.49
    assert torch.allclose(psnr_full(image, reference), -10 * torch.log10(mse))


def test_view_without_foreground_is_nan_and_others_unaffected():
    image, reference = _random_pair(n=3)
    fg = torch.ones(image.shape[:3], dtype=torch.bool)
    fg[1] = False
    values = psnr_fg(image, reference, fg)
    assert torch.isnan(values[1]) and torch.isfinite(values[[0, 2]]).all()
    assert torch.allclose(values[[0, 2]], psnr_full(image, reference)[[0, 2]])
    assert torch.isnan(ssim_fg(image, reference, fg)[1])


# ---------------------------------------------------------------- SSIM against scikit-image


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("kind", ["random", "natural"])
def test_ssim_full_matches_skimage(dtype, kind):
    if kind == "random":
        image, reference = (t[0].numpy() for t in _random_pair(n=1, h=48, w=37))
    else:
        image, reference = _natural_pair()
    np_dtype = np.float32 if dtype == torch.float32 else np.float64
    image, reference = image.astype(np_dtype), reference.astype(np_dtype)
    expected = _skimage_ssim(image, reference)
    ours = ssim_full(torch.from_numpy(image)[None], torch.from_numpy(reference)[None])
    assert ours.dtype == dtype
    assert ours.item() == pytest.approx(expected, abs=1e-3 if dtype == torch.float32 else 1e-10)


def test_ssim_map_is_skimages_full_map_border_included():
    image, reference = _natural_pair()
    _, expected = _skimage_ssim(image, reference, full=True)
    ours = ssim_map(torch.from_numpy(image)[None], torch.from_numpy(reference)[None])[0]
    np.testing.assert_allclose(ours.numpy(), expected.mean(axis=-1), atol=1e-10)


def test_ssim_fg_is_mean_of_map_over_foreground_in_interior():
    image, reference = _random_pair(n=2, h=30, w=28)
    smap = ssim_map(image, reference)
    fg = torch.rand(2, 30, 28, generator=torch.Generator().manual_seed(1)) < 0.4
    # A mask away from the 5-pixel border: plain mean of the map over it.
    inner = torch.zeros_like(fg)
    inner[:, 5:-5, 5:-5] = fg[:, 5:-5, 5:-5]
    expected = torch.stack([smap[i][inner[i]].mean() for i in range(2)])
    assert torch.allclose(ssim_fg(image, reference, inner), expected)
    # Mask pixels on the border are left out, like ssim_full leaves the border out.
    assert torch.allclose(ssim_fg(image, reference, fg), expected)
    full_mask = torch.ones_like(fg)
    assert torch.allclose(ssim_fg(image, reference, full_mask), ssim_full(image, reference))
    assert torch.allclose(ssim_full(image, reference), smap[:, 5:-5, 5:-5].mean(dim=(1, 2)))


# ---------------------------------------------------------------- vectorisation, API


@pytest.mark.parametrize("batch_size", [1, 2, 8])
def test_evaluate_vectorised_equals_per_view_loop(batch_size):
    image, reference = _random_pair(n=5, h=24, w=20)
    fg = torch.rand(5, 24, 20, generator=torch.Generator().manual_seed(2)) < 0.6
    batched = evaluate(image, reference, fg, batch_size=batch_size)
    for i in range(5):
        single = evaluate(image[i : i + 1], reference[i : i + 1], fg[i : i + 1])
        for name in METRIC_NAMES:
            assert torch.allclose(batched[name][i], single[name][0], rtol=1e-12, atol=0)
    assert torch.allclose(batched["psnr_fg"], psnr_fg(image, reference, fg))
    assert torch.allclose(batched["ssim_fg"], ssim_fg(image, reference, fg))


def test_mean_metrics_averages_views_and_skips_nan():
    metrics = {
        "psnr_fg": torch.tensor([20.0, float("nan"), 30.0]),
        "ssim_full": torch.tensor([0.5, 0.7, 0.9]),
        "empty": torch.tensor([float("nan")]),
    }
    means = mean_metrics(metrics)
    assert means["psnr_fg"] == pytest.approx(25.0)
    assert means["ssim_full"] == pytest.approx(0.7)
    assert math.isnan(means["empty"])
    assert all(isinstance(value, float) for value in means.values())


def test_evaluate_of_no_views_is_empty():
    empty = torch.zeros(0, 16, 16, 3)
    result = evaluate(empty, empty, torch.zeros(0, 16, 16, dtype=torch.bool))
    assert all(values.shape == (0,) for values in result.values())


def test_input_validation():
    image, reference = _random_pair(n=1)
    with pytest.raises(ValueError, match="shape"):
        psnr_full(image, reference[:, :-1])
    with pytest.raises(ValueError, match=r"\(N, H, W, C\)"):
        psnr_full(image[0], reference[0])
    with pytest.raises(TypeError, match="floating"):
        psnr_full((image * 255).to(torch.uint8), (reference * 255).to(torch.uint8))
    with pytest.raises(TypeError, match="bool"):
        psnr_fg(image, reference, torch.ones(image.shape[:3]))
    with pytest.raises(ValueError, match="mask shape"):
        ssim_fg(image, reference, torch.ones(1, 5, 5, dtype=torch.bool))
    with pytest.raises(ValueError, match="at least 11"):
        ssim_full(image[:, :10], reference[:, :10])


# ---------------------------------------------------------------- gradients, loss


def test_ssim_map_gradcheck():
    image, reference = _random_pair(n=2, h=7, w=6)
    image.requires_grad_(True)
    reference.requires_grad_(True)
    assert torch.autograd.gradcheck(ssim_map, (image, reference))


def test_psnr_gradcheck():
    image, reference = _random_pair(n=2, h=4, w=5)
    image.requires_grad_(True)
    fg = torch.rand(2, 4, 5, generator=torch.Generator().manual_seed(3)) < 0.5
    fg[:, 0, 0] = True
    assert torch.autograd.gradcheck(lambda x: psnr_fg(x, reference, fg), (image,))
    assert torch.autograd.gradcheck(lambda x: psnr_full(x, reference), (image,))


def test_ssim_loss():
    image, reference = _random_pair(n=3, h=20, w=22, dtype=torch.float32)
    loss_fn = SSIMLoss()
    image.requires_grad_(True)
    loss = loss_fn(image, reference)
    assert loss.dim() == 0
    assert loss.item() == pytest.approx(1.0 - ssim_full(image, reference).mean().item(), abs=1e-6)
    loss.backward()
    assert image.grad is not None and torch.isfinite(image.grad).all()
    assert image.grad.abs().sum() > 0
    assert loss_fn(reference, reference).item() == pytest.approx(0.0, abs=1e-6)
    fg = torch.zeros(3, 20, 22, dtype=torch.bool)
    assert loss_fn(image, reference, fg).item() == 0.0
    fg[:, 5:15, 5:15] = True
    expected = 1.0 - ssim_map(image, reference)[fg].mean()
    assert loss_fn(image, reference, fg).item() == pytest.approx(expected.item(), abs=1e-6)
