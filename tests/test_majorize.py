"""The majorise-minimise step that starts the loop for free texels."""

import pytest
import torch
from mesh_support import three_material_demo

import geoscaler.optim.loop as optimize_module
from geoscaler.color import (
    linear_to_srgb,
    linear_to_srgb_slope,
    srgb_to_linear,
    srgb_to_linear_slope,
)
from geoscaler.methods.direct import TexelModel
from geoscaler.optim.loop import OptimizeConfig, optimize
from geoscaler.optim.majorize import curvature_bounds, majorized_step
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import validation_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, ViewSet


def test_the_slopes_are_the_derivatives_of_the_srgb_curves():
    x = torch.linspace(0.0005, 0.9995, 2001, dtype=torch.float64).requires_grad_(True)
    (decoded,) = torch.autograd.grad(srgb_to_linear(x).sum(), x)
    (encoded,) = torch.autograd.grad(linear_to_srgb(x).sum(), x)
    torch.testing.assert_close(srgb_to_linear_slope(x.detach()), decoded)
    torch.testing.assert_close(linear_to_srgb_slope(x.detach()), encoded)
    # the encoding clamps to [0, 1]: no slope outside
    assert linear_to_srgb_slope(torch.tensor([-0.1, 1.2])).tolist() == [0.0, 0.0]


def test_the_srgb_curves_differentiate_as_their_formulas_by_finite_differences():
    # the curves' backward passes are the slopes themselves: checked here against the formulas
    decoded = torch.tensor([0.001, 0.02, 0.04, 0.05, 0.3, 0.7, 0.999], dtype=torch.float64)
    assert torch.autograd.gradcheck(srgb_to_linear, decoded.requires_grad_(True))
    linear = torch.tensor([-0.2, 0.001, 0.003, 0.004, 0.2, 0.9, 1.3], dtype=torch.float64)
    assert torch.autograd.gradcheck(linear_to_srgb, linear.requires_grad_(True))


def test_the_srgb_encoding_is_the_standards_formula():
    x = torch.linspace(-0.1, 1.1, 100_001)
    clamped = x.clamp(0.0, 1.0)
    formula = torch.where(
        clamped <= 0.0031308,
        clamped * 12.92,
        1.055 * clamped.clamp_min(0.0031308) ** (1 / 2.4) - 0.055,
    )
    assert torch.equal(linear_to_srgb(x), formula)
    assert torch.equal(linear_to_srgb(x.clone().requires_grad_(True)).detach(), formula)


@pytest.fixture(scope="module")
def small_views():
    """Three cached 16-pixel views of a two-textured, one-untextured mesh, with the taps of
    8 x 8 and 16 x 8 candidates."""
    mesh = three_material_demo()
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=16))
    views = ViewSet(renderer, validation_cameras()[:3])
    while views.cache_next():
        pass
    return ViewCache(views, [(8, 8), (16, 8), None], with_taps=True)


def random_model(seed: int) -> TexelModel:
    generator = torch.Generator().manual_seed(seed)
    textures = [torch.rand(8, 8, 3, generator=generator), torch.rand(16, 8, 3, generator=generator)]
    return TexelModel([*textures, None])


def test_the_bounds_are_the_row_sums_of_the_gauss_newton_curvature(small_views):
    model = random_model(0)
    parameters = model.parameters()
    views = [0, 2]
    loss, gradients, bounds = curvature_bounds(small_views, model, views)
    expected = [torch.zeros_like(p) for p in parameters]
    for view in views:

        def colours(*values, view=view):
            textures = [srgb_to_linear(v) for v in values]
            return small_views.object_colours(view, [*textures, None]).reshape(-1)

        jacobians = torch.autograd.functional.jacobian(colours, tuple(parameters))
        full = torch.cat([j.reshape(j.shape[0], -1) for j in jacobians], dim=1)  # (n, P)
        assert (full >= 0).all()  # what makes the row sums a bound
        row_sums = 2 * full.T @ (full @ torch.ones(full.shape[1])) / full.shape[0]
        parts = row_sums.split([p.numel() for p in parameters])
        for total, part in zip(expected, parts, strict=True):
            total += part.view_as(total) / len(views)
    for bound, row_sums in zip(bounds, expected, strict=True):
        assert bound.abs().max() > 0
        torch.testing.assert_close(bound, row_sums, rtol=1e-4, atol=1e-9)
    assert loss > 0
    assert [g.shape for g in gradients] == [p.shape for p in parameters]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_majorized_step_lowers_the_loss_of_its_views(small_views, seed):
    model = random_model(seed)
    before = majorized_step(small_views, model, [0, 1, 2])
    after, _, _ = curvature_bounds(small_views, model, [0, 1, 2])
    assert after < 0.5 * before


def test_the_loop_takes_its_first_steps_majorized_then_adamw(monkeypatch):
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=32, views=(0, 30)))
    views = validation_view_sets(renderer, guard_views=1)
    calls = []

    def counted(train, model, chosen):
        calls.append(len(chosen))
        return majorized_step(train, model, chosen)

    monkeypatch.setattr(optimize_module, "majorized_step", counted)
    config = OptimizeConfig(
        steps=6, pool_views=6, majorized_steps=4, validate_every=6, ssim_weight=0.0
    )
    model = TexelModel([torch.full((16, 16, 3), 0.5)])
    result = optimize(renderer, model, config, Validation(views, [(16, 16)]))
    assert result.steps == 6 and calls == [4, 4, 4, 4]
    calls.clear()  # a model without slopes (the network's) never takes one
    optimize(renderer, _Unsloped(model), config, Validation(views, [(16, 16)]))
    assert calls == []


class _Unsloped:
    """A texel model without :meth:`slopes`."""

    def __init__(self, model: TexelModel):
        self.model = model

    def parameters(self):
        return self.model.parameters()

    def candidate(self):
        return self.model.candidate()

    def project(self) -> None:
        self.model.project()
