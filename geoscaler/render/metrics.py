"""Image-quality metrics of the evaluation protocol (PROTOCOL.md, protocol 1).

Every function works on batches of rendered views, vectorised over the views, on any device
(CPU or CUDA) and in float32 or float64, and is differentiable where that makes sense (the same
SSIM serves as a training loss).

Conventions:

- ``image`` and ``reference``: ``(N, H, W, C)`` floating tensors of sRGB-encoded values in
  ``[0, 1]``, ``C = 3`` for RGB renders (any ``C >= 1`` works: channels are averaged). The
  reference is the view rendered with the original texture, the image the same view with the
  candidate.
- ``fg``: ``(N, H, W)`` bool, the foreground: pixels the mesh covers in the reference render.
- Results are ``(N,)`` tensors, one value per view; :func:`mean_metrics` averages them over
  the views of a set, as the protocol reports them.

SSIM border convention: :func:`ssim_map` returns the full ``(N, H, W)`` map, the Gaussian
filter extending the image by symmetric (half-sample) reflection, exactly as scikit-image's
``structural_similarity(..., gaussian_weights=True, full=True)`` does. Both averages then
leave out the ``SSIM_PAD = 5`` pixel border, where the window reaches past the image and the
values depend on the padding: :func:`ssim_full` is the mean over the interior
``[5:H-5, 5:W-5]``, which is scikit-image's mean SSIM, and :func:`ssim_fg` is the mean over the
foreground pixels of that same interior. So a mask that covers the whole image gives
``ssim_fg == ssim_full``.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import nn

SSIM_WINDOW = 11
"""Side of the Gaussian SSIM window, in pixels."""
SSIM_SIGMA = 1.5
"""Standard deviation of the Gaussian SSIM window, in pixels."""
SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_PAD = (SSIM_WINDOW - 1) // 2
"""Border (5 pixels) that the SSIM averages leave out, as scikit-image crops it."""

METRIC_NAMES = ("psnr_fg", "psnr_full", "ssim_full", "ssim_fg")
"""Keys of :func:`evaluate`'s result, headline first."""

__all__ = [
    "METRIC_NAMES",
    "SSIMLoss",
    "evaluate",
    "mean_metrics",
    "psnr_fg",
    "psnr_full",
    "ssim_fg",
    "ssim_full",
    "ssim_map",
]


def _check_pair(image: torch.Tensor, reference: torch.Tensor) -> None:
    """Raise unless ``image`` and ``reference`` are floating ``(N, H, W, C)`` of one shape."""
    if image.dim() != 4:
        raise ValueError(f"expected (N, H, W, C) images, got shape {tuple(image.shape)}")
    if image.shape != reference.shape:
        raise ValueError(
            f"image and reference differ in shape: {tuple(image.shape)} vs {tuple(reference.shape)}"
        )
    if not (image.is_floating_point() and reference.is_floating_point()):
        raise TypeError(
            f"expected floating images in [0, 1], got {image.dtype} and {reference.dtype}"
        )


def _check_fg(fg: torch.Tensor, image: torch.Tensor) -> None:
    """Raise unless ``fg`` is a bool ``(N, H, W)`` mask matching ``image``'s first 3 dims."""
    if fg.dtype != torch.bool:
        raise TypeError(f"expected a bool foreground mask, got {fg.dtype}")
    if fg.shape != image.shape[:3]:
        raise ValueError(
            f"foreground mask shape {tuple(fg.shape)} does not match images "
            f"{tuple(image.shape[:3])}"
        )


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-view mean of ``values`` ``(N, H, W)`` over ``mask`` ``(N, H, W)`` -> ``(N,)``.

    nan for a view whose mask is empty. ``torch.where`` (not a product) keeps non-finite
    values outside the mask out of the sum and out of the gradient.
    """
    total = torch.where(mask, values, torch.zeros((), dtype=values.dtype, device=values.device))
    count = mask.sum(dim=(1, 2)).to(values.dtype)
    return total.sum(dim=(1, 2)) / count


def psnr_full(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """PSNR over whole views, peak 1.0.

    ``PSNR = -10 log10(MSE)``, ``MSE = mean over all pixels and channels of (image - ref)^2``.

    Args:
        image, reference: ``(N, H, W, C)`` floating, sRGB values in ``[0, 1]``.

    Returns:
        ``(N,)`` PSNR in dB per view; ``+inf`` where the views are identical.
    """
    _check_pair(image, reference)
    mse = (image - reference).square().mean(dim=(1, 2, 3))
    return -10.0 * torch.log10(mse)


def psnr_fg(image: torch.Tensor, reference: torch.Tensor, fg: torch.Tensor) -> torch.Tensor:
    """PSNR over foreground pixels only, peak 1.0: the protocol's headline metric.

    ``MSE = sum over fg pixels p and channels c of (image - ref)^2 / (C |fg|)`` per view,
    ``PSNR = -10 log10(MSE)``. Background pixels do not enter, whatever their values.

    Args:
        image, reference: ``(N, H, W, C)`` floating, sRGB values in ``[0, 1]``.
        fg: ``(N, H, W)`` bool foreground of the reference render.

    Returns:
        ``(N,)`` PSNR in dB per view; ``+inf`` where the foregrounds are identical, nan for a
        view without foreground pixels.
    """
    _check_pair(image, reference)
    _check_fg(fg, image)
    per_pixel = (image - reference).square().mean(dim=-1)
    return -10.0 * torch.log10(_masked_mean(per_pixel, fg))


def _gaussian_window(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The 1D SSIM window ``(SSIM_WINDOW,)``: ``w_k ∝ exp(-k^2 / (2 sigma^2))``, sum 1."""
    k = torch.arange(SSIM_WINDOW, dtype=torch.float64) - SSIM_PAD
    w = torch.exp(-(k * k) / (2.0 * SSIM_SIGMA**2))
    return (w / w.sum()).to(dtype=dtype, device=device)


def _symmetric_index(size: int, pad: int, device: torch.device) -> torch.Tensor:
    """Indices ``(size + 2 pad,)`` that extend an axis by half-sample symmetric reflection.

    ``d c b a | a b c d | d c b a``: scipy.ndimage's ``mode='reflect'``, repeated with period
    ``2 size`` so that any ``pad`` works, even beyond the axis length.
    """
    i = torch.remainder(torch.arange(-pad, size + pad, device=device), 2 * size)
    return torch.where(i >= size, 2 * size - 1 - i, i)


def _symmetric_pad(x: torch.Tensor, pad: int = SSIM_PAD) -> torch.Tensor:
    """Extend ``(N, H, W, C)`` images by ``pad`` pixels of symmetric reflection on each side.

    Returns ``(N, H + 2 pad, W + 2 pad, C)``: ``d c b a | a b c d | d c b a`` along rows and
    columns (:func:`_symmetric_index`). Mirrored slices are concatenated when ``pad`` fits in
    the image (a contiguous copy, much cheaper than a gather); longer pads use the index.
    """
    height, width = x.shape[1], x.shape[2]
    if pad <= min(height, width):
        x = torch.cat([x[:, :pad].flip(1), x, x[:, height - pad :].flip(1)], dim=1)
        return torch.cat([x[:, :, :pad].flip(2), x, x[:, :, width - pad :].flip(2)], dim=2)
    x = x.index_select(1, _symmetric_index(height, pad, x.device))
    return x.index_select(2, _symmetric_index(width, pad, x.device))


def _gaussian_filter_valid(x: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian filter of padded planes, valid part only.

    ``(N, K, H + 2 SSIM_PAD, W + 2 SSIM_PAD)`` -> ``(N, K, H, W)``: a row and a column pass
    (depthwise ``conv2d``, ``groups = K``). Channels-last input (as :func:`ssim_map` makes it)
    takes the fastest CPU convolution path.
    """
    planes = x.shape[1]
    w = _gaussian_window(x.dtype, x.device)
    x = F.conv2d(x, w.view(1, 1, 1, -1).repeat(planes, 1, 1, 1), groups=planes)
    return F.conv2d(x, w.view(1, 1, -1, 1).repeat(planes, 1, 1, 1), groups=planes)


def ssim_map(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM, Gaussian window 11, sigma 1.5, averaged over channels.

    Per channel, with ``G*`` the Gaussian filter (module docstring: symmetric padding),
    ``mu_x = G*x``, ``var_x = G*(x^2) - mu_x^2``, ``cov = G*(x y) - mu_x mu_y`` (population
    statistics), ``C1 = (0.01)^2``, ``C2 = (0.03)^2`` (data range 1)::

        SSIM = (2 mu_x mu_y + C1) (2 cov + C2) / ((mu_x^2 + mu_y^2 + C1) (var_x + var_y + C2))

    and the result is the mean over channels. This equals the channel mean of scikit-image's
    full SSIM map (``gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
    data_range=1``), border included. Differentiable in both inputs.

    Args:
        image, reference: ``(N, H, W, C)`` floating, values in ``[0, 1]``.

    Returns:
        ``(N, H, W)`` SSIM map; exactly 1 where the views are identical.
    """
    _check_pair(image, reference)
    # Pad the 2 images before forming the 5 statistics: products of padded values are the
    # padded products, and there are fewer planes to pad. (N, H', W', 5C) -> channels-last.
    x = _symmetric_pad(image)
    y = _symmetric_pad(reference)
    planes = torch.cat([x, y, x * x, y * y, x * y], dim=-1).permute(0, 3, 1, 2)
    stats = _gaussian_filter_valid(planes)
    mu_x, mu_y, xx, yy, xy = stats.chunk(5, dim=1)
    var_x = xx - mu_x * mu_x
    var_y = yy - mu_y * mu_y
    cov = xy - mu_x * mu_y
    c1 = SSIM_K1**2
    c2 = SSIM_K2**2
    numerator = (2.0 * mu_x * mu_y + c1) * (2.0 * cov + c2)
    denominator = (mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2)
    return (numerator / denominator).mean(dim=1)


def _interior(height: int, width: int, device: torch.device) -> torch.Tensor:
    """``(H, W)`` bool: True except on the ``SSIM_PAD`` border that SSIM averages leave out."""
    if min(height, width) < SSIM_WINDOW:
        raise ValueError(
            f"SSIM needs images of at least {SSIM_WINDOW} x {SSIM_WINDOW} pixels, "
            f"got {height} x {width}"
        )
    inside = torch.zeros(height, width, dtype=torch.bool, device=device)
    inside[SSIM_PAD : height - SSIM_PAD, SSIM_PAD : width - SSIM_PAD] = True
    return inside


def _ssim_means(smap: torch.Tensor, fg: torch.Tensor | None) -> torch.Tensor:
    """Mean of an SSIM map ``(N, H, W)`` over the interior (and ``fg`` if given) -> ``(N,)``."""
    inside = _interior(smap.shape[1], smap.shape[2], smap.device).expand_as(smap)
    return _masked_mean(smap, inside if fg is None else inside & fg)


def ssim_full(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Mean SSIM per view over the interior ``[5:H-5, 5:W-5]`` of :func:`ssim_map`.

    This is scikit-image's ``structural_similarity(..., gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1, channel_axis=-1)``, which crops the same border.

    Args:
        image, reference: ``(N, H, W, C)`` floating, ``H, W >= 11``.

    Returns:
        ``(N,)`` mean SSIM per view, 1 for identical views.
    """
    return _ssim_means(ssim_map(image, reference), None)


def ssim_fg(image: torch.Tensor, reference: torch.Tensor, fg: torch.Tensor) -> torch.Tensor:
    """Mean of :func:`ssim_map` over the foreground pixels of the interior, per view.

    The pixels averaged are ``fg & interior``, interior being ``[5:H-5, 5:W-5]`` as for
    :func:`ssim_full` (the border's SSIM depends on how the image is padded), so a mask that
    covers the whole image gives :func:`ssim_full`.

    Args:
        image, reference: ``(N, H, W, C)`` floating, ``H, W >= 11``.
        fg: ``(N, H, W)`` bool foreground of the reference render.

    Returns:
        ``(N,)`` mean SSIM per view; nan for a view with no foreground pixel in the interior.
    """
    _check_fg(fg, image)
    return _ssim_means(ssim_map(image, reference), fg)


def _content_box(image: torch.Tensor, reference: torch.Tensor) -> tuple[slice, slice] | None:
    """Rows and columns outside which SSIM is exactly 1 in every view of the batch.

    Where both ``(N, H, W, C)`` images are zero in a pixel's whole window, ``mu``, ``var`` and
    ``cov`` are exactly 0 and SSIM is ``C1 C2 / (C1 C2) = 1`` exactly (renders: the black
    background around the mesh). The box is the bounding box of the non-zero pixels grown by
    ``2 SSIM_PAD``, so that the symmetric padding of the cropped images reflects zeros exactly
    where the full images hold zeros, and SSIM inside the box is the same as in the full image.

    Returns:
        ``(rows, cols)`` slices, or None when both images are zero everywhere.
    """
    nonzero = (image != 0).any(dim=-1) | (reference != 0).any(dim=-1)
    rows = torch.nonzero(nonzero.any(dim=(0, 2))).flatten().tolist()
    cols = torch.nonzero(nonzero.any(dim=(0, 1))).flatten().tolist()
    if not rows:
        return None
    grow = 2 * SSIM_PAD
    height, width = image.shape[1], image.shape[2]
    return (
        slice(max(rows[0] - grow, 0), min(rows[-1] + 1 + grow, height)),
        slice(max(cols[0] - grow, 0), min(cols[-1] + 1 + grow, width)),
    )


def _ssim_map_on_content(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """:func:`ssim_map`, computed only inside :func:`_content_box` (1 outside): faster on renders
    of a mesh against a black background, the same values."""
    smap = image.new_ones(image.shape[:3])
    box = _content_box(image, reference)
    if box is not None:
        rows, cols = box
        smap[:, rows, cols] = ssim_map(image[:, rows, cols], reference[:, rows, cols])
    return smap


@torch.no_grad()
def evaluate(
    images: torch.Tensor,
    references: torch.Tensor,
    fg: torch.Tensor,
    batch_size: int = 8,
) -> dict[str, torch.Tensor]:
    """All protocol metrics per view (no gradients).

    Views are processed ``batch_size`` at a time (vectorised within a batch) to bound memory:
    SSIM holds about ``15 * batch_size * H * W`` filter values at once.

    Args:
        images: ``(N, H, W, C)`` candidate renders, floating sRGB in ``[0, 1]``.
        references: ``(N, H, W, C)`` renders with the original texture.
        fg: ``(N, H, W)`` bool foreground of the reference renders.
        batch_size: views per vectorised batch.

    Returns:
        ``{"psnr_fg", "psnr_full", "ssim_full", "ssim_fg"}`` -> ``(N,)`` tensors.
    """
    _check_pair(images, references)
    _check_fg(fg, images)
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if images.shape[0] == 0:
        return {name: images.new_empty(0) for name in METRIC_NAMES}
    parts: dict[str, list[torch.Tensor]] = {name: [] for name in METRIC_NAMES}
    for start in range(0, images.shape[0], batch_size):
        img = images[start : start + batch_size]
        ref = references[start : start + batch_size]
        mask = fg[start : start + batch_size]
        smap = _ssim_map_on_content(img, ref)
        parts["psnr_fg"].append(psnr_fg(img, ref, mask))
        parts["psnr_full"].append(psnr_full(img, ref))
        parts["ssim_full"].append(_ssim_means(smap, None))
        parts["ssim_fg"].append(_ssim_means(smap, mask))
    return {name: torch.cat(values) for name, values in parts.items()}


def mean_metrics(metrics: Mapping[str, torch.Tensor]) -> dict[str, float]:
    """Average per-view metrics over the views of a set, as the protocol reports them.

    Each value is the mean of the ``(N,)`` per-view values. Views where a metric is undefined
    (nan: no foreground) are left out of that metric's mean; nan if all are. A view with
    ``+inf`` PSNR (identical to the reference) makes the mean ``+inf``.

    Args:
        metrics: name -> ``(N,)`` tensor, e.g. :func:`evaluate`'s result.

    Returns:
        name -> mean as a Python float.
    """
    return {
        name: float(torch.nanmean(values.detach().to(torch.float64)))
        for name, values in metrics.items()
    }


class SSIMLoss(nn.Module):
    """Training loss ``1 - mean SSIM``, the same SSIM as the metrics, differentiable.

    ``forward(image, reference, fg=None)`` takes ``(N, H, W, C)`` images (``H, W >= 11``) and
    an optional ``(N, H, W)`` bool foreground, and returns a scalar: ``1 -`` the mean of
    :func:`ssim_map` over the interior pixels (``[5:H-5, 5:W-5]``, as the metrics) of all views,
    restricted to ``fg`` when given. The pixels of the batch are pooled, so views with little
    foreground weigh less and a view without any adds nothing; without ``fg`` this is
    ``1 - ssim_full(...).mean()``. A batch without a single foreground pixel gives 0.
    """

    def forward(
        self, image: torch.Tensor, reference: torch.Tensor, fg: torch.Tensor | None = None
    ) -> torch.Tensor:
        smap = ssim_map(image, reference)
        mask = _interior(smap.shape[1], smap.shape[2], smap.device).expand_as(smap)
        if fg is not None:
            _check_fg(fg, image)
            mask = mask & fg
        zero = torch.zeros((), dtype=smap.dtype, device=smap.device)
        dissimilarity = torch.where(mask, 1.0 - smap, zero)
        return dissimilarity.sum() / mask.sum().clamp(min=1).to(smap.dtype)
