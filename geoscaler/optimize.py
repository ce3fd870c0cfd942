"""The per-mesh optimisation loop that every learned method shares.

A *model* produces the candidate: linear-light textures (one per material, None where the
material is untextured) and optionally new UVs. The loop renders K random training views of
the candidate through the protocol renderer (or the paper's soft rasteriser, candidate and
original alike: ``training_renderer="soft"``), compares them with renders of the original
(L2 plus a weighted 1 - SSIM on the sRGB images, foreground only), and steps AdamW with a
warm-up and cosine decay. It validates the candidate as it ships (gutters filled, 8-bit) on
a :class:`~geoscaler.validation.Validation` (Q and near/far guards) and keeps the best state
that clears the filters' floor on every set (with ``backtrack``, a candidate that validates
worse than the best sends the model back to the best at a lower learning rate). It stops at a
step count, a wall-clock budget or a plateau, and reports progress events that the CLI's
progress bar and the desktop app consume.

Views are cached while the loop trains: the first step waits for ``views_per_step`` training
views only; the rest of the training pool and the validation views are cached between steps,
:data:`CACHED_PER_STEP` after each step until they are all there. Under a budget the
pool stops growing and the validation sets freeze once :data:`CACHING_SHARE` of it is spent,
and the loop stops early enough for what must follow: the validations still owed and the
caller's own scoring and export (``reserve``).

Gutters are filled from the UV layout alone (:func:`geoscaler.uvmaps.reachable_texels`), so
what ships never depends on which views the machine managed to cache.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import torch

from geoscaler.adamw import AdamW
from geoscaler.cameras import Camera, sample_training_cameras
from geoscaler.events import Controller, ProgressEvent
from geoscaler.losses import PerceptualTerm, view_loss
from geoscaler.majorize import Sloped, majorized_step
from geoscaler.protocol import RANGE_S
from geoscaler.render import Renderer
from geoscaler.schedule import Schedule
from geoscaler.soft import SoftSettings
from geoscaler.texture import fill_gutters, quantize_linear
from geoscaler.uvmaps import reachable_masks
from geoscaler.validation import Best as _Best
from geoscaler.validation import Scores, Validation, ViewCost
from geoscaler.views import ViewCache, ViewSet, mip_chains, training_views

WIDE_RANGE = (1.5, 4.2)
"""Distances wider than the protocol's range S on both sides: from the near robustness set
(1.5, magnified texels) to the far one (4.0, where coarser mip levels of the candidate show)."""
TRAINING_RANGES = (RANGE_S, WIDE_RANGE)
"""The loop's default training distances: views taken in turn from range S, where Q is measured,
and from :data:`WIDE_RANGE`, so that the texture is not sharpened for one distance at the cost
of another (``benchmarks/budget.py --loop``; see docs/decisions/training-distance-ranges.md)."""
FINISH_MARGIN = 1.5
"""Factor on the estimate of what must follow the loop (the validations still owed and the
views they need; the caller's ``reserve`` is added as it is), checked before every step, the
first included: the estimate is rough, and a single step squeezed into a short budget gains
little and can overrun it (``benchmarks/budget.py``; see docs/decisions/finish-margin.md)."""
CACHING_SHARE = 0.4
"""Under a time budget, views are cached within this share of it: then the training pool stops
growing and the validation sets freeze at what is cached."""
CACHED_PER_STEP = 2
"""Views cached after each step while some are missing: a count, not a time share, so that a
run without a budget is the same on every machine."""


class Model(Protocol):
    """What the loop optimises."""

    def parameters(self) -> Sequence[torch.Tensor]: ...

    def candidate(self) -> tuple[list[torch.Tensor | None], torch.Tensor | None]:
        """``(textures, uvs)``: per material ``(h, w, 3)`` linear texture or None, and
        ``(V, 2)`` UVs or None to keep the mesh's own."""
        ...

    def project(self) -> None:
        """Called after each step to keep parameters valid (e.g. texels in [0, 1])."""
        ...


class Restorable(Model, Protocol):
    """A model that can be set back to a validated candidate (what backtracking needs)."""

    def restore(self, textures: Sequence[torch.Tensor | None]) -> None:
        """Set the parameters so that the candidate's textures are ``textures`` (linear)."""
        ...


@dataclass
class OptimizeConfig:
    """Settings of the loop.

    Attributes:
        steps: maximum optimisation steps.
        time_budget: wall-clock seconds for everything, cache building included (None: none).
        views_per_step: K training views rendered per step.
        pool_views: training cameras cached up front, drawn from ``distances``.
        distances: camera distance range of the training views, or several ranges taken in
            turn (:func:`~geoscaler.cameras.sample_training_cameras`).
        lr: peak learning rate; warm-up over ``warmup_steps``, then cosine decay to 0.
        short_run_boost: at most this factor on the learning rate when the time budget allows
            fewer steps than ``steps`` (1: none; :meth:`Schedule.boost`).
        backtrack: with a factor f (< 1), a validated candidate that ranks below the best so
            far sends the model back to the best (``Restorable.restore``), multiplies the
            learning rate by f and validates again after ``validate_every * f`` steps; with
            it the candidate is also validated as the validation sets freeze, so that a step
            size that hurts is found early (None: no backtracking).
        majorized_steps: the first steps are majorise-minimise steps
            (:func:`geoscaler.majorize.majorized_step`), where the model is
            :class:`~geoscaler.majorize.Sloped` and the loss the plain L2 on cached taps;
            AdamW takes the rest.
        weight_decay: AdamW weight decay.
        ssim_weight: weight of ``1 - SSIM`` beside the L2 term.
        loss_in_db: the step minimises the mean of its views' ``10 log10(loss)`` (each view's
            loss relative to itself, as the validation's per-view PSNR gains weigh views)
            instead of the mean loss (where views with large errors, close ones, dominate).
        validate_every: steps between validations on Q (the last step always validates).
        patience: validations without improvement before stopping (None: never).
        seed: seeds the cameras and the view order.
        training_renderer: what renders the training views, candidate and original alike:
            ``"exact"`` (the protocol renderer) or ``"soft"`` (the paper's soft rasteriser,
            :mod:`geoscaler.soft`, with ``soft`` settings). Validation is always exact.
    """

    steps: int = 400
    time_budget: float | None = None
    views_per_step: int = 4
    pool_views: int = 48
    distances: tuple[float, float] | tuple[tuple[float, float], ...] = TRAINING_RANGES
    lr: float = 0.02
    short_run_boost: float = 1.0
    backtrack: float | None = None
    majorized_steps: int = 0
    weight_decay: float = 0.0
    warmup_steps: int = 10
    ssim_weight: float = 0.1
    loss_in_db: bool = False
    validate_every: int = 50
    patience: int | None = None
    seed: int = 0
    training_renderer: str = "exact"
    soft: SoftSettings = field(default_factory=SoftSettings)

    def __post_init__(self) -> None:
        if self.training_renderer not in ("exact", "soft"):
            raise ValueError(f"training_renderer: exact or soft, not {self.training_renderer!r}")

    @property
    def schedule(self) -> Schedule:
        """The learning rate's schedule of these settings."""
        return Schedule(self.steps, self.warmup_steps, self.time_budget, self.short_run_boost)


@dataclass
class OptimizeResult:
    """The best validated candidate, finished as it ships (:func:`finish`), and how the run
    went.

    Attributes:
        textures, uvs: the candidate (linear textures, gutters filled; UVs or None).
        steps: steps taken; ``best_step`` the step of the candidate (0: the start).
        scores: the candidate's validation PSNR-fg per set; ``best_psnr`` is Q's.
        clears_floor: the candidate is no worse than the best baseline on every set.
        shortfall: dB (<= 0) it falls below the best baseline on its worst set.
        baselines: baseline name -> its validation PSNR-fg per set.
        stopped_by: ``"steps"``, ``"time budget"``, ``"plateau"`` or ``"stopped"``.
        seconds: wall time from the start the budget counts from.
        first_step_seconds: seconds from that start to the end of the first step (nan: none).
        training_views: training views cached; ``validation_views`` set name -> views
            validated on.
        backtracks: times the run went back to its best candidate (``config.backtrack``).
        history: one dict per step (loss, elapsed, validation scores where validated).
    """

    textures: list[torch.Tensor | None]
    uvs: torch.Tensor | None
    steps: int
    best_step: int
    scores: dict[str, float]
    clears_floor: bool
    shortfall: float
    baselines: dict[str, dict[str, float]]
    stopped_by: str
    seconds: float
    first_step_seconds: float = math.nan
    training_views: int = 0
    validation_views: dict[str, int] = field(default_factory=dict)
    backtracks: int = 0
    history: list[dict] = field(default_factory=list)

    @property
    def best_psnr(self) -> float:
        return self.scores.get("Q", math.nan)


def train_step(
    train: ViewCache,
    model: Model,
    optimizer: AdamW,
    views: Sequence[int],
    config: OptimizeConfig,
    lr_factor: Callable[[], float],
    perceptual: PerceptualTerm | None = None,
) -> float:
    """One step on the mean loss of the training ``views`` (or of their losses in dB,
    ``config.loss_in_db``); returns the mean loss.

    ``lr_factor()`` is read after the backward pass (so that a budgeted schedule sees the time
    the step took) and scales ``config.lr`` for this step.
    """
    optimizer.zero_grad()
    textures, uvs = model.candidate()
    mips = mip_chains(textures)  # once for every view
    losses = [view_loss(train, i, mips, uvs, config.ssim_weight, perceptual) for i in views]
    loss = torch.stack(losses)
    if config.loss_in_db:  # a view with nothing to get wrong (loss 0) has no gradient
        (10 * torch.log10(loss.clamp_min(1e-12))).mean().backward()
    else:
        loss.mean().backward()
    optimizer.lr = config.lr * lr_factor()
    optimizer.step()
    model.project()
    return loss.mean().item()


Candidate = tuple[list[torch.Tensor | None], torch.Tensor | None]
"""``(textures, uvs)``: per material a ``(h, w, 3)`` linear texture or None, and ``(V, 2)``
UVs or None (the mesh's own)."""


def finish(
    textures: Sequence[torch.Tensor | None], reachable: Sequence[torch.Tensor | None]
) -> list[torch.Tensor | None]:
    """The candidate's textures as they will ship, before 8-bit encoding: detached, and the
    gutters (texels outside ``reachable``, per material; None: no gutter filling) filled from
    their charts (:func:`geoscaler.texture.fill_gutters`)."""
    finished = []
    for texture, mask in zip(textures, reachable, strict=True):
        if texture is not None:
            texture = texture.detach()
            texture = texture.clone() if mask is None else fill_gutters(texture, mask)
        finished.append(texture)
    return finished


def finished_candidate(model: Model, reachable: Sequence[torch.Tensor | None]) -> Candidate:
    """The model's candidate as it will ship, before 8-bit encoding (:func:`finish`)."""
    with torch.no_grad():
        textures, uvs = model.candidate()
        return finish(textures, reachable), None if uvs is None else uvs.detach().clone()


def _detached(model: Model) -> Candidate:
    """A copy of the model's candidate, out of the autograd graph."""
    with torch.no_grad():
        textures, uvs = model.candidate()
        copies = [None if t is None else t.detach().clone() for t in textures]
        return copies, None if uvs is None else uvs.detach().clone()


def validate(validation: Validation, candidate: Candidate) -> dict[str, float]:
    """PSNR-fg per validation set of a finished candidate, 8-bit quantised as it ships: what
    is validated is what ships."""
    textures, uvs = candidate
    return validation.psnr([None if t is None else quantize_linear(t) for t in textures], uvs)


class _Caching:
    """Caches the training pool and the validation views between steps.

    Before the first step :meth:`until_trainable` caches ``views_per_step`` training views
    (none beyond the first, under a budget they would overrun).
    After each step :meth:`after_step` caches :data:`CACHED_PER_STEP` more, training and
    validation views in turn (whichever has fewer) until one is complete, then the other; the
    validation freezes once complete. Under a budget, once
    :data:`CACHING_SHARE` of it is spent, the pool stops growing and the validation freezes at
    what is cached.
    """

    def __init__(
        self,
        train: ViewCache,
        validation: Validation,
        config: OptimizeConfig,
        start: float,
        emit: Callable[[ProgressEvent], None],
    ):
        self.train, self.validation, self.config = train, validation, config
        self.start, self.emit = start, emit
        self.view_cost = ViewCost()
        self.deadline = None
        if config.time_budget is not None:
            self.deadline = start + CACHING_SHARE * config.time_budget

    @property
    def pool(self) -> ViewSet:
        return self.train.views

    def _cache_pool_view(self) -> bool:
        started = time.perf_counter()
        if not self.pool.cache_next():
            return False
        self.train.find_taps(len(self.pool) - 1)
        self.view_cost.add(time.perf_counter() - started)
        return True

    def _cache_one(self) -> bool:
        """Cache the next view due; False when nothing is left to cache."""
        pool_first = self.validation.frozen or len(self.pool) <= self.validation.num_views
        if pool_first:
            return self._cache_pool_view() or self.validation.cache_next()
        return self.validation.cache_next() or self._cache_pool_view()

    def until_trainable(self, fits: Callable[[float], bool]) -> bool:
        """Cache the training views the first step needs while ``fits(seconds)`` says that
        caching the rest of them (at the mean price of those cached so far) still fits the budget;
        False when they cannot all be cached in time."""
        needed = min(self.config.views_per_step, len(self.pool.cameras))
        while len(self.pool) < needed:
            if not fits(self.view_cost.mean * (needed - len(self.pool))):
                return False
            if not self._cache_pool_view():
                break
            elapsed = time.perf_counter() - self.start
            self.emit(
                ProgressEvent(
                    "caching", 0, self.config.steps, elapsed, done=len(self.pool), total=needed
                )
            )
        return True

    def after_step(self) -> None:
        """Cache :data:`CACHED_PER_STEP` views; past the caching deadline, :meth:`close`."""
        if self.deadline is not None and time.perf_counter() > self.deadline:
            self.close()
            return
        for _ in range(CACHED_PER_STEP):
            if not self._cache_one():
                break
        if self.validation.complete:
            self.validation.freeze()

    def close(self) -> None:
        """No more training views; cache the validation views left until the caching deadline
        (all of them, without a budget), and validate on those from now on."""
        self.pool.cameras = self.pool.cameras[: len(self.pool)]
        while self.deadline is None or time.perf_counter() < self.deadline:
            if not self.validation.cache_next():
                break
        self.validation.freeze()

    @property
    def views_done(self) -> tuple[int, int]:
        """``(cached, planned)`` views, training and validation together."""
        cached = len(self.pool) + self.validation.num_views
        return cached, len(self.pool.cameras) + self.validation.planned


def optimize(
    renderer: Renderer,
    model: Model,
    config: OptimizeConfig,
    validation: Validation,
    on_event: Callable[[ProgressEvent], None] | None = None,
    controller: Controller | None = None,
    keeps_uvs: bool = True,
    perceptual: PerceptualTerm | None = None,
    training_cameras: Sequence[Camera] | None = None,
    started_at: float | None = None,
    reserve: float = 0.0,
    pool: ViewCache | None = None,
    start_scores: Scores | None = None,
) -> OptimizeResult:
    """Optimise ``model`` so that renders of its candidate match renders of the original.

    Args:
        renderer: the mesh's renderer (its device is the device of the run).
        model: the candidate's parameters (:class:`Restorable` with ``config.backtrack``).
        config: loop settings.
        validation: the validation sets (their views may not be cached yet) with the taps of
            the candidate's texture sizes, which the training pool's taps take too, and the
            baselines whose floor the result must clear.
        on_event: receives :class:`ProgressEvent` reports.
        controller: lets another thread pause, resume or stop the loop.
        keeps_uvs: the model never changes UVs, so texture taps can be cached and gutters
            filled.
        perceptual: an extra loss term (the network's VGG-19 term).
        training_cameras: the views to train on (default: ``config.pool_views`` cameras drawn
            from ``config.distances``). Methods never train on the validation cameras; the
            texel-ceiling benchmark does, to bound what any texture could reach there.
        started_at: the ``time.perf_counter()`` the time budget counts from (default: now), so
            that the job's and the method's set-up count too.
        reserve: seconds the caller needs after the loop returns (under a budget).
        pool: the training pool to train on and grow to its cameras (default: a new one over
            ``training_cameras``): an earlier loop's keeps its cached views and taps.
        start_scores: the validation scores of the model's start, when an earlier loop on the
            same validation validated it (it is not validated again).

    Returns:
        The best validated candidate (detached) by :meth:`Validation.rank`: the best on Q of
        those that clear the floor on every set, or the one that falls least below it; and the
        run's history.
    """
    start = time.perf_counter() if started_at is None else started_at
    controller = controller or Controller()
    emit = on_event or (lambda event: None)
    if pool is None:
        cameras = training_cameras or sample_training_cameras(
            config.pool_views, config.seed, config.distances
        )
        soft = config.soft if config.training_renderer == "soft" else None
        pool = training_views(renderer, cameras, validation.sizes, keeps_uvs, soft)
    train, cameras = pool, pool.views.cameras
    validating = [camera for cache in validation.sets.values() for camera in cache.views.cameras]
    farthest = max(camera.distance for camera in (*cameras, *validating))

    @functools.cache
    def reachable() -> list[torch.Tensor | None]:
        """Per material the texels a lookup can read, made after the first step (not before
        it: ~1 s on a 4096^2 original)."""
        if not keeps_uvs:
            return [None] * len(validation.sizes)
        masks = reachable_masks(renderer.mesh, validation.sizes, farthest, renderer.resolution)
        return [None if m is None else m.to(renderer.device) for m in masks]

    best = _Best(validation)
    deadline = None if config.time_budget is None else start + config.time_budget
    renderer.reference_textures()  # made once, before views are timed: not a view's cost
    caching = _Caching(train, validation, config, start, emit)

    def seconds_needed() -> float:
        owed = 1 + (not best.has_start and start_scores is None)  # the last, and the start
        view_seconds = caching.view_cost.mean  # a validation view's cost, before one is cached
        return FINISH_MARGIN * validation.seconds_needed(owed, True, view_seconds) + reserve

    def fits(seconds: float) -> bool:
        """``seconds`` of work, then what must follow the loop, fit in the budget."""
        return deadline is None or time.perf_counter() + seconds + seconds_needed() <= deadline

    trainable = caching.until_trainable(fits)
    # Until a step is timed, 0: a step from cached views costs a fraction of caching them.
    step_seconds = 0.0
    optimizer = AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    generator = torch.Generator().manual_seed(config.seed)
    start_state = _detached(model)

    candidate = functools.partial(_detached, model)  # the current state, on request
    plain_l2 = config.ssim_weight == 0 and perceptual is None and not config.loss_in_db
    majorizes = isinstance(model, Sloped) and keeps_uvs and train.with_taps and plain_l2

    def offer(scores: dict[str, float], finished: Candidate, step: int) -> bool:
        improved = best.offer(scores, finished, step)
        event = ProgressEvent(
            "validation",
            step,
            config.steps,
            time.perf_counter() - start,
            loss_value,
            scores["Q"],
            best.psnr,
            scores=scores,
            candidate=candidate,
        )
        emit(event)
        return improved

    def validate_start() -> None:
        emit(
            ProgressEvent(
                "baselines",
                step,
                config.steps,
                time.perf_counter() - start,
                baselines=validation.baseline_scores(),
            )
        )
        textures, uvs = start_state
        start_candidate = finish(textures, reachable()), uvs
        scores = validate(validation, start_candidate) if start_scores is None else start_scores
        best.offer(scores, start_candidate, 0)

    history: list[dict] = []
    step, loss_value, stopped_by = 0, math.nan, "steps"
    if not trainable:  # not even the first step's views could be cached in time
        stopped_by = "time budget"
    lr_scale, backtracks, check_at = 1.0, 0, -1  # check_at: a validation backtracking asks for
    validated_step, first_step = -1, math.nan
    loop_start, schedule = time.perf_counter(), config.schedule
    while trainable and step < config.steps:
        controller.wait_while_paused()
        if controller.stopped:
            stopped_by = "stopped"
            break
        step_start = time.perf_counter()
        if not fits(step_seconds):
            stopped_by = "time budget"
            break
        views = torch.randperm(len(train), generator=generator)[: config.views_per_step]
        if step < config.majorized_steps and majorizes:
            loss_value = majorized_step(train, model, views.tolist())
        else:
            loss_value = train_step(
                train,
                model,
                optimizer,
                views.tolist(),
                config,
                lambda at=step, scale=lr_scale: (
                    scale
                    * schedule.factor(
                        at, schedule.time_spent(time.perf_counter(), start, loop_start)
                    )
                ),
                perceptual,
            )
        step += 1
        step_seconds = time.perf_counter() - step_start
        elapsed = time.perf_counter() - start
        if step == 1:
            first_step = elapsed
            reachable()  # now, before the budget's next look at the clock, not in a validation
        done, total = caching.views_done
        emit(
            ProgressEvent(
                "step",
                step,
                config.steps,
                elapsed,
                loss_value,
                best_psnr=best.psnr,
                done=done,
                total=total,
                candidate=candidate,
            )
        )
        history.append({"step": step, "loss": loss_value, "elapsed": elapsed})
        caching.after_step()
        if not validation.frozen:
            continue
        if not best.has_start:
            validate_start()
            if config.backtrack is not None:  # is the step size hurting already?
                check_at = step
        if step % config.validate_every == 0 or step == config.steps or step == check_at:
            finished = finished_candidate(model, reachable())
            scores = validate(validation, finished)
            validated_step = step
            improved = offer(scores, finished, step)
            history[-1]["validation_psnr_fg"] = scores["Q"]
            if not improved and config.backtrack is not None and step < config.steps:
                model.restore(best.textures)
                optimizer = AdamW(model.parameters(), weight_decay=config.weight_decay)
                lr_scale *= config.backtrack
                backtracks += 1
                check_at = step + max(round(config.validate_every * config.backtrack), 1)
                history[-1]["backtrack"] = lr_scale
            if not improved and config.patience is not None and best.stale >= config.patience:
                stopped_by = "plateau"
                break

    caching.close()
    if not best.has_start:
        validate_start()
    if validated_step != step and step > 0:  # stopped between validations: it may be better
        finished = finished_candidate(model, reachable())
        offer(validate(validation, finished), finished, step)
    seconds = time.perf_counter() - start
    emit(ProgressEvent("done", step, config.steps, seconds, loss_value, None, best.psnr))
    return OptimizeResult(
        best.textures,
        best.uvs,
        step,
        best.step,
        best.scores,
        best.clears,
        best.rank[0],
        validation.baseline_scores(),
        stopped_by,
        seconds,
        first_step,
        len(train),
        dict(validation.counts or {}),
        backtracks,
        history,
    )
