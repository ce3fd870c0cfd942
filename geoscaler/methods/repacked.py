"""``direct`` in a new UV layout (``--uv repack`` and ``--uv auto``).

The charts are repacked by the texels the training views ask of them
(:func:`geoscaler.uv.atlas.repack`, planned on what every training camera sees), the
reference maps are baked into the new layout (:func:`geoscaler.uv.bake.bake`), and the texels are
optimised through the renderer as ``direct`` does. References are always the original maps on
the original UVs: the new layout has the same faces, in the same order, and every corner its
3D position (UVs are given per face corner, so a cut chart's seam is two UVs of one vertex),
so every G-buffer (and foreground mask) is the original's, and the job's validation views are
shared (:class:`LayoutValidation`). The result carries the new UVs and the :class:`Atlas`,
which the export needs to bake every other map of the repacked materials. ``--uv auto`` races
the two layouts on that shared validation (:func:`raced`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from geoscaler.clock import WALL_CLOCK, Budget, Clock, unlimited
from geoscaler.color import texture_to_linear
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh
from geoscaler.methods.learned import fit, loop_config
from geoscaler.methods.registry import (
    LayoutFacts,
    MethodOptions,
    MethodResult,
    RunContext,
    TrialFacts,
    output_sizes_for,
)
from geoscaler.optim.floor import paired_gap
from geoscaler.optim.loop import (
    CACHING_SHARE,
    FINISH_MARGIN,
    NOTHING_TO_GAIN,
    PLAIN,
    LoopSetup,
    OptimizeConfig,
    Phase,
    nothing_visible_to_gain,
    reaches_memory_limit,
    validate,
)
from geoscaler.optim.validation import (
    Scores,
    Validation,
    sets_below,
    validation_view_sets,
)
from geoscaler.process import release_free_memory
from geoscaler.render.cameras import Camera, sample_training_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, training_views
from geoscaler.resize.sizes import COLOR, SizeRule
from geoscaler.uv.atlas import Atlas, repack
from geoscaler.uv.bake import BAKE_SECONDS_PER_SAMPLE, ChartMaps, bake
from geoscaler.uv.detail import LostDetail, lost_detail
from geoscaler.uv.uvmodes import check_uv_mode

MAX_OVERSAMPLE = 4
"""Most samples per side of a new texel when baking (the original's density at 4x)."""
TRIAL_SHARE = 0.2
"""``--uv auto``: the share of the steps, and of the time left, that each layout's trial gets
before the better one goes on (:func:`raced`)."""
NEW_LAYOUTS = ("repack", "unaligned")
"""The names of the new layouts a race may weigh: the planned one, and where that aligned its
charts to the original's mip blocks, the unaligned one (:func:`_timely_layouts`)."""
SPARSER = "every new layout planned is sparser than the mesh's own where the views look (k below 1)"
"""Why no new layout is weighed where each one planned has ``k`` below 1
(:func:`offered_layouts`)."""
PREPARING_SHARE = 0.4
"""Under a time budget, the share of the time left when planning starts (``--uv auto``: after
the own layout's trial) by which the new layouts are planned and baked, the rest left to the
steps: the packing's search stops there, the cut's plan is not
made where it would end later (:func:`~geoscaler.uv.atlas.repack`), nor the bake where its
estimate would (:func:`bake_seconds`: the mesh's own layout goes on). The first new layout
may take longer, as long as the time left after it still holds its bake and a new layout's
shortest trial that can be ranked (:func:`_planning_deadline`). The trial that runs
before the planning caches its views within the rest of the loop's caching share
(:data:`FIRST_TRIAL_CACHING`)."""
FIRST_TRIAL_CACHING = CACHING_SHARE * (1.0 - PREPARING_SHARE)
"""The caching share of a race's first trial where new layouts are planned after it: the
planning takes its share out of the time the views are cached in, as it did when it came
before the first step, so that a short budget's race does not freeze more validation views
than it can afford (docs/decisions/keep-first-race.md)."""


class LayoutValidation(Validation):
    """The job's validation (its views, frozen counts and baselines) with candidates rendered
    in a new UV layout: the same G-buffers and references, the taps of ``renderer``'s UVs.

    Baselines (filters on the mesh's own UVs) are scored by the job's validation, on the same
    frozen views; freezing either freezes both at the same counts."""

    def __init__(self, base: Validation, renderer: Renderer):
        views = {name: cache.views for name, cache in base.sets.items()}
        super().__init__(views, base.sizes, {}, base.scorings_after, base.clock)
        self.sets = {n: ViewCache(v, base.sizes, True, renderer) for n, v in views.items()}
        self.base = base
        if base.frozen:
            self.counts = dict(base.counts)

    def cache_next(self) -> bool:
        if self.base.frozen:
            self.freeze()
            return False
        return super().cache_next()

    def freeze(self) -> None:
        if self.base.frozen:
            self.counts = dict(self.base.counts)
            return
        super().freeze()
        self.base.freeze()

    def baseline_scores(self) -> dict[str, dict[str, float]]:
        self.freeze()
        return self.base.baseline_scores()

    @property
    def pricing(self) -> Validation:
        """The base until this layout has measured its own unit costs (the same views and
        sizes, the base's baselines)."""
        return self if self._render_seconds else self.base

    def taps_seconds(self, views: int, view_seconds: float = 0.0) -> float:
        """As :meth:`Validation.taps_seconds`, at the base's cost of a view's taps: the views
        themselves are cached already, by the base."""
        return self.base.taps_seconds(views, view_seconds)


PLANNING_VIEWS_SHARE = 0.5
"""Under a time budget, the most of the time left to a plan's deadline that rendering its views
(:class:`PlanningViews`) may take; the rest is the packing's. Views that would take longer are
not rendered on: the plan is not made (a plan whose views took its time was packed too late
and dropped, after taking 1.7 s of a 15 s run on the mug from its steps)."""


class PlanningViews:
    """What every training camera sees, as a plan reads it: per camera the face of each pixel,
    one sample per pixel. Rendered once, shared by the plans made from it (the aligned and the
    unaligned layout see the same views).

    Every camera of the training pool, not a few: charts that few views see are starved
    otherwise (``benchmarks/repack.py --methods bake``; see
    docs/decisions/repack-planning-cameras.md)."""

    def __init__(self, renderer: Renderer, config: Any):
        self.renderer, self.config = renderer, config
        self._tri_ids: list[torch.Tensor] = []
        self._lost: dict[tuple, LostDetail] = {}

    def render_by(self, deadline: float | None = None, clock: Clock = WALL_CLOCK) -> bool:
        """Render the views not yet rendered; whether all are. Under a ``deadline`` (an instant
        on ``clock``), rendering stops as soon as the views left, at the mean time of those
        rendered here, would end after :data:`PLANNING_VIEWS_SHARE` of the time to it."""
        config, renderer = self.config, self.renderer
        cameras = sample_training_cameras(config.pool_views, config.seed, config.distances)
        started, before = clock.now(), len(self._tri_ids)
        for camera in cameras[before:]:
            self._tri_ids.append(renderer.rasterize(camera, renderer.image_size).tri_ids)
            if deadline is None:
                continue
            now, rendered = clock.now(), len(self._tri_ids) - before
            left = len(cameras) - len(self._tri_ids)
            if now + left * (now - started) / rendered > started + PLANNING_VIEWS_SHARE * (
                deadline - started
            ):
                return len(self._tri_ids) == len(cameras)
        return True

    @property
    def tri_ids(self) -> list[torch.Tensor]:
        """Per camera the ``(H, W)`` int tensor of faces (-1: background)."""
        self.render_by()
        return self._tri_ids

    def lost_detail(self, sizes: list) -> LostDetail:
        """What each face's texels lose at the output ``sizes``
        (:func:`~geoscaler.uv.detail.lost_detail`), measured once for the plans that share
        these views."""
        key = tuple(sizes)
        if key not in self._lost:
            renderer = self.renderer
            self._lost[key] = lost_detail(renderer.mesh, renderer.reference_maps(), sizes)
        return self._lost[key]


def plan_layout(
    mesh: TexturedMesh,
    rule: SizeRule,
    renderer: Renderer,
    config: Any,
    budget: Budget | None = None,
    align: bool = True,
    views: PlanningViews | None = None,
) -> Atlas:
    """The new layout for ``rule``'s sizes within ``budget`` (:func:`~geoscaler.uv.atlas.repack`;
    None: no limit), its chart scales from the faces every training camera sees
    (``views``; None: rendered here) and the detail the original's texels lose at those sizes
    (:func:`~geoscaler.uv.detail.lost_detail`); ``align``: False never aligns charts."""
    views = views or PlanningViews(renderer, config)
    sizes = output_sizes_for(mesh, rule, renderer)
    references = renderer.reference_maps()
    detail = [
        None if s is None or r is None else r.shape[0] / s[0]
        for s, r in zip(sizes, references, strict=True)
    ]
    lost = views.lost_detail(sizes)
    return repack(mesh, sizes, views.tri_ids, renderer.resolution, detail, budget, align, lost)


def baked_maps(
    mesh: TexturedMesh, atlas: Atlas, references: list[np.ndarray | None], sizes: list
) -> list[np.ndarray | None]:
    """Per material its reference map baked into the new layout (materials of one group share
    one array), or None for a material that keeps its layout or has no map."""
    out: list[np.ndarray | None] = [None] * len(mesh.materials)
    for group in atlas.groups:
        faces = np.isin(mesh.face_material, group) & (atlas.chart_of_face >= 0)
        layout = ChartMaps(atlas.uvs[faces], atlas.chart_of_face[faces], atlas.linear, atlas.offset)
        size = sizes[group[0]][0]
        reference = references[group[0]]
        pixels, _ = bake(reference, COLOR, layout, size, oversampling(reference, size))
        for material in group:
            out[material] = pixels
    return out


def oversampling(reference: np.ndarray, size: int) -> int:
    """Samples per side of each new texel when ``reference`` is baked at ``size``."""
    return int(np.clip(reference.shape[0] // size, 1, MAX_OVERSAMPLE))


def bake_seconds(sizes: list, references: list[np.ndarray | None]) -> float:
    """An upper bound on :func:`baked_maps`'s seconds on an idle machine (each base-colour
    image baked once): every sample of its grids at
    :data:`~geoscaler.uv.bake.BAKE_SECONDS_PER_SAMPLE`, the price of the export's re-bake of
    the other maps. (A validation view's cost per sample of its frame priced a bake at 0.4 to
    0.8 times its seconds, per sample that sees the mesh at 1.2 to 2.7 times: a view's cost
    follows neither.)"""
    images = {id(r): (r, s[0]) for r, s in zip(references, sizes, strict=True) if r is not None}
    samples = sum((size * oversampling(r, size)) ** 2 for r, size in images.values())
    return samples * BAKE_SECONDS_PER_SAMPLE


@dataclass
class Layout:
    """A UV layout the texels can be optimised in.

    Attributes:
        renderer: renders candidates on this layout's UVs (references as the original).
        validation: the job's validation, candidates rendered on this layout's UVs.
        starts: per material a ``(h, w, 3)`` linear start (the bake), None for Lanczos.
        atlas: the new layout, or None for the mesh's own.
        baked: per material the 8-bit bake whose alpha the result takes (new layout only).
    """

    renderer: Renderer
    validation: Validation
    starts: list[torch.Tensor | None] | None = None
    atlas: Atlas | None = None
    baked: list[np.ndarray | None] = field(default_factory=list)

    def fit(
        self,
        mesh: TexturedMesh,
        rule: SizeRule,
        model: Any,
        config: OptimizeConfig,
        context: RunContext,
        started: float,
        facts: LayoutFacts | None,
        setup: LoopSetup = PLAIN,
    ) -> MethodResult:
        """:func:`geoscaler.methods.learned.fit` in this layout (``setup``: an earlier loop's
        pool and start scores, the race's phase): the result carries the UVs and
        :class:`Atlas` of a new one."""
        context = replace(context, validation=self.validation)
        if self.atlas is not None:
            on_event = _with_layout_uvs(context.on_event, self.renderer.uvs)
            context = replace(context, on_event=on_event)
        result = fit(mesh, rule, self.renderer, model, config, context, started, setup)
        result.layout_facts = facts
        if self.atlas is None:
            return result
        result.uvs = self.atlas.uvs.copy()
        result.layout = self.atlas
        result.textures = _with_alpha(result.textures, self.baked)
        return result


def repacked_direct(
    mesh: TexturedMesh,
    rule: SizeRule,
    options: MethodOptions,
    context: RunContext,
    started: float,
    start_model: Any,
    defaults: dict,
) -> MethodResult:
    """``direct`` in a new layout (``--uv repack``; where two new layouts are planned,
    :func:`_timely_layouts`, their race), or ``--uv auto``'s race of the mesh's own layout and
    the new ones (:func:`raced`).

    Args:
        start_model: ``(mesh, rule, renderer, starts) -> TexelModel`` making free texels from
            per-material linear starts (None: ``direct``'s Lanczos start); the model can be
            restored to a validated candidate (``restore``).
        defaults: ``direct``'s loop settings.
    """
    renderer = context.renderer or Renderer(mesh, options.device)
    config = loop_config(defaults, options, context)
    if config.training_renderer != "exact":
        raise GeoscalerError("--uv repack and auto train through the exact renderer only")
    mode = check_uv_mode(options.settings.get("uv", "keep"))
    memo: dict = {}  # the two layouts share each view (G-buffer, reference)
    sizes = output_sizes_for(mesh, rule, renderer)
    validation = context.validation
    if validation is None:
        validation = Validation(validation_view_sets(renderer), sizes, clock=context.clock)
    facts = LayoutFacts(uv=mode)
    end = _method_end(config, context, started)
    new_end = None if end is None else end - context.relayout_reserve
    own = Layout(renderer.relaid(mesh.uvs, memo), validation)

    def planned(trial_seconds: float | None = None) -> dict[str, Layout]:
        atlases = _timely_layouts(
            mesh, rule, renderer, config, validation, new_end, facts, trial_seconds
        )
        return {
            name: _new_layout(mesh, atlas, renderer, validation, sizes, memo)
            for name, atlas in zip(NEW_LAYOUTS, atlases, strict=False)
        }

    if mode == "auto":
        layouts, later = {"keep": own}, planned
    else:
        layouts, later = planned() or {"keep": own}, None
    return raced(mesh, rule, layouts, start_model, config, context, started, facts, later)


def _new_layout(
    mesh: TexturedMesh,
    atlas: Atlas,
    renderer: Renderer,
    validation: Validation,
    sizes: list,
    memo: dict,
) -> Layout:
    """The :class:`Layout` of ``atlas``, starting from the reference maps baked into it."""
    baked = baked_maps(mesh, atlas, renderer.reference_maps(), sizes)
    linear = {id(b): texture_to_linear(b, renderer.device) for b in baked if b is not None}
    relaid = renderer.relaid(atlas.uvs, memo)
    starts = [None if b is None else linear[id(b)] for b in baked]  # groups share one start
    return Layout(relaid, LayoutValidation(validation, relaid), starts, atlas, baked)


def raced(
    mesh: TexturedMesh,
    rule: SizeRule,
    layouts: dict[str, Layout],
    start_model: Any,
    config: OptimizeConfig,
    context: RunContext,
    started: float,
    facts: LayoutFacts,
    later: Callable[[float], dict[str, Layout]] | None = None,
) -> MethodResult:
    """A trial in each layout (``--uv auto``: the mesh's own and the new ones; ``repack``: the
    new ones, aligned and not), then the one whose trial validates best goes on from its best
    candidate with the steps and the time left.

    ``later(trial_seconds)`` makes more layouts once the trials of ``layouts`` have run
    (``--uv auto``: the new ones are planned and baked after the own layout's trial; a new
    layout's shortest trial that can be ranked takes ``trial_seconds``,
    :meth:`_Trials.least_later`): the first step waits on no planning, and a race that ends
    after that trial (nothing visible left to gain, no step made, stopped) plans nothing (the
    reason in ``facts.skipped``).

    The first trial runs, after what the race pays once (the validation views' caching and
    the baselines' scoring), at most :data:`TRIAL_SHARE` of the time left and that share of
    the steps; the others make as many steps as the first made, bounded only by
    the method's end, so that all are ranked after the same number of steps. A trial that
    could not make them is not ranked, and a first trial of no step (its share of the budget
    spent on caching) ends the race: the first layout goes on alone. Trials are ranked as
    the loop ranks candidates (:meth:`Validation.rank`: the same frozen views and floor in
    every layout; a tie keeps the mesh's own); a new layout whose trial is below the own one's
    on some set is out (:func:`_winner`). The winner's loop goes on from its validated
    best, with its training pool (growing again) and that best's scores as its start's, so
    what ships is never below the better trial on the validation views. The losers' pools
    and validation taps go first: the pool grows within the method's memory limit (the own
    layout's validation is the job's; where anything scores in the mesh's UVs again, its
    taps are found again).
    The winner makes the steps asked, its trial's counted; the losers' trial steps come on top
    (the result's ``steps`` and ``best_step`` count from the race's first step). One layout,
    or fewer steps than layouts (no room for a trial in each): the first goes on alone (the
    mesh's own for ``auto``). A trial that stops with nothing visible left to gain
    (:data:`~geoscaler.optim.loop.NOTHING_TO_GAIN`) ends the race with what it ships.
    A new layout's trial and loop end :attr:`RunContext.relayout_reserve` seconds before the
    method's end: its export re-bakes the other maps.
    """
    trials = len(layouts) + (later is not None)  # at least
    if trials < 2 or config.steps < trials:
        name, layout = next(iter(layouts.items()))
        facts.used = name
        if layout.atlas is not None:
            facts.planned = layout.atlas.facts
        if later is not None:
            facts.skipped = "too few steps for a trial in each layout"
        model = start_model(mesh, rule, layout.renderer, layout.starts)
        context = replace(context, reserve=context.reserve + _relayout_reserve(layout, context))
        return layout.fit(mesh, rule, model, config, context, started, facts)
    end = _method_end(config, context, started)
    cameras = sample_training_cameras(config.pool_views, config.seed, config.distances)
    race = _Trials(config, context, started, end, cameras, planning_follows=later is not None)
    race.run_each(mesh, rule, layouts, start_model)
    if later is not None:
        if race.ended:
            facts.skipped = race.ended
        else:
            layouts = {**layouts, **later(race.least_later(layouts["keep"].validation))}
            race.run_each(mesh, rule, layouts, start_model)
    winner = _winner(race.results, layouts, facts, race.steps_each, race.starts)
    facts.race.update(race.gated)
    first_step = _first_step(race.results.values())
    best, layout, model = race.results[winner], layouts[winner], race.models[winner]
    race.keep_only(winner)
    for name, loser in layouts.items():
        if name != winner:
            loser.validation.drop_taps()
    layouts = {winner: layout}
    release_free_memory()
    best_step = best.loop.best_step
    steps_left = config.steps - best.loop.steps
    relayout = _relayout_reserve(layout, context)
    end = None if end is None else end - relayout
    finishing = FINISH_MARGIN * layout.validation.seconds_needed(2, False)
    no_time = end is not None and context.clock.now() + finishing >= end
    if _stopped(context) or steps_left < 1 or no_time or race.nothing_to_gain:
        best.loop = replace(best.loop, steps=race.steps, first_step_seconds=first_step)
        best.layout_facts = facts
        return best
    device = layout.renderer.device
    model.restore(
        [None if t is None else texture_to_linear(t[..., :3], device) for t in best.textures]
    )
    pool = race.pools[winner]
    pool.views.cameras = list(cameras)  # the trial's loop stopped the pool's growth
    total = replace(config, steps=race.steps + steps_left)  # the losers' trials on top
    phase = _Phase(total, context, started, race.steps, first=False, last=True)
    scores = best.loop.validation_scores
    result = phase.fit(
        mesh,
        rule,
        layout,
        model,
        end,
        context.reserve + relayout,
        steps_left,
        facts,
        pool=pool,
        start_scores=scores,
    )
    loop = result.loop
    result.loop = replace(
        loop,
        steps=loop.steps + race.steps,
        best_step=loop.best_step or best_step,  # 0: its start, the trial's best
        first_step_seconds=_first_step([*race.results.values(), result]),
    )
    return result


def _first_step(results: Iterable[MethodResult]) -> float:
    """Seconds from the method's start to the race's first step: the earliest first step of
    ``results`` (nan: none made a step)."""
    made = [r.loop.first_step_seconds for r in results if not math.isnan(r.loop.first_step_seconds)]
    return min(made, default=math.nan)


def _timely_layouts(
    mesh: TexturedMesh,
    rule: SizeRule,
    renderer: Renderer,
    config: OptimizeConfig,
    validation: Validation,
    end: float | None,
    facts: LayoutFacts,
    trial_seconds: float | None = None,
) -> list[Atlas]:
    """The new layouts (:func:`offered_layouts`), planned and baked by :data:`PREPARING_SHARE`
    of the time from now to ``end`` (None: no budget), the first one by the time that still
    holds its bake and a trial of ``trial_seconds`` if that is later (:func:`_planning_deadline`).
    Each bake is priced first (:func:`bake_seconds`), so each plan's deadline leaves the bakes
    their time."""
    clock = validation.clock
    planned_by, first_by, baking = _planning_deadline(
        mesh, rule, renderer, clock, end, trial_seconds
    )
    return offered_layouts(mesh, rule, renderer, config, facts, clock, planned_by, baking, first_by)


def offered_layouts(
    mesh: TexturedMesh,
    rule: SizeRule,
    renderer: Renderer,
    config: OptimizeConfig,
    facts: LayoutFacts,
    clock: Clock = WALL_CLOCK,
    planned_by: float | None = None,
    baking: float = 0.0,
    first_by: float | None = None,
) -> list[Atlas]:
    """The new layouts a race may weigh (:data:`NEW_LAYOUTS`): the planned one, and where that
    aligned its charts to the original's mip blocks (:func:`~geoscaler.uv.atlas.alignment_for`)
    the unaligned one too, time allowing. A layout sparser than the mesh's own where the views
    look (``k`` below 1; an aligned one's scales are powers of two of the original's, rounded
    down) is not weighed: its bake starts below the filters in the own layout, which the race's
    gate then finds, after its bake and its start's validation
    (docs/decisions/keep-first-race.md, "The starts on the development set"). None where the
    layout does not move a chart, every plan is sparser, or there is no time for it (the reason
    in ``facts.skipped``; under a deadline a plan whose views would take more than
    :data:`PLANNING_VIEWS_SHARE` of its time is not made). The first one's facts go in
    ``facts.planned``.

    Args:
        planned_by: the instant on ``clock`` the first plan must be done by (None: no limit);
            each later one by ``baking`` seconds (a bake's estimate) earlier.
        first_by: a later instant for the first plan (None: ``planned_by``).
    """
    atlases: list[Atlas] = []
    views = PlanningViews(renderer, config)
    sparser = False
    for align in (True, False):
        deadline = _plan_deadline(planned_by, first_by, baking, len(atlases))
        if deadline is not None and clock.now() >= deadline:
            break
        if deadline is not None and not views.render_by(deadline, clock):
            break  # the views would leave the packing too little of the time
        budget = None if deadline is None else unlimited(clock).until(deadline)
        atlas = plan_layout(mesh, rule, renderer, config, budget, align, views)
        if align or not atlases:
            facts.planned = atlas.facts
        if not atlas.moved:
            return atlases
        sparser = atlas.facts.k < 1.0
        if not sparser and (deadline is None or clock.now() <= deadline):
            atlases.append(atlas)
        if not atlas.aligned:
            break
    if not atlases:
        facts.skipped = (
            SPARSER if sparser else "the time budget left no time to plan and bake a new layout"
        )
    return atlases


def _plan_deadline(
    planned_by: float | None, first_by: float | None, baking: float, made: int
) -> float | None:
    """The instant the plan after ``made`` others must be done by (:func:`offered_layouts`'s
    arguments; None: no limit)."""
    if planned_by is None:
        return None
    deadline = planned_by - made * baking
    return deadline if first_by is None or made else max(first_by, deadline)


def _planning_deadline(
    mesh: TexturedMesh,
    rule: SizeRule,
    renderer: Renderer,
    clock: Clock,
    end: float | None,
    trial_seconds: float | None = None,
) -> tuple[float | None, float | None, float]:
    """``(instant the plans must be done by, a later one for the first plan or None, seconds a
    bake takes)`` (None, None and 0 without a budget; the bake priced by :func:`bake_seconds`).

    The plans are done by :data:`PREPARING_SHARE` of the time left, less the bake. Where a
    new layout's shortest trial that can be ranked takes ``trial_seconds``
    (:meth:`_Trials.least_later`), the first plan may end as late as the time left to ``end``
    still holds its bake and that trial: the race needs no more to weigh it. On a short
    budget the share alone left the planning less than it takes (gso_chefmate_8_frypan and bob
    at 4x and 15 s; bob: 0.7 to 1.0 s where its planning views take 0.9 s and its packing
    0.8 s), and so did a trial as long as the own layout's, its views' caching included (bob
    at 8x and 15 s; see docs/decisions/keep-first-race.md)."""
    if end is None:
        return None, None, 0.0
    sizes = output_sizes_for(mesh, rule, renderer)
    baking = bake_seconds(sizes, renderer.reference_maps())
    now = clock.now()
    first_by = None if trial_seconds is None else end - trial_seconds - baking
    return now + PREPARING_SHARE * (end - now) - baking, first_by, baking


def _relayout_reserve(layout: Layout, context: RunContext) -> float:
    """Seconds the job's export needs after the method on top of its reserve where ``layout``
    ships: a new layout's re-bake of the other maps (:attr:`RunContext.relayout_reserve`)."""
    return 0.0 if layout.atlas is None else context.relayout_reserve


def _method_end(config: OptimizeConfig, context: RunContext, started: float) -> float | None:
    """When the method must be done (an instant on ``context.clock``; None: no budget): its budget
    from ``started``, less the job's ``reserve`` after it."""
    if config.time_budget is None:
        return None
    return started + config.time_budget - context.reserve


class _Trials:
    """:func:`raced`'s trials, one layout after the other, and what they leave: each one's
    result, model and training pool, and the steps made in all."""

    def __init__(
        self,
        config: OptimizeConfig,
        context: RunContext,
        started: float,
        end: float | None,
        cameras: list[Camera],
        planning_follows: bool = False,
    ):
        """``planning_follows``: more layouts are planned after the first trial."""
        self.config, self.context, self.started, self.end = config, context, started, end
        self.cameras, self.planning_follows = cameras, planning_follows
        self.steps_each = max(1, round(TRIAL_SHARE * config.steps))
        self.results: dict[str, MethodResult] = {}
        self.models: dict[str, Any] = {}
        self.pools: dict[str, ViewCache] = {}
        self.validations: dict[str, Validation] = {}
        self.starts: dict[str, dict[str, float]] = {}
        self.gated: dict[str, TrialFacts] = {}
        self.steps = 0

    def run_each(
        self, mesh: TexturedMesh, rule: SizeRule, layouts: dict[str, Layout], start_model: Any
    ) -> None:
        """The trials of the ``layouts`` not yet run, in order, while the race goes on
        (:attr:`ended`) and the steps asked leave room for one more."""
        for name, layout in layouts.items():
            if name in self.results or name in self.gated:
                continue
            if self.results and (self.ended or self.steps + self.steps_each > self.config.steps):
                return
            model = start_model(mesh, rule, layout.renderer, layout.starts)
            self.run(mesh, rule, name, layout, model)

    def keep_only(self, winner: str) -> None:
        """Forget every other layout's model and training pool (their taps). The trials fill
        the method's memory limit between them, and the winner's pool grows only while the
        process's resident size (freed memory kept included) stays below it: what the losers
        held is given back for it (:func:`raced` trims the freed memory)."""
        self.models = {winner: self.models[winner]}
        self.pools = {winner: self.pools[winner]}

    @property
    def ended(self) -> str | None:
        """Why no further trial runs (None: the race goes on)."""
        if _stopped(self.context):
            return "stopped"
        if self.nothing_to_gain:
            return "a filter already validates beyond what is visible"
        if self.results and self.steps_each == 0:
            return "the first trial made no step in its share of the time"
        return None

    def run(
        self, mesh: TexturedMesh, rule: SizeRule, name: str, layout: Layout, model: Any
    ) -> None:
        """The trial of ``layout`` from ``model``: the first one, within its share of the time,
        sets the step count of the others to the steps it made; they run to the method's end at
        most. A trial after the first finds its layout's taps in the validation views (frozen
        by the first) before its time starts: that is the layout's cost, not its steps'.
        After the mesh's own layout's trial, a new layout whose start validates below the
        best filter on some set beyond the noise (:func:`start_below`) gets no trial
        (:attr:`gated`): the own layout's trial gained on every set from a start at the filters
        (Lanczos), so such a trial would have to out-learn it there, which no trial on the
        development set did (docs/decisions/keep-first-race.md)."""
        first = not self.results
        handover: dict[str, Any] = {}
        if not first:
            layout.validation.find_taps()
            if "keep" in self.results:
                with torch.no_grad():
                    start = validate(layout.validation, model.candidate())
                self.starts[name] = below = start_below(layout.validation, start)
                if below:
                    self.gated[name] = _gated_facts(layout.validation, start, below)
                    layout.validation.drop_taps()  # no trial: the memory is the others'
                    return
                handover["start_scores"] = start
            self._room_for_a_pool()
        deadline = self._first_deadline(layout.validation) if first else self.end
        if deadline is not None:  # a new layout's re-bake of the other maps follows
            deadline = min(deadline, self.end - _relayout_reserve(layout, self.context))
        if first and self.planning_follows:
            handover["caching_share"] = FIRST_TRIAL_CACHING
            handover["room_for_a_pool"] = True
        phase = _Phase(self.config, self.context, self.started, self.steps, first, last=False)
        pool = training_views(layout.renderer, self.cameras, layout.validation.sizes, True)
        result = phase.fit(
            mesh, rule, layout, model, deadline, 0.0, self.steps_each, pool=pool, **handover
        )
        if first and self.planning_follows and self._invisible(layout.validation, result):
            result.loop = replace(result.loop, stopped_by=NOTHING_TO_GAIN)
        self.results[name], self.models[name], self.pools[name] = result, model, pool
        self.validations[name] = layout.validation
        self.steps += result.loop.steps
        if first:
            self.steps_each = result.loop.steps

    def _room_for_a_pool(self) -> None:
        """Where the process could not hold one more training pool as large as the earlier
        trials' under the method's memory limit, forget their taps, and where that leaves no
        room either, the taps of their validations too (each found again where its layout
        goes on, and priced by :meth:`Validation.seconds_needed` meanwhile). The trials share
        the training cameras and validation views and, through the renderers' memo, their
        G-buffers, so what a layout adds is its taps: each trial then holds one layout's
        taps, as the first did, and trains on as many views. At the limit a later trial's
        pool stopped at the views every loop owes (bob at 8x and 60 s: 4 against the first
        trial's 14; ycb_banana: 4 against 20, its validation's taps beside the first's)."""
        limit = self.config.memory_limit
        if limit is None:
            return
        pools = sum(pool.nbytes for pool in self.pools.values())
        for caches in (self.pools.values(), self.validations.values()):
            if caches and reaches_memory_limit(limit, pools):
                for cache in caches:
                    cache.drop_taps()
                release_free_memory()

    def least_later(self, validation: Validation) -> float:
        """Seconds a later trial takes at least to be ranked (:func:`_ranked`), with the loop's
        :data:`~geoscaler.optim.loop.FINISH_MARGIN`: its taps in the first trial's
        ``validation`` views and in one step's training views
        (:meth:`Validation.taps_seconds`), and three validations: its start's, one after a
        step, and the step (the forward and backward passes of ``views_per_step`` views, about
        one validation's renders in the nine or more views it has)."""
        views = validation.num_views + self.config.views_per_step
        taps = validation.taps_seconds(views)
        return FINISH_MARGIN * (validation.seconds_needed(3, False) + taps)

    def _invisible(self, validation: Validation, first: MethodResult) -> bool:
        """Whether the first trial ended with its validation showing a filter beyond what is
        visible, where its loop did not look (the least views came with its last caching):
        the race then plans no layout for a gain no one could see."""
        if not self.config.finish_when_invisible or first.loop.stopped_by == NOTHING_TO_GAIN:
            return False
        return bool(nothing_visible_to_gain(validation))

    def _first_deadline(self, validation: Validation) -> float | None:
        """When the first trial ends (None: no budget): after what the race pays once, whatever
        the layouts, :data:`TRIAL_SHARE` of the time left after it, but never less than the
        trial's own least (the training views of one full step and the two validations every
        loop owes, priced as the loop prices them). Paid once: the validation views still to
        cache before they freeze and the baselines' scoring
        (:meth:`~geoscaler.optim.validation.Validation.seconds_needed`, with the loop's
        :data:`~geoscaler.optim.loop.FINISH_MARGIN`). A share that had to pay them too, or
        that could not hold a step, left a short budget's first trial no step: its loop then
        spent the race's time caching validation views."""
        if self.end is None:
            return None
        now, view = self.context.clock.now(), validation.view_cost
        once = FINISH_MARGIN * validation.seconds_needed(0, True, view)
        owed = FINISH_MARGIN * validation.seconds_needed(2, True, view) - once
        least = self.config.views_per_step * view + owed
        share = max(TRIAL_SHARE * max(self.end - now - once, 0.0), least)
        return min(now + once + share, self.end)

    @property
    def nothing_to_gain(self) -> bool:
        """A trial stopped because a filter already validates beyond what is visible: the race
        ends there, with what that trial ships."""
        return any(r.loop.stopped_by == NOTHING_TO_GAIN for r in self.results.values())


def start_below(validation: Validation, start: Scores) -> dict[str, float]:
    """Set name -> how far (dB) ``start`` validates below the best filter there beyond the
    noise (:func:`~geoscaler.optim.floor.paired_gap` of the filter over it), on the sets where
    it does."""
    floor = validation.floor()
    gaps = {name: paired_gap(best, start, name) for name, best in floor.items()}
    return {name: round(gap, 4) for name, gap in gaps.items() if gap > 0}


def _gated_facts(validation: Validation, start: Scores, below: dict[str, float]) -> TrialFacts:
    """The facts of a layout that had no trial, its start below a filter."""
    rank = validation.rank(start)
    return _trial_facts(start, rank, 0, below_own_on=[], start_below=below, gated=True)


def _trial_facts(
    scores: Scores, rank: tuple[float, float], steps: int, **verdict: Any
) -> TrialFacts:
    """A trial's :class:`TrialFacts`: its ``scores`` per set and its ``rank``
    (:meth:`Validation.rank`) after ``steps``, rounded as the report shows them, with
    ``verdict``, the race's other facts of it."""
    shortfall, q = rank
    return TrialFacts(
        steps=steps,
        validation_psnr_fg=round(q, 4),
        validation_sets={name: round(value, 4) for name, value in scores.items()},
        shortfall_db=round(shortfall, 4),
        **verdict,
    )


def _winner(
    trials: dict[str, MethodResult],
    layouts: dict[str, Layout],
    facts: LayoutFacts,
    steps_each: int,
    starts: Mapping[str, dict[str, float]] | None = None,
) -> str:
    """The layout whose trial ranks first on the validation (a tie keeps the mesh's own) among
    those that made ``steps_each`` steps and are not below the mesh's own layout's trial on any
    set beyond the noise (:func:`~geoscaler.optim.validation.sets_below`): a new layout better
    on Q but worse far away does not replace the own one. The first trial always counts (it
    set ``steps_each``). Each trial's facts go into ``facts.race``, with how far below a
    filter its start validated where ``starts`` measured it (:func:`start_below`)."""
    starts = starts or {}
    scores = {name: trial.loop.validation_scores for name, trial in trials.items()}
    ranks = {name: layouts[name].validation.rank(scores[name]) for name in trials}
    own = scores.get("keep")
    below = {n: [] if own is None or n == "keep" else sets_below(scores[n], own) for n in trials}
    facts.race = {
        name: _trial_facts(
            scores[name],
            ranks[name],
            trial.loop.steps,
            below_own_on=below[name],
            unfinished=trial.loop.steps < steps_each,
            start_below=starts.get(name),
            training_views=trial.loop.training_views,
        )
        for name, trial in trials.items()
    }
    first = next(iter(trials))
    eligible = [
        name
        for name in ranks
        if name == first
        or (not below[name] and _ranked(facts.race[name], ranks[name], ranks[first]))
    ]
    winner = max(eligible, key=lambda name: (ranks[name], name == "keep"))
    facts.used = winner
    if layouts[winner].atlas is not None:
        facts.planned = layouts[winner].atlas.facts
    return winner


def _ranked(
    trial: TrialFacts, rank: tuple[float, float], first_rank: tuple[float, float]
) -> bool:
    """Whether a later trial is ranked: one that made the first trial's steps, or one that made
    fewer (the budget ended it), at least one, and already ranks above the first. A loop keeps
    its best candidate, so its validated best only rises with more steps: fewer steps can
    understate a layout, never overstate it, and a shorter trial that wins would win the
    full one too."""
    if not trial.unfinished:
        return True
    return trial.steps >= 1 and rank > first_rank


def _stopped(context: RunContext) -> bool:
    return context.controller is not None and context.controller.stopped


@dataclass
class _Phase:
    """One phase of :func:`raced`: a loop whose steps and events continue the race's
    (:class:`~geoscaler.optim.loop.Phase`).

    Attributes:
        config, context, started: the method's loop settings, context and start.
        steps_before: steps the race made before this phase.
        first: the first phase counts its budget from the method's start (its views are cached
            in the run's caching window, up to its own end) and reports the caching; later ones
            count from their own start.
        last: the phase that ends the race (it reports the end).
    """

    config: OptimizeConfig
    context: RunContext
    started: float
    steps_before: int
    first: bool
    last: bool

    def fit(
        self,
        mesh: TexturedMesh,
        rule: SizeRule,
        layout: Layout,
        model: Any,
        loop_end: float | None,
        reserve: float,
        steps: int,
        facts: LayoutFacts | None = None,
        **handover: Any,
    ) -> MethodResult:
        """:meth:`Layout.fit` for at most ``steps`` steps, its loop ending by ``loop_end``
        (an instant on the context's clock; None: no budget) with ``reserve`` seconds after it;
        its events and ``best_step`` counted on from the race's steps (0: its start)."""
        now = self.context.clock.now()
        start = self.started if self.first else now
        config = replace(self.config, steps=steps)
        if loop_end is not None:
            if self.first:
                reserve = self.started + self.config.time_budget - loop_end
            else:
                config = replace(config, time_budget=loop_end + reserve - now)
        context = replace(self.context, reserve=reserve)
        phase = Phase(self.steps_before, self.config.steps, self.started, self.first, self.last)
        setup = LoopSetup(phase=phase, **handover)
        result = layout.fit(mesh, rule, model, config, context, start, facts, setup)
        if not self.first:  # its loop timed its first step from its own start
            since = round(result.loop.first_step_seconds + (start - self.started), 3)
            result.loop = replace(result.loop, first_step_seconds=since)
        return result


def _with_layout_uvs(on_event: Any, uvs: torch.Tensor) -> Any:
    """``on_event`` whose events' live candidates carry the new layout's UVs (the loop's model
    renders on its renderer's own UVs and says None), so an observer such as the app shows
    them as they are."""
    if on_event is None:
        return None

    def forward(event: Any) -> None:
        if event.candidate is not None:
            inner = event.candidate
            event = replace(event, candidate=lambda: (inner()[0], uvs.detach().clone()))
        on_event(event)

    return forward


def _with_alpha(
    textures: list[np.ndarray | None], baked: list[np.ndarray | None]
) -> list[np.ndarray | None]:
    """Each optimised RGB texture with the baked map's alpha (in the new layout) appended
    where the baked map has one: the job re-attaches the original's alpha only to textures
    without one, and that alpha is in the old layout."""
    out = []
    for texture, source in zip(textures, baked, strict=True):
        if texture is not None and source is not None and source.shape[2] in (2, 4):
            texture = np.concatenate([texture[..., :3], source[..., -1:]], axis=2)
        out.append(texture)
    return out
