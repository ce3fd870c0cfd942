"""The bakes a race weighs, on every development mesh at product size: a new layout that gives
the views at least the own layout's texels starts where the filters are on Q, not below them.

A bake that starts below the best filter makes the race keep the mesh's own layout, and the
re-allocation is lost where it should pay most (a 4096 scan's bake once started 10 dB below
Lanczos at 4x). Q is the set the layouts are planned for; the near and far views of a layout
read its mips across chart borders and are the race's gate's to judge (:func:`start_below` on
every set, before a trial)."""

from __future__ import annotations

from functools import cache

import pytest
import torch
from conftest import mesh_params

from geoscaler.io import load_mesh
from geoscaler.methods import LayoutFacts, MethodOptions, RunContext
from geoscaler.methods.direct import DEFAULT_CONFIG, start_model
from geoscaler.methods.learned import loop_config
from geoscaler.methods.registry import output_sizes_for
from geoscaler.methods.repacked import _new_layout, offered_layouts, start_below
from geoscaler.optim.loop import validate
from geoscaler.optim.validation import Validation
from geoscaler.optim.validation_views import validation_view_sets
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.renderer import Renderer
from geoscaler.resize.filters import bicubic, lanczos, reference_textures
from geoscaler.resize.sizes import SizeRule

Q_VIEWS = 6
"""Validation views of Q the starts are compared on (the race's own count varies with its
budget; its gate allows for the noise of however many it has)."""


@cache
def _mesh(path):
    return load_mesh(path)


def _q_validation(mesh, renderer: Renderer, scale: int) -> Validation:
    """The job's validation on Q alone: :data:`Q_VIEWS` views, bicubic and Lanczos of the
    full-resolution originals as its filters."""
    originals = reference_textures(mesh, None)
    filters = {
        name: [None if t is None else f(t, scale) for t in originals]
        for name, f in (("bicubic", bicubic), ("lanczos", lanczos))
    }
    sizes = output_sizes_for(mesh, SizeRule(scale=scale), renderer)
    validation = Validation({"Q": validation_view_sets(renderer)["Q"]}, sizes, filters)
    validation.freeze({"Q": Q_VIEWS})
    return validation


@pytest.mark.parametrize("scale", [4, 8])
@pytest.mark.parametrize("path", mesh_params())
def test_a_new_layout_as_dense_as_the_own_one_starts_no_lower_than_the_filters_on_q(path, scale):
    mesh = _mesh(path)
    renderer = Renderer(mesh, "cpu", product_evaluation(PROTOCOL_EVALUATION))
    rule = SizeRule(scale=scale)
    config = loop_config(DEFAULT_CONFIG, MethodOptions(device="cpu"), RunContext(renderer))
    atlases = offered_layouts(mesh, rule, renderer, config, LayoutFacts(uv="auto"))
    dense = [atlas for atlas in atlases if atlas.facts.k >= 1.0]
    if not dense:
        pytest.skip(f"no new layout at least as dense as the own one at {scale}x")
    validation = _q_validation(mesh, renderer, scale)
    for atlas in dense:
        layout = _new_layout(mesh, atlas, renderer, validation, validation.sizes, {})
        layout.validation.find_taps()
        model = start_model(mesh, rule, layout.renderer, layout.starts)
        with torch.no_grad():
            start = validate(layout.validation, model.candidate())
        floor = validation.floor()["Q"]["Q"]
        below = start_below(layout.validation, start)
        assert "Q" not in below, (
            f"{'aligned' if atlas.aligned else 'unaligned'} layout, k {atlas.facts.k:.3f}: "
            f"starts at {start['Q']:.2f} dB on Q, the best filter at {floor:.2f}"
        )
