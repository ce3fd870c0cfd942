"""AdamW: the update of ``torch.optim.AdamW``, without its first-use import of dynamo."""

import subprocess
import sys

import torch

from geoscaler.optim.adamw import AdamW


def quadratic_steps(optimizer, parameters, lrs):
    """Steps on sum((p - 1)^2 * weights) with a changing learning rate."""
    weights = [torch.linspace(0.5, 3.0, p.numel()).reshape(p.shape) for p in parameters]
    for lr in lrs:
        for group in getattr(optimizer, "param_groups", []):
            group["lr"] = lr
        if hasattr(optimizer, "lr"):
            optimizer.lr = lr
        optimizer.zero_grad()
        loss = sum(((p - 1) ** 2 * w).sum() for p, w in zip(parameters, weights, strict=True))
        loss.backward()
        optimizer.step()


def test_matches_torch_adamw_over_steps_with_a_schedule():
    torch.manual_seed(0)
    start = [torch.randn(4, 5, 3, dtype=torch.float64), torch.randn(7, dtype=torch.float64)]
    ours = [p.clone().requires_grad_(True) for p in start]
    theirs = [p.clone().requires_grad_(True) for p in start]
    lrs = [0.01 * (1 + i % 3) for i in range(25)]
    quadratic_steps(AdamW(ours, lr=0.01, weight_decay=0.05), ours, lrs)
    quadratic_steps(torch.optim.AdamW(theirs, lr=0.01, weight_decay=0.05), theirs, lrs)
    for a, b in zip(ours, theirs, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)


def test_a_parameter_without_gradient_is_left_alone():
    used = torch.zeros(3, requires_grad=True)
    unused = torch.full((2,), 5.0, requires_grad=True)
    optimizer = AdamW([used, unused], lr=0.1, weight_decay=0.5)
    optimizer.zero_grad()
    (used - 1).pow(2).sum().backward()
    optimizer.step()
    assert torch.equal(unused.detach(), torch.full((2,), 5.0))
    assert optimizer.steps == [1, 0]
    # Adam's first step moves each coordinate by lr against the gradient's sign
    torch.testing.assert_close(used.detach(), torch.full((3,), 0.1))


def test_using_it_does_not_import_dynamo():
    code = (
        "import sys, torch; from geoscaler.optim.adamw import AdamW;"
        "p = torch.zeros(2, requires_grad=True); o = AdamW([p]);"
        "p.sum().backward(); o.step(); print('torch._dynamo' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
