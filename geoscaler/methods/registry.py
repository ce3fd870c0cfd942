"""The registry of downsampling methods: what a method is, what it is handed, what it returns.

A method takes a mesh and a :class:`~geoscaler.resize.sizes.SizeRule` (a scale, a longest side...)
and returns 8-bit textures at the sizes the rule gives (one per textured material) and, if it
moves them, new UVs. Every method starts from the reference maps (:func:`reference_maps`: the
protocol's, originals over 2048 reduced, or a downsampling job's full-resolution originals),
and the rule applies to them (:func:`output_sizes_for`). A *learned* method
optimises through the renderer: it takes steps, a time budget and a run context from the job;
a filter ignores them.

This module imports no method: the package :mod:`geoscaler.methods` imports each method module,
and each registers itself here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from geoscaler.clock import WALL_CLOCK, Clock
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh
from geoscaler.optim.events import Controller, ProgressEvent
from geoscaler.optim.lit import LitFacts
from geoscaler.optim.validation import Validation
from geoscaler.protocol import REFERENCE_MAX_SIZE
from geoscaler.render.renderer import Renderer
from geoscaler.resize.filters import output_sizes, reference_textures
from geoscaler.resize.sizes import SizeRule, check_scale
from geoscaler.uv.atlas import Atlas, AtlasFacts


@dataclass(frozen=True)
class MethodOptions:
    """What the user chose for a method; filters ignore all of it.

    Attributes:
        device: ``"auto"``, ``"cpu"`` or ``"cuda"``.
        seed: random seed; on the CPU the same seed gives the same result (on CUDA, atomic
            additions may change the last bits).
        steps: optimisation steps (None: the method's default).
        time_budget: wall-clock seconds the job may spend (None: no limit).
        settings: method-specific settings, e.g. the network's ``variant``, ``preset`` and
            ``vgg19``, or ``optimize`` (:class:`~geoscaler.optim.loop.OptimizeConfig` overrides).
    """

    device: str = "auto"
    seed: int = 0
    steps: int | None = None
    time_budget: float | None = None
    settings: Mapping[str, Any] = field(default_factory=dict)


@dataclass
class RunContext:
    """What the job hands a method besides its options.

    Attributes:
        renderer: the mesh's renderer, whose ``evaluation`` says the image size, supersampling
            and views (None: the method makes a protocol-1 one on ``options.device``).
        validation: the validation sets with the taps of the output sizes and the job's
            baselines (None: the method makes its own, without baselines).
        controller: pauses or stops the method from another thread.
        on_event: receives the optimisation loop's progress events.
        time_budget: seconds the method may still spend: the job's budget less what the job
            spent before it (None: no limit).
        reserve: seconds of ``time_budget`` the job needs after the method (its export).
        clock: where the method reads the time (its budget, its costs).
        relayout_reserve: seconds the job needs after the method on top of ``reserve`` where
            the result ships a new UV layout (its export re-bakes the other maps into it).
    """

    renderer: Renderer | None = None
    validation: Validation | None = None
    controller: Controller | None = None
    on_event: Callable[[ProgressEvent], None] | None = None
    time_budget: float | None = None
    reserve: float = 0.0
    clock: Clock = WALL_CLOCK
    relayout_reserve: float = 0.0


@dataclass
class LoopFacts:
    """What a learned method's optimisation loop did (the loop's result without its
    candidate; :class:`~geoscaler.optim.loop.OptimizeResult`).

    Attributes:
        steps: steps taken (a race: by every layout's trial and the winner's continuation).
        best_step: the step whose candidate is kept (0: the start).
        validation_scores: set name -> mean PSNR-fg (dB) of the kept candidate.
        clears_floor: the kept candidate is no worse than the best filter on every set.
        baseline_scores: filter name -> its scores per set.
        stopped_by: ``"steps"``, ``"time budget"``, ``"stopped"``, ``"plateau"`` or
            ``"nothing visible to gain"`` (:data:`~geoscaler.optim.loop.NOTHING_TO_GAIN`).
        first_step_seconds: seconds from the method's start to its first step's end (3
            decimals; nan: no step).
        training_views: training views cached; ``validation_views``: set name -> views
            validated on.
        backtracks: times the loop went back to its best candidate.
    """

    steps: int
    best_step: int
    validation_scores: Mapping[str, float]
    clears_floor: bool
    baseline_scores: dict[str, dict[str, float]]
    stopped_by: str
    first_step_seconds: float
    training_views: int
    validation_views: dict[str, int]
    backtracks: int

    @property
    def validation_psnr_fg(self) -> float:
        """The kept candidate's PSNR-fg on Q (dB; nan: none)."""
        return self.validation_scores.get("Q", math.nan)


@dataclass
class TrialFacts:
    """One layout's trial in the race of ``--uv auto``.

    Attributes:
        steps: the trial's steps; ``validation_psnr_fg``: its rank's Q (dB);
        validation_sets: set name -> its mean PSNR-fg; shortfall_db: how far it falls below
        the filters' floor on its worst set (0: it clears it); below_own_on: the sets on which
        it is below the own layout's trial beyond the noise; unfinished: it made fewer steps
        than the first trial (stopped by the budget's end), so it was ranked only if it made
        one at least and already ranked above the first trial.
        start_below: set name -> how far (dB) the layout's start (its bake) validated below
        the best filter there beyond the noise, on the sets where it did (a new layout's
        trial only; None: not measured); gated: it started below on some set, so it had no
        trial (``steps`` 0, the scores its start's).
        training_views: the views its training pool held as it ended (None: no trial).
    """

    steps: int
    validation_psnr_fg: float
    validation_sets: dict[str, float]
    shortfall_db: float
    below_own_on: list[str]
    unfinished: bool = False
    start_below: dict[str, float] | None = None
    gated: bool = False
    training_views: int | None = None


@dataclass
class LayoutFacts:
    """What ``--uv repack`` / ``auto`` did with the UV layout.

    Attributes:
        uv: the mode asked for.
        used: the layout the result is in (``"keep"``, ``"repack"``, ``"unaligned"``).
        planned: the planned new layout's facts (:attr:`Atlas.facts`), None where none was.
        skipped: why no new layout was planned, if none was.
        race: layout -> its trial, where layouts raced.
    """

    uv: str
    used: str = "keep"
    planned: AtlasFacts | None = None
    skipped: str | None = None
    race: dict[str, TrialFacts] | None = None


@dataclass
class NetworkFacts:
    """What the network method ran: its variant, preset, size and perceptual term, and how
    far its UV warp moved the texels (``{"mean", "max"}`` texels; None: no warp)."""

    variant: str
    preset: str
    parameters: int
    perceptual: str
    uv_shift_texels: dict[str, float] | None = None


@dataclass
class Shipping:
    """What the job ships in place of a learned method's own result.

    Attributes:
        shipped: the method's name, or the filter that ships instead.
        shortfall_db: how far the method's own result fell below the filters' floor on its
            worst set (0: it clears it; None: not validated).
        not_run: why the method was not run (the budget could not hold it), if it was not.
        seconds_left: the budget's seconds left when it was not run.
    """

    shipped: str
    shortfall_db: float | None = None
    not_run: str | None = None
    seconds_left: float | None = None


@dataclass
class MethodResult:
    """What a method produced, and its facts for the report (typed; the report turns them
    into JSON).

    Attributes:
        textures: per material, the ``(h, w, C)`` uint8 sRGB texture (None if untextured).
        uvs: float32 new UVs, ``(V, 2)`` per vertex (a warp) or ``(F, 3, 2)`` per face
            corner (a new layout, :attr:`Atlas.uvs`), or None when the method keeps the
            mesh's own; :meth:`TexturedMesh.with_uvs` makes the mesh that ships.
        seconds: wall-clock time of the method (the job adds what it spent for it).
        layout: the new UV layout when the method repacked the charts (``uvs`` are its UVs;
            the export bakes every other map of the repacked materials into it), else None.
        device, training_renderer: where and through what a learned method trained.
        loop: what its loop did; ``layout_facts``: what ``--uv`` did; ``network``: what the
            network method ran.
        shipping: what the job ships for it (set by the job).
        first_step_after_start: seconds from the job's start to the first step's end.
        maps: maps other than the base colours made for the result, ``id(original array) ->
            (array, how it was made)`` (the job's lit stage, :mod:`geoscaler.pipeline.lit`);
            None: every other map by its class.
        lit: what the lit stage did (None: it did not run).
    """

    textures: list[np.ndarray | None]
    uvs: np.ndarray | None = None
    seconds: float = 0.0
    layout: Atlas | None = None
    device: str | None = None
    training_renderer: str | None = None
    loop: LoopFacts | None = None
    layout_facts: LayoutFacts | None = None
    network: NetworkFacts | None = None
    shipping: Shipping | None = None
    first_step_after_start: float | None = None
    maps: dict[int, tuple[np.ndarray, str]] | None = None
    lit: LitFacts | None = None

    def shipped(self, name: str) -> str:
        """What ships for method ``name``: itself, or the filter the job chose instead."""
        return name if self.shipping is None else self.shipping.shipped


Run = Callable[[TexturedMesh, SizeRule, MethodOptions, RunContext], MethodResult]


def reference_maps(mesh: TexturedMesh, renderer: Renderer | None) -> list[np.ndarray | None]:
    """The maps a method starts from: ``renderer``'s (its evaluation's cap), or the
    protocol's without one."""
    return reference_textures(mesh) if renderer is None else renderer.reference_maps()


def output_sizes_for(
    mesh: TexturedMesh, rule: SizeRule, renderer: Renderer | None
) -> list[tuple[int, int] | None]:
    """Per material the ``(h, w)`` a method returns: ``rule`` on :func:`reference_maps`."""
    cap = REFERENCE_MAX_SIZE if renderer is None else renderer.evaluation.reference_max_size
    return output_sizes(mesh, rule, cap)


def as_rule(scale: int | SizeRule) -> SizeRule:
    """A scale (a whole number >= 2) as the rule that divides each side by it."""
    return scale if isinstance(scale, SizeRule) else SizeRule(scale=check_scale(scale))


@dataclass(frozen=True)
class Method:
    """A registered method.

    Attributes:
        name: the name users type (``--method``, ``--methods``).
        run: the implementation.
        learned: optimises through the renderer (steps, budget, progress) or is a filter.
        settings: fixed settings merged into the options (aliases such as ``geoscaler-base``).
        steps: a learned method's default step limit for its settings (None: a filter).
    """

    name: str
    run: Run
    learned: bool
    settings: Mapping[str, Any] = field(default_factory=dict)
    steps: Callable[[Mapping[str, Any]], int] | None = None


_METHODS: dict[str, Method] = {}


def register(
    name: str,
    run: Run,
    *,
    learned: bool,
    settings: Mapping[str, Any] | None = None,
    steps: Callable[[Mapping[str, Any]], int] | None = None,
) -> None:
    """Add a method (or, with ``settings``, an alias that runs ``run`` with them); a learned
    one says with ``steps`` what step limit it runs for given settings when the user sets
    none."""
    _METHODS[name] = Method(name, run, learned, dict(settings or {}), steps)


def unregister(name: str) -> None:
    """Remove a method (e.g. one a test registered); unknown names are ignored."""
    _METHODS.pop(name, None)


def method_names(aliases: bool = True) -> list[str]:
    """Registered names in registration order (without aliases: the methods themselves)."""
    return [name for name, m in _METHODS.items() if aliases or not m.settings]


def get_method(name: str) -> Method:
    """The method called ``name``; an unknown name raises a :class:`GeoscalerError` that lists
    the known ones."""
    if name not in _METHODS:
        known = ", ".join(method_names())
        raise GeoscalerError(f"{name!r}: unknown method; choose one of: {known}")
    return _METHODS[name]


def default_steps(name: str, settings: Mapping[str, Any] | None = None) -> int | None:
    """The step limit method ``name`` runs with ``settings`` when the user gives no
    ``--steps``: ``settings["optimize"]["steps"]`` if set, else the method's own default
    (None for a filter)."""
    method = get_method(name)
    settings = {**(settings or {}), **method.settings}
    override = settings.get("optimize", {}).get("steps")
    if override is not None:
        return int(override)
    return None if method.steps is None else method.steps(settings)


def is_learned(name: str) -> bool:
    """Whether ``name`` optimises (steps, time budget, progress events) or is a filter."""
    return get_method(name).learned


def run_method(
    name: str,
    mesh: TexturedMesh,
    scale: int | SizeRule,
    options: MethodOptions | None = None,
    context: RunContext | None = None,
) -> MethodResult:
    """Run a registered method at ``scale`` (a whole number, or any :class:`SizeRule`) and
    time it, wall clock, set-up included.

    Without a ``context`` the method gets the whole of ``options.time_budget``.
    """
    method = get_method(name)
    options = options or MethodOptions()
    if method.settings:
        options = replace(options, settings={**options.settings, **method.settings})
    context = context or RunContext(time_budget=options.time_budget)
    start = context.clock.now()
    result = method.run(mesh, as_rule(scale), options, context)
    result.seconds = context.clock.now() - start
    return result
