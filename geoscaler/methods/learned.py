"""What every learned method does around the optimisation loop, once: take the job's renderer
and validation (or make them), build the loop's settings from the options, run
:func:`geoscaler.optim.loop.optimize` under the time left, and return 8-bit textures with the
loop's facts for the report."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from geoscaler.clock import Budget
from geoscaler.color import linear_to_texture
from geoscaler.mesh import TexturedMesh
from geoscaler.methods.registry import (
    LoopFacts,
    MethodOptions,
    MethodResult,
    RunContext,
    output_sizes_for,
)
from geoscaler.optim.loop import METHOD_MEMORY, PLAIN, LoopSetup, Model, OptimizeConfig, optimize
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.process import resident_bytes
from geoscaler.render.renderer import Renderer
from geoscaler.resize.sizes import SizeRule


def method_renderer(mesh: TexturedMesh, options: MethodOptions, context: RunContext) -> Renderer:
    """The job's renderer of ``mesh``, or a protocol one on ``options.device``."""
    return context.renderer or Renderer(mesh, options.device)


def loop_config(
    defaults: Mapping[str, Any], options: MethodOptions, context: RunContext
) -> OptimizeConfig:
    """The loop's settings: the method's ``defaults`` (``steps`` included), overridden by
    ``options.settings["optimize"]``, then by the user's steps, the time left and the seed;
    the memory limit :data:`~geoscaler.optim.loop.METHOD_MEMORY` above what the process holds
    now, unless the settings give one."""
    settings = {**defaults, **options.settings.get("optimize", {})}
    settings["steps"] = options.steps or settings["steps"]
    resident = resident_bytes()
    if resident is not None:
        settings.setdefault("memory_limit", resident + METHOD_MEMORY)
    return OptimizeConfig(time_budget=context.time_budget, seed=options.seed, **settings)


def fit(
    mesh: TexturedMesh,
    rule: SizeRule,
    renderer: Renderer,
    model: Model,
    config: OptimizeConfig,
    context: RunContext,
    started: float,
    setup: LoopSetup = PLAIN,
) -> MethodResult:
    """Optimise ``model`` and return its best validated candidate as 8-bit textures (and UVs).

    Args:
        mesh, rule: the job (``rule`` gives the output sizes).
        renderer: the mesh's renderer.
        model: the candidate's parameters.
        config: the loop's settings.
        context: validation views, controller and progress callback of the job.
        started: the instant of the method's start on ``context.clock`` (its set-up counts).
        setup: how the loop trains (:class:`~geoscaler.optim.loop.LoopSetup`): UVs kept or
            not, an extra loss term, an earlier loop's pool and start scores, its phase.
    """
    validation = context.validation
    if validation is None:
        sizes = output_sizes_for(mesh, rule, renderer)
        validation = Validation(validation_view_sets(renderer), sizes, clock=context.clock)
    result = optimize(
        renderer,
        model,
        config,
        validation,
        setup,
        Budget(context.clock, started, config.time_budget, context.reserve),
        context.on_event,
        context.controller,
    )
    textures = [None if t is None else linear_to_texture(t) for t in result.textures]
    uvs = None if result.uvs is None else result.uvs.detach().cpu().numpy().astype("float32")
    loop = LoopFacts(
        steps=result.steps,
        best_step=result.best_step,
        validation_scores=result.scores,
        clears_floor=result.clears_floor,
        baseline_scores=result.baselines,
        stopped_by=result.stopped_by,
        first_step_seconds=round(result.first_step_seconds, 3),
        training_views=result.training_views,
        validation_views=result.validation_views,
        backtracks=result.backtracks,
    )
    return MethodResult(textures, uvs, device=str(renderer.device),
                        training_renderer=config.training_renderer, loop=loop)  # fmt: skip
