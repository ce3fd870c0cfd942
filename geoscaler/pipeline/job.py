"""One job pipeline: what ``downsample``, ``compare``, ``bench``, ``demo`` and the app all run.

``load -> plan outputs -> cache Q once -> run each method under its budget -> score -> gains
-> export -> report``:

- :class:`_MethodRuns` is the shared core: it checks the job, caches the validation set Q once
  (with the texture taps of the output sizes) and runs the filters and then the learned methods
  (which validate on that same cache, under the budget left) at one scale.
- :func:`compare_mesh` (``compare``, ``bench``) scores every output as it will ship (8-bit,
  alpha re-attached) on all views of the protocol's sets; :func:`compare_on_validation`
  (``downsample``, the app) scores them on the validation's Q views, under the whole job's
  :class:`JobBudget`; both set each row's gain over bicubic.
- :func:`downsample` runs a method beside bicubic and Lanczos on Q;
  :mod:`geoscaler.pipeline.downsampling` checks a job, runs it and writes the asset.

A :class:`JobObserver` watches a job (the CLI's progress bars, the app's live state).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from geoscaler.clock import WALL_CLOCK, Budget, Clock
from geoscaler.errors import GeoscalerError
from geoscaler.io import (
    check_outputs,
    prepare_folder,
)
from geoscaler.mesh import Material, TexturedMesh, check_geometry
from geoscaler.methods import (
    MethodOptions,
    MethodResult,
    RunContext,
    Shipping,
    is_learned,
    run_method,
)
from geoscaler.optim.events import Controller, ProgressEvent
from geoscaler.optim.lit import LitRun, least_seconds_bound
from geoscaler.optim.validation import MIN_FROZEN, Validation, validation_view_sets
from geoscaler.pipeline.arguments import (
    check_distances,
    check_method,
    check_protocol,
    check_rules,
)
from geoscaler.pipeline.lit import LIT_SHARE, lit_stage_applies, lit_stage_price, train_lit
from geoscaler.pipeline.rows import protocol_row, scored_row, validation_row
from geoscaler.pipeline.shipping import (
    EVERY_MAP_FILTERS,
    ShippedMap,
    alpha_cutoff,
    asset_of,
    every_map_by,
)
from geoscaler.protocol import GAIN_REFERENCE, REFERENCE_MAX_SIZE, VALIDATION_DISTANCE
from geoscaler.render.cameras import spread_order, view_set_cameras
from geoscaler.render.lit import default_protocol, lit_scores
from geoscaler.render.metrics import mean_metrics
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, ViewSet
from geoscaler.resize.filters import output_sizes
from geoscaler.resize.maps import resize_alpha
from geoscaler.resize.sizes import SizePlan, SizeRule

REPORT_BASELINES = ("bicubic", "lanczos")
"""Methods a downsampling job always scores beside its result (bicubic is the gain's zero)."""


class JobObserver:
    """Watches a job; each hook does nothing unless a subclass says otherwise."""

    def stage(self, what: str, done: int, total: int) -> None:
        """Coarse progress: ``what`` is running, ``done`` of ``total`` units of it are done."""

    def views_cached(self, distance: float, views: ViewSet) -> None:
        """The view set at ``distance``: Q as the job starts (its views are cached while the
        methods run), the protocol's other sets once cached."""

    def method_started(self, name: str, scale: int | str, time_budget: float | None) -> None:
        """Method ``name`` starts at ``scale`` (a rule's label: 4, or "x4, <= 1024"); a
        learned one has ``time_budget`` seconds."""

    def on_event(self, event: ProgressEvent) -> None:
        """A learned method's optimisation loop reports."""

    def scored(self, row: dict[str, Any]) -> None:
        """A row was scored (without its gain, which comes once bicubic is scored too)."""


@dataclass
class Comparison:
    """What :func:`compare_mesh` measured.

    Attributes:
        rows: one dict per (distance, scale, listed method), keys :data:`ROW_KEYS`; ``scale``
            is the size rule's label (4, or "x4, <= 1024").
        outputs: ``(method, rule label)`` -> the method's result as it ships (bicubic
            included).
        foreground: distance -> ``(N,)`` int64 foreground pixels of each view's reference.
        view_indices: the protocol view indices scored (0..59), the same at every distance.
        device: the torch device the views were rendered on.
        protocol: the protocol of PROTOCOL.md the rows follow (1: unlit base colour; 2: every
            map lit, each method's asset as it ships).
    """

    rows: list[dict[str, Any]]
    outputs: dict[tuple[str, int | str], MethodResult]
    foreground: dict[float, np.ndarray] = field(default_factory=dict)
    view_indices: list[int] = field(default_factory=list)
    device: str = "cpu"
    protocol: int = 1


def checked_output_sizes(
    mesh: TexturedMesh, scale: int | SizeRule, max_size: int | None = REFERENCE_MAX_SIZE
) -> list[tuple[int, int] | None]:
    """:func:`geoscaler.resize.filters.output_sizes` of a scale or rule, refusing a bad scale and a
    mesh with nothing to downsample."""
    (rule,) = check_rules([scale])
    try:
        sizes = output_sizes(mesh, rule, max_size)
    except GeoscalerError as error:
        raise GeoscalerError(f"--scale {rule.label}: {error}") from None
    if all(size is None for size in sizes):
        raise GeoscalerError("the mesh has no base-colour texture; there is nothing to downsample")
    return sizes


def ship_textures(
    textures: Sequence[np.ndarray | None],
    references: Sequence[np.ndarray | None],
    materials: Sequence[Material],
) -> list[np.ndarray | None]:
    """The method's textures as they will be written: where the reference map has alpha and
    the method returned RGB only (learned methods optimise colour), the reference's alpha is
    resized to the texture's size and appended (:func:`geoscaler.resize.maps.resize_alpha`: a
    ``MASK`` material keeps its coverage), so cut-outs survive."""
    shipped: list[np.ndarray | None] = []
    for texture, original, material in zip(textures, references, materials, strict=True):
        if texture is not None and original is not None:
            if texture.shape[2] == 3 and original.shape[2] in (2, 4):
                cutoff = alpha_cutoff(material)
                alpha = resize_alpha(original[..., -1], texture.shape[:2], cutoff)
                texture = np.concatenate([texture, alpha.reshape(*texture.shape[:2], 1)], axis=2)
        shipped.append(texture)
    return shipped


def remaining_budget(budget: float | None, spent: float) -> float | None:
    """What is left of a time budget (None: no budget) after ``spent`` seconds of the job's
    work for the method, such as caching the validation views; kept positive."""
    return None if budget is None else max(budget - spent, 1e-3)


@dataclass(frozen=True)
class JobBudget:
    """A job's wall-clock budget (``downsample``: the command's, from its start).

    Attributes:
        started_at: the instant on the job's clock ``options.time_budget`` counts from.
        reserve: seconds the caller needs after the job's methods and rows (the export).
        relayout: seconds the export needs on top of ``reserve`` where a method's result
            ships a new UV layout (the other maps re-baked into it).
    """

    started_at: float
    reserve: float = 0.0
    relayout: float = 0.0


class _MethodRuns:
    """What both pipelines share: the checked job (mesh, rules, methods, renderer, Q's views)
    and running every method at one scale, the filters first as the learned methods'
    baselines."""

    def __init__(
        self,
        mesh: TexturedMesh,
        scales: Sequence[int | SizeRule],
        methods: Sequence[str],
        options: MethodOptions | None,
        renderer: Renderer | None,
        observer: JobObserver | None,
        controller: Controller | None,
        clock: Clock,
        distances: Sequence[float] = (VALIDATION_DISTANCE,),
        protocol: int = 1,
        plan: SizePlan | None = None,
    ):
        check_geometry(mesh, mesh.source_path or "the mesh")
        self.mesh, self.controller, self.clock = mesh, controller, clock
        self.rules = check_rules(scales)
        self.distances = check_distances(distances)
        self.listed = [check_method(name) for name in methods]
        self.options = options or MethodOptions()
        self.observer = observer or JobObserver()
        listed = self.listed
        self.to_run = listed if GAIN_REFERENCE in listed else [*listed, GAIN_REFERENCE]
        self.renderer = renderer or Renderer(mesh, self.options.device)
        self.protocol = protocol
        self.plan = plan
        if protocol == 2 and self.renderer.evaluation.reference_max_size is not None:
            # protocol 2 compares with the maps as the user has them: no reference cap
            evaluation = replace(self.renderer.evaluation, reference_max_size=None)
            self.renderer = Renderer(mesh, self.renderer.device, evaluation)
        cap = self.renderer.evaluation.reference_max_size
        self.sizes = {rule.label: checked_output_sizes(mesh, rule, cap) for rule in self.rules}
        self.scales = [rule.label for rule in self.rules]
        self.comparison = Comparison([], {}, device=str(self.renderer.device), protocol=protocol)
        self.view_sets = validation_view_sets(self.renderer)
        self.observer.views_cached(VALIDATION_DISTANCE, self.view_sets["Q"])
        indices = self.renderer.evaluation.view_indices
        self.comparison.view_indices = [indices[i] for i in spread_order(len(indices))]
        self.scores: dict[tuple[float, str, int | str], dict[str, Any]] = {}
        # the stages the observer is told of: each method at each scale, run and scored at
        # each distance, and each distance's views
        steps = len(self.scales) * len(self.to_run) * (1 + len(self.distances))
        self.progress = _Stages(self.observer, steps + len(self.distances))

    def run_scale(
        self, rule: SizeRule, scorings_after: int, budget: JobBudget | None
    ) -> tuple[dict[str, MethodResult], Validation]:
        """Every method at ``rule``: the filters, then the learned methods, each validated on
        the job's views under what is left of ``budget`` (None: each its own budget) and
        shipping no worse than the filters (:func:`no_worse_than_filters`)."""
        scale, renderer, clock = rule.label, self.renderer, self.clock
        filters = [name for name in self.to_run if not is_learned(name)]
        outputs: dict[str, MethodResult] = {}
        for name in filters:
            self.progress.step(f"{name} x{scale}")
            context = RunContext(renderer, clock=clock)
            outputs[name] = _run(self.mesh, rule, name, self.options, context, None, self.observer)
        baselines = {name: outputs[name].textures for name in filters}
        validation = Validation(self.view_sets, self.sizes[scale], baselines, scorings_after, clock)
        for name in (name for name in self.to_run if is_learned(name)):
            self.progress.step(f"{name} x{scale}")
            outputs[name] = self._run_learned(rule, name, validation, outputs, budget)
        self.comparison.outputs.update({(name, scale): outputs[name] for name in self.to_run})
        return outputs, validation

    def _run_learned(
        self,
        rule: SizeRule,
        name: str,
        validation: Validation,
        outputs: dict[str, MethodResult],
        budget: JobBudget | None,
    ) -> MethodResult:
        seconds, reserve, clock = self.options.time_budget, 0.0, self.clock
        if budget is not None:
            seconds = remaining_budget(seconds, clock.now() - budget.started_at)
            reserve = budget.reserve
        lit = lit_stage_applies(self.mesh, name, self.protocol)
        if budget is not None:
            self.renderer.reference_textures()  # made once, before a view is priced
            if not learned_fits(validation, seconds, reserve):
                return not_run(name, outputs, seconds)
        lit_seconds, stage, price = 0.0, None, 0.0
        if lit and seconds is not None:
            after = validation.seconds_needed(0, caching=False)  # the stage's budget keeps it
            if budget is not None:
                # learned_fits timed the unlit view of Q's first camera, the one priced lit
                price = least_seconds_bound(validation.view_cost, self.renderer.evaluation)
                if lit_share(seconds, price + after):  # else no lit view is worth pricing
                    began = clock.now()
                    stage = self._lit_stage(rule, outputs)
                    price = stage.priced.least if stage.priced else 0.0
                    seconds -= clock.now() - began  # the stage's first view, cached, is its own
            lit_seconds = lit_share(seconds, price + after)
            if not lit_seconds:  # not held through the method: built again only if time is left
                stage = None
        reserve_after = reserve + lit_seconds  # the lit stage's time follows the method
        # A new layout is not trained lit: its re-bake takes the lit stage's time first.
        relayout = 0.0 if budget is None else max(budget.relayout - lit_seconds, 0.0)
        context = RunContext(self.renderer, validation, self.controller,
                             self.observer.on_event, seconds, reserve_after, clock,
                             relayout)  # fmt: skip
        method_start = clock.now()
        result = _run(self.mesh, rule, name, self.options, context, seconds, self.observer)
        if budget is not None and result.loop is not None:
            first = method_start - budget.started_at + result.loop.first_step_seconds
            result.first_step_after_start = round(first, 3)
        result = no_worse_than_filters(name, result, validation, outputs)
        if lit and result.uvs is None:
            after = validation.seconds_needed(0, caching=False)
            stage_budget = Budget(clock, method_start, seconds, reserve + after)
            what = f"{name} x{rule.label}: lit views, seconds"
            result = train_lit(
                self.mesh, self._plan(rule), name, result, outputs.get("lanczos"), stage_budget,
                str(self.renderer.device), self.options.seed, self.options.steps, self.controller,
                lambda done, total: self.observer.stage(what, done, total),
                self.renderer.evaluation, stage, price,
            )  # fmt: skip
        return result

    def _plan(self, rule: SizeRule) -> SizePlan:
        return self.plan or SizePlan(rule, rule, rule)

    def _lit_stage(self, rule: SizeRule, outputs: dict[str, MethodResult]) -> LitRun:
        """The lit stage at ``rule``, priced (:func:`~geoscaler.pipeline.lit.lit_stage_price`)."""
        device, evaluation = str(self.renderer.device), self.renderer.evaluation
        lanczos, options = outputs.get("lanczos"), self.options
        return lit_stage_price(self.mesh, self._plan(rule), lanczos, self.clock, device,
                               evaluation, options.seed, options.steps)  # fmt: skip

    def finish(self) -> Comparison:
        """The rows with their gains over bicubic, ordered by distance, scale, then the
        listed methods; Q's foreground counts."""
        scores = self.scores
        for (distance, name, scale), row in scores.items():
            reference = scores[distance, GAIN_REFERENCE, scale]["psnr_fg"]
            row["gain_db"] = 0.0 if name == GAIN_REFERENCE else row["psnr_fg"] - reference
        comparison = self.comparison
        comparison.rows = [
            scores[distance, name, scale]
            for distance in self.distances
            for scale in self.scales
            for name in self.listed
        ]
        q = self.view_sets["Q"]
        if len(q):
            counts = q.foreground[: len(q)].sum(dim=(1, 2)).cpu().numpy()
            comparison.foreground.setdefault(VALIDATION_DISTANCE, counts)
        self.progress.done()
        return comparison


def compare_mesh(
    mesh: TexturedMesh,
    scales: Sequence[int | SizeRule],
    methods: Sequence[str],
    distances: Sequence[float] = (VALIDATION_DISTANCE,),
    options: MethodOptions | None = None,
    renderer: Renderer | None = None,
    observer: JobObserver | None = None,
    controller: Controller | None = None,
    clock: Clock = WALL_CLOCK,
    protocol: int | None = None,
) -> Comparison:
    """Run ``methods`` at every scale and score them on all views of the protocol's sets at
    ``distances`` (``compare``, ``bench``).

    The filters run first; they are the *baselines* of the learned methods, which validate on a
    :class:`~geoscaler.optim.validation.Validation` (Q and near/far guards, cached while they
    train) and ship their result only where it clears the best baseline on every validation
    set (:func:`no_worse_than_filters`). Each learned method's ``options.time_budget`` counts
    from its own start.

    Args:
        mesh: the mesh; its textures are the originals.
        scales: whole reduction factors >= 2 (e.g. ``[4, 8]``) or size rules.
        methods: registered method names, in the order rows are wanted; bicubic runs for the
            gains whether listed or not.
        distances: camera distances of the protocol view sets scored (2.4 is Q; 1.5 near,
            4.0 far).
        options: settings of every method; ``options.device`` also renders the views.
        renderer: the mesh's renderer; its ``evaluation`` says the image size and the views
            standing for each set (default: protocol 1 on ``options.device``).
        observer: watches the job.
        controller: pauses or stops the learned methods (their best state so far is kept).
        clock: where the job and its methods read the time.
        protocol: 1 (unlit base colour) or 2 (every map lit: each method's asset as it ships,
            the filters' every map by that filter; references uncapped); None: the mesh's
            default (:func:`geoscaler.render.lit.default_protocol`).

    Returns:
        A :class:`Comparison`; its rows are ordered by distance, scale, then ``methods``.

    Raises:
        GeoscalerError: an unknown method, a bad scale or distance, a scale too large for a
            texture, or a method's own error.
    """
    protocol = default_protocol(mesh) if protocol is None else check_protocol(protocol)
    runs = _MethodRuns(
        mesh, scales, methods, options, renderer, observer, controller, clock, distances, protocol
    )
    for rule in runs.rules:
        runs.run_scale(rule, scorings_after=0, budget=None)
    if protocol == 2:
        _score_lit_sets(runs)
    else:
        _score_protocol_sets(runs)
    return runs.finish()


def compare_on_validation(
    mesh: TexturedMesh,
    scale: int | SizeRule,
    methods: Sequence[str],
    options: MethodOptions | None = None,
    renderer: Renderer | None = None,
    observer: JobObserver | None = None,
    controller: Controller | None = None,
    budget: JobBudget | None = None,
    clock: Clock = WALL_CLOCK,
    protocol: int = 1,
    plan: SizePlan | None = None,
) -> Comparison:
    """Run ``methods`` at ``scale`` and score them on the validation's Q views, the ones the
    shipped result was chosen on (a downsampling job's report, inside its budget).

    As :func:`compare_mesh`, but under the whole job's ``budget`` (None: each learned method's
    own from its start): a learned method gets what is left of it and keeps the reserve and the
    time of the rows' scoring for after it; one that cannot take a step in what is left is not
    run, and its Lanczos start ships (:func:`learned_fits`). Under ``protocol`` 2 ``direct``
    goes on through the lit stage (:mod:`geoscaler.pipeline.lit`) with ``plan``'s sizes for
    every map (None: ``scale``'s); the rows stay unlit (protocol 1's Q), the lit stage's
    scores are in the result's :attr:`~MethodResult.lit`.
    """
    runs = _MethodRuns(mesh, [scale], methods, options, renderer, observer, controller, clock,
                       protocol=protocol, plan=plan)  # fmt: skip
    (rule,) = runs.rules
    outputs, validation = runs.run_scale(rule, len(runs.to_run), budget)
    _cache_for_rows(validation, runs.options.time_budget, budget)
    for name in runs.to_run:
        runs.progress.step(f"scoring {name} x{rule.label}")
        row = validation_row(outputs[name], name, rule.label, validation)
        runs.scores[VALIDATION_DISTANCE, name, rule.label] = row
        runs.observer.scored(row)
    return runs.finish()


class _Stages:
    """Counts the job's stages for :meth:`JobObserver.stage`."""

    def __init__(self, observer: JobObserver, total: int):
        self.observer, self.total, self.count = observer, total, 0

    def step(self, what: str) -> None:
        self.observer.stage(what, self.count, self.total)
        self.count = min(self.count + 1, self.total)

    def done(self) -> None:
        self.observer.stage("done", self.total, self.total)


def lit_share(seconds: float, price: float) -> float:
    """Seconds of a learned method's ``seconds`` kept for the lit stage after it: its
    :data:`~geoscaler.pipeline.lit.LIT_SHARE`, or none where that share cannot hold
    ``price``, the stage's least cost (:func:`~geoscaler.pipeline.lit.lit_stage_price`) and
    what the validation owes after it: the method then has the whole budget, and the stage
    whatever it leaves."""
    share = LIT_SHARE * seconds
    return share if price <= share else 0.0


def learned_fits(validation: Validation, budget: float | None, reserve: float) -> bool:
    """Whether the least a learned method does fits in ``budget`` seconds (None: no budget):
    one view more, then what its loop owes whether or not it steps (its start and a candidate
    validated, the baselines scored, the views the validation still needs, the rows' scoring),
    then ``reserve``. Where this does not fit, the loop could not take a step (it asks
    ``views_per_step`` views and :data:`~geoscaler.optim.loop.FINISH_MARGIN` on the same
    estimate) and would still validate its start, overrunning a short budget.

    Views are priced on one validation view cached here first (the loop would cache it), after
    the reference textures are made, whose cost would otherwise swell that view's. Not the
    loop's test itself: with its margin, short runs that do make steps within their budget
    would not run (see docs/decisions/finish-margin.md)."""
    if budget is None:
        return True
    started = validation.clock.now()
    validation.cache_next()
    left = budget - (validation.clock.now() - started)
    owed = validation.seconds_needed(2, caching=True) + reserve
    return validation.view_cost + owed <= left


def not_run(name: str, filters: dict[str, MethodResult], budget: float) -> MethodResult:
    """What ships for a learned method the budget had no time for (:func:`learned_fits`): the
    filter it starts from (Lanczos; bicubic in a job without it), unvalidated, with the reason
    in its shipping facts."""
    start = "lanczos" if "lanczos" in filters else GAIN_REFERENCE
    reason = (
        f"the time budget ({budget:.1f} s left after loading and the filters) cannot hold "
        f"the validation {name} owes even without a step"
    )
    shipping = Shipping(start, not_run=reason, seconds_left=budget)
    return MethodResult(list(filters[start].textures), shipping=shipping)


def _cache_for_rows(
    validation: Validation, seconds: float | None, budget: JobBudget | None
) -> None:
    """Before the rows of a job whose learned method did not validate (or that has none):
    cache the validation views (all of them, or under the job's budget of ``seconds`` those
    that leave time for the scoring and the reserve). The rows score Q alone, so only Q must
    reach its least views."""
    if validation.frozen:
        return
    least = {"Q": MIN_FROZEN["Q"]}
    if seconds is None or budget is None:
        validation.cache_all()
    else:
        end = budget.started_at + seconds - budget.reserve
        while validation.clock.now() + 2 * validation.seconds_needed(0, True, least=least) < end:
            if not validation.cache_next():
                break
    validation.freeze(least)


def _score_protocol_sets(runs: _MethodRuns) -> None:
    """Score every output on all views of the protocol's sets at the job's distances (Q's
    views are the validation's, completed here)."""
    q, observer = runs.view_sets["Q"], runs.observer
    for distance in runs.distances:
        runs.progress.step(f"rendering the views at {distance:g}")
        if distance == VALIDATION_DISTANCE:
            while q.cache_next():
                observer.stage("caching Q", len(q), len(q.cameras))
            views = q
        else:  # the same directions, in the same order as Q's
            cameras = view_set_cameras(distance, q.renderer.evaluation)
            views = ViewSet(q.renderer, [cameras[i] for i in spread_order(len(cameras))])
        runs.comparison.foreground[distance] = views.foreground.sum(dim=(1, 2)).cpu().numpy()
        if views is not q:  # Q was handed over as the job started
            observer.views_cached(distance, views)
        for scale in runs.scales:
            cache = ViewCache(views, runs.sizes[scale], with_taps=True)
            for name in runs.to_run:
                runs.progress.step(f"scoring {name} x{scale} at {distance:g}")
                output = runs.comparison.outputs[name, scale]
                row = protocol_row(output, name, scale, distance, cache)
                runs.scores[distance, name, scale] = row
                observer.scored(row)


def _score_lit_sets(runs: _MethodRuns) -> None:
    """Protocol 2: every method's asset as it ships (the filters' with every map by that
    filter, :func:`geoscaler.pipeline.shipping.every_map_by`) scored lit on all views of the
    protocol's sets at the job's distances."""
    evaluation, observer = runs.renderer.evaluation, runs.observer
    for distance in runs.distances:
        cameras = view_set_cameras(distance, evaluation)
        cameras = [cameras[i] for i in spread_order(len(cameras))]
        for rule in runs.rules:
            scale, plan = rule.label, SizePlan(rule, rule, rule)
            outputs = [runs.comparison.outputs[name, scale] for name in runs.to_run]
            assets = [
                lit_asset(runs.mesh, name, output, plan)
                for name, output in zip(runs.to_run, outputs, strict=True)
            ]
            what = f"lit views x{scale} at {distance:g}"
            scores, foreground = lit_scores(
                runs.mesh, assets, cameras, runs.renderer.device, evaluation,
                lambda done, total, what=what: observer.stage(what, done, total),
            )  # fmt: skip
            runs.comparison.foreground[distance] = foreground
            for name, output, per_view in zip(runs.to_run, outputs, scores, strict=True):
                runs.progress.step(f"scored {name} x{scale} at {distance:g}")
                metrics = mean_metrics(per_view)
                row = scored_row(output, name, scale, distance, metrics, len(cameras))
                runs.scores[distance, name, scale] = row
                observer.scored(row)


def lit_asset(mesh: TexturedMesh, name: str, result: MethodResult, plan: SizePlan) -> TexturedMesh:
    """The asset protocol 2 scores for method ``name``: box, bicubic and Lanczos in the mesh's
    own layout resize every map (the protocol's baselines); any other method ships its base
    colours (and UVs) with every other map by its class."""
    if name in EVERY_MAP_FILTERS and result.uvs is None:
        return every_map_by(mesh, plan, name)
    return asset_of(mesh, result, plan, name)[0]


def no_worse_than_filters(
    name: str,
    result: MethodResult,
    validation: Validation,
    filters: dict[str, MethodResult],
) -> MethodResult:
    """What a learned method ships: of its result and the filters, the one
    :meth:`Validation.rank` puts first: the learned result wherever it is no worse than the
    best filter on every validation set (Q, near, far), else whichever falls least below that
    floor on its worst set (a learned method starts from Lanczos; a pool cut short or a bad
    run must not ship below the filters the job has).

    Args:
        name: the learned method.
        result: its result, with its loop's facts (a method without them ships as it is).
        validation: the validation sets, frozen, with the filters as baselines.
        filters: filter name -> its result, at the same scale.

    Returns:
        The result to ship, whose :class:`~geoscaler.methods.registry.Shipping` names what
        ships and how far the method's own result fell below the floor.
    """
    if result.loop is None:
        result.shipping = Shipping(name)
        return result
    scores = {name: result.loop.validation_scores, **validation.baseline_scores()}
    best = max(scores, key=lambda candidate: validation.rank(scores[candidate]))
    result.shipping = Shipping(best, shortfall_db=validation.shortfall(scores[name]))
    if best == name:
        return result
    return replace(result, textures=list(filters[best].textures), uvs=None, layout=None)


def _run(
    mesh: TexturedMesh,
    rule: SizeRule,
    name: str,
    options: MethodOptions,
    context: RunContext,
    budget: float | None,
    observer: JobObserver,
) -> MethodResult:
    """Run one method as the job does, in ``context`` (a learned one's: the job's renderer,
    validation and ``budget`` seconds); every output with its alpha re-attached as it will
    ship."""
    observer.method_started(name, rule.label, budget if is_learned(name) else None)
    result = run_method(name, mesh, rule, options, context)
    references = context.renderer.reference_maps()
    result.textures = ship_textures(result.textures, references, mesh.materials)
    return result


def prepare_out_dir(
    out: str | Path, names: Sequence[str], force: bool, inputs: Sequence[Path], probe: bool = True
) -> list[Path]:
    """Check every output file in the folder ``out`` before work. The last check before work
    (``probe``) creates the folder if needed and tries a file in it
    (:func:`geoscaler.io.check_outputs`); an earlier one only looks, and passes a folder that
    does not exist yet, so a command refused in between leaves nothing behind."""
    folder = Path(out)
    paths = [folder / name for name in names]
    if not probe and not folder.exists():
        return paths  # nothing can be in the way in it; the last check creates it
    prepare_folder(folder)
    return check_outputs(paths, force=force, inputs=inputs, probe=probe)


@dataclass
class Downsampled:
    """What :func:`run_job` produced and measured.

    Attributes:
        result: the method's textures as they ship (8-bit, alpha re-attached), UVs, seconds
            (caching of Q included for learned methods) and facts.
        comparison: the rows on Q: the method first, then bicubic and Lanczos, each with its
            ``gain_db`` over bicubic; the outputs (for pictures).
        learned: the method is learned; then ``time_budget`` and ``steps_limit`` are what it
            was given (None: none).
        maps: every texture of the asset as it ships (set by :func:`run_job`).
    """

    result: MethodResult
    comparison: Comparison
    learned: bool = False
    time_budget: float | None = None
    steps_limit: int | None = None
    maps: list[ShippedMap] = field(default_factory=list)

    @property
    def rows(self) -> list[dict[str, Any]]:
        return self.comparison.rows


def downsample(
    mesh: TexturedMesh,
    scale: int | SizeRule,
    method: str,
    options: MethodOptions,
    renderer: Renderer | None = None,
    observer: JobObserver | None = None,
    controller: Controller | None = None,
    budget: JobBudget | None = None,
    clock: Clock = WALL_CLOCK,
    protocol: int = 1,
    plan: SizePlan | None = None,
) -> Downsampled:
    """Run ``method`` on ``mesh`` at ``scale`` (a whole number or a :class:`SizeRule`) and
    score it, bicubic and Lanczos on Q.

    ``budget``, ``clock``, ``protocol``, ``plan``: as :func:`compare_on_validation`
    (``budget`` None: the method's budget counts from its own start).
    """
    methods = [method, *(name for name in REPORT_BASELINES if name != method)]
    comparison = compare_on_validation(
        mesh, scale, methods, options, renderer, observer, controller, budget, clock, protocol, plan
    )
    (rule,) = check_rules([scale])
    result = comparison.outputs[method, rule.label]
    if not is_learned(method):
        return Downsampled(result, comparison)
    return Downsampled(result, comparison, True, options.time_budget, options.steps)
