"""A majorise-minimise step for free texels: the loop's first steps.

With the mesh's UVs, a view's colours at the object's pixels are ``E(u + A S(p))``: ``p`` the
parameters (sRGB-encoded texels), ``S`` their decoding to linear light, ``A`` the fixed
sparse lookups of the view (mip chain and trilinear taps, every weight >= 0), ``u`` the
untextured materials' light and ``E`` the sRGB encoding. The Jacobian ``J = E' A S'`` of the
colours is elementwise non-negative, so the Gauss-Newton curvature ``J^T J`` of the L2 loss is
bounded above by the diagonal ``D = diag(J^T J 1)`` (its row sums), and ``p - g / D`` lowers the
linearised loss of the step's views from any start (a Jacobi step, as SIRT in tomography).

Adam's first steps move every texel by about the learning rate whatever its gradient: a start
that is already close (Lanczos on a detailed map) is first made worse, one far from it takes
tens of steps. This step moves each texel by what its own curvature says. It fits the few views
of one step, so the loop takes a handful of them first and goes on with Adam.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import torch

from geoscaler.color import linear_to_srgb, linear_to_srgb_slope
from geoscaler.render.views import ViewCache, mip_chains

DAMPING = 1e-3
"""Added to the curvature bound, relative to its mean over the texels with one: keeps the
step finite where a texel barely shows."""


@runtime_checkable
class Sloped(Protocol):
    """A model whose linear textures are an elementwise function of its parameters."""

    def parameters(self) -> Sequence[torch.Tensor]: ...

    def candidate(self) -> tuple[list[torch.Tensor | None], torch.Tensor | None]: ...

    def project(self) -> None: ...

    def slopes(self) -> list[torch.Tensor | None]:
        """Per material the ``(h, w, 3)`` derivative of each linear texel of the candidate by
        its parameter (None: untextured)."""
        ...


def curvature_bounds(
    train: ViewCache, model: Sloped, views: Sequence[int]
) -> tuple[torch.Tensor, list[torch.Tensor], list[torch.Tensor]]:
    """``(loss, gradients, bounds)`` of the mean L2 loss of the training ``views`` (the loss
    ``view_loss`` gives without SSIM or a perceptual term), per parameter its gradient and
    ``D``, the row sums of the loss's Gauss-Newton curvature ``mean_v (2 / n_v) J_v^T J_v``
    (``n_v``: the view's colour values).

    ``train`` must hold the views' taps (the mesh's UVs, or a fixed new layout's).
    """
    parameters = list(model.parameters())
    textures, _ = model.candidate()
    mips = mip_chains(textures)
    with torch.no_grad():
        slopes = mip_chains(model.slopes())
    losses, curvatures = [], []
    for view in views:
        linear = train.object_linear(view, mips)
        colours = linear_to_srgb(linear)
        losses.append((colours - train.object_reference(view)).square().mean())
        with torch.no_grad():  # J 1: the colours' change as every parameter moves by one
            along_ones = train.object_linear(view, slopes, untextured=False)
            along_ones = along_ones * linear_to_srgb_slope(linear)
        # d/dp of this is (2 / n) J^T J 1
        curvatures.append(2 * (colours * along_ones).sum() / colours.numel())
    loss = torch.stack(losses).mean()
    gradients = torch.autograd.grad(loss, parameters, retain_graph=True)
    bounds = torch.autograd.grad(torch.stack(curvatures).mean(), parameters)
    return loss.detach(), list(gradients), list(bounds)


def majorized_step(train: ViewCache, model: Sloped, views: Sequence[int]) -> float:
    """One step ``p <- p - g / (D + damping)`` on the mean L2 loss of the training ``views``
    (:func:`curvature_bounds`); returns that loss before the step."""
    loss, gradients, bounds = curvature_bounds(train, model, views)
    with torch.no_grad():
        for parameter, gradient, bound in zip(model.parameters(), gradients, bounds, strict=True):
            shown = int(torch.count_nonzero(bound))  # every bound is >= 0 (J >= 0)
            if shown:
                parameter.sub_(gradient / (bound + DAMPING * bound.sum() / shown))
    model.project()
    return loss.item()
