"""Colour encodings: 8-bit sRGB textures and linear light, and the grey-to-RGB rule.

The sRGB transfer functions (IEC 61966-2-1) and their slopes on tensors, the 8-bit decode
table, and the conversions between ``(H, W, C)`` uint8 sRGB textures and float linear ones that
every module uses: the data model, image loading, the sampler, the filters, the optimiser.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch


def srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    """Decode sRGB-encoded values in [0, 1] to linear light (IEC 61966-2-1), same shape.

    Differentiable; the backward pass keeps only ``x`` (:func:`srgb_to_linear_slope`), not
    the formula's intermediates: on a 2048 x 2048 texture those were ~100 MB a step."""
    return _Curve.apply(x, _srgb_to_linear, srgb_to_linear_slope)


def _srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: torch.Tensor) -> torch.Tensor:
    """Encode linear light to sRGB in [0, 1] (inputs clamped to [0, 1] first), same shape.

    Differentiable; the backward pass keeps only ``x`` (:func:`linear_to_srgb_slope`). The
    encoding holds two buffers of ``x``'s size at once, not the formula's six: it runs on whole
    textures each validation."""
    return _Curve.apply(x, _linear_to_srgb, linear_to_srgb_slope)


def _linear_to_srgb(x: torch.Tensor) -> torch.Tensor:
    encoded = x.clamp(0.0, 1.0)
    dark = encoded <= 0.0031308
    low = encoded * 12.92
    encoded.clamp_(min=0.0031308).pow_(1 / 2.4).mul_(1.055).sub_(0.055)
    return torch.where(dark, low, encoded, out=low)


class _Curve(torch.autograd.Function):
    """An elementwise curve whose backward pass is its slope at the saved input."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, curve: Callable, slope: Callable) -> torch.Tensor:  # noqa: ANN001
        ctx.save_for_backward(x)
        ctx.slope = slope
        return curve(x)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None, None]:  # noqa: ANN001
        (x,) = ctx.saved_tensors
        return grad * ctx.slope(x), None, None


def srgb_to_linear_slope(x: torch.Tensor) -> torch.Tensor:
    """d :func:`srgb_to_linear` / dx at sRGB-encoded values ``x``, same shape."""
    return torch.where(x <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((x + 0.055) / 1.055) ** 1.4)


def linear_to_srgb_slope(x: torch.Tensor) -> torch.Tensor:
    """d :func:`linear_to_srgb` / dx at linear values ``x``, same shape (0 outside [0, 1],
    where the encoding clamps)."""
    inside = (x >= 0) & (x <= 1)
    slope = 1.055 / 2.4 * x.clamp(0.0031308, 1.0) ** (1 / 2.4 - 1)
    return torch.where(inside, torch.where(x <= 0.0031308, 12.92, slope), 0.0)


def to_rgb(texture: np.ndarray) -> np.ndarray:
    """The colour channels of a texture, grey broadcast to RGB and alpha dropped.

    The one grey-to-RGB rule of the project: grey (and grey+alpha) repeats its grey channel
    into R, G and B.

    Parameters
    ----------
    texture : (H, W) or (H, W, C) array
        ``C`` in 1..4: grey, grey+alpha, RGB or RGBA; any dtype.

    Returns
    -------
    (H, W, 3) array of the same dtype
        A view of ``texture`` when ``C >= 3``, a new array for grey.
    """
    if texture.ndim == 2:
        texture = texture[..., None]
    return texture[..., :3] if texture.shape[2] >= 3 else np.repeat(texture[..., :1], 3, axis=2)


def texture_to_linear(texture: np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
    """``(H, W, C)`` uint8 sRGB texture to ``(H, W, 3)`` float32 linear RGB (alpha dropped).

    Grayscale textures (C = 1 or 2) are broadcast to RGB (:func:`to_rgb`).
    """
    rgb = to_rgb(texture)
    if rgb.dtype != np.uint8:
        raise TypeError(f"an 8-bit texture is expected, got {rgb.dtype}")
    return torch.from_numpy(np.take(DECODED_SRGB, rgb)).to(device)


DECODED_SRGB = srgb_to_linear(torch.arange(256, dtype=torch.float32) / 255.0).numpy()
"""Linear light of each 8-bit sRGB code, float32: a table lookup decodes a 4096^2 texture ~30x
faster than the formula (0.06 s against 1.8 s), to the same bits."""


def linear_to_texture(linear: torch.Tensor) -> np.ndarray:
    """``(H, W, C)`` linear float texture to uint8 sRGB, as it would ship."""
    encoded = linear_to_srgb(linear.detach()).mul(255.0).round()
    return encoded.to(torch.uint8).cpu().numpy()


def quantize_linear(linear: torch.Tensor) -> torch.Tensor:
    """Round a linear texture to the nearest 8-bit sRGB value and decode it again."""
    return srgb_to_linear(linear_to_srgb(linear).mul(255.0).round() / 255.0)
