"""AdamW, the optimiser of every learned method, in plain tensor operations.

The same update as ``torch.optim.AdamW`` (decoupled weight decay, bias-corrected moments, no
AMSGrad). It exists because the first use of any ``torch.optim`` optimiser imports
``torch._dynamo`` (~2 s on a 2-core CPU, measured with ``python -X importtime``): time every
command would spend before its first step.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch


class AdamW:
    """Decoupled-weight-decay Adam over a fixed list of parameters.

    Args:
        parameters: the tensors to optimise (``requires_grad``); a parameter without a gradient
            at a step is left as it is, its moments too.
        lr: learning rate; :attr:`lr` may be changed between steps (a schedule).
        weight_decay: decoupled weight decay (the parameter shrinks by ``lr * weight_decay``).
        betas: the moments' decay rates.
        eps: added to the second moment's root.
    """

    def __init__(
        self,
        parameters: Iterable[torch.Tensor],
        lr: float = 1e-3,
        weight_decay: float = 1e-2,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ):
        self.parameters = list(parameters)
        self.lr = lr
        self.weight_decay = weight_decay
        self.betas = betas
        self.eps = eps
        self.steps = [0] * len(self.parameters)
        self.first = [torch.zeros_like(p) for p in self.parameters]
        self.second = [torch.zeros_like(p) for p in self.parameters]

    def zero_grad(self) -> None:
        """Forget the gradients (set them to None)."""
        for p in self.parameters:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update of every parameter that has a gradient."""
        beta1, beta2 = self.betas
        for i, p in enumerate(self.parameters):
            if p.grad is None:
                continue
            self.steps[i] += 1
            t = self.steps[i]
            p.mul_(1 - self.lr * self.weight_decay)
            self.first[i].lerp_(p.grad, 1 - beta1)
            self.second[i].mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
            denominator = (self.second[i].sqrt() / math.sqrt(1 - beta2**t)).add_(self.eps)
            p.addcdiv_(self.first[i], denominator, value=-self.lr / (1 - beta1**t))
