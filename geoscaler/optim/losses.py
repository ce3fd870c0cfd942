"""The training loss of the optimisation loop: how far a candidate's render of a view is from
the original's (L2 and 1 - SSIM on sRGB images over the object, plus an optional perceptual
term)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from geoscaler.render.metrics import SSIMLoss
from geoscaler.render.texture import MipTexture
from geoscaler.render.views import ViewCache


@dataclass
class PerceptualTerm:
    """``weight * loss(image, reference)`` on the object's crop of two ``(H, W, 3)`` images."""

    loss: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    weight: float


def rendering_loss(
    image: torch.Tensor,
    reference: torch.Tensor,
    foreground: torch.Tensor,
    ssim_weight: float,
    perceptual: PerceptualTerm | None = None,
) -> torch.Tensor:
    """The training loss of one view, on sRGB images:

    ``mean_fg (image - reference)^2 + ssim_weight (1 - SSIM_fg) + perceptual`` (the last two
    on the crop around the object).
    """
    mse = (image - reference).square().mean(-1)[foreground].mean()
    if ssim_weight == 0 and perceptual is None:
        return mse
    rows = torch.nonzero(foreground.any(1)).squeeze(1)
    cols = torch.nonzero(foreground.any(0)).squeeze(1)
    pad = 8  # keep the SSIM window's context around the object
    r0, r1 = max(int(rows[0]) - pad, 0), min(int(rows[-1]) + pad + 1, image.shape[0])
    c0, c1 = max(int(cols[0]) - pad, 0), min(int(cols[-1]) + pad + 1, image.shape[1])
    if r1 - r0 < 11 or c1 - c0 < 11:
        return mse
    crop = (slice(r0, r1), slice(c0, c1))
    loss = mse
    if ssim_weight != 0:
        ssim = SSIMLoss()(image[crop][None], reference[crop][None], foreground[crop][None])
        loss = loss + ssim_weight * ssim
    if perceptual is not None:
        loss = loss + perceptual.weight * perceptual.loss(image[crop], reference[crop])
    return loss


def view_loss(
    cache: ViewCache,
    view: int,
    textures: Sequence[torch.Tensor | MipTexture | None],
    uvs: torch.Tensor | None,
    ssim_weight: float,
    perceptual: PerceptualTerm | None = None,
) -> torch.Tensor:
    """:func:`rendering_loss` of a candidate in the cached view ``view``.

    The L2 term alone reads the object's pixels only; with the taps they alone are rendered
    (:meth:`~geoscaler.render.views.ViewCache.object_colours`), the same mean up to float
    rounding."""
    if uvs is None and cache.with_taps and ssim_weight == 0 and perceptual is None:
        colours = cache.object_colours(view, textures)
        return (colours - cache.object_reference(view)).square().mean()
    image = cache.render(view, textures, uvs)
    return rendering_loss(image, *cache.views.reference(view), ssim_weight, perceptual)
