"""The per-mesh optimisation loop that every learned method shares.

A *model* produces the candidate: linear-light textures (one per material, None where the
material is untextured) and optionally new UVs. The loop renders K random training views of
the candidate through the protocol renderer (or the paper's soft rasteriser, candidate and
original alike: ``training_renderer="soft"``), compares them with renders of the original
(L2 plus a weighted 1 - SSIM on the sRGB images, foreground only), and steps AdamW with a
warm-up and cosine decay. It validates the candidate as it ships (gutters filled, 8-bit) on
a :class:`~geoscaler.optim.validation.Validation` (Q and near/far guards) and keeps the best state
that clears the filters' floor on every set (with ``backtrack``, a candidate that validates
worse than the best sends the model back to the best at a lower learning rate). It stops at a
step count, a wall-clock budget or a plateau, and reports progress events that the CLI's
progress bar and the desktop app consume.

Views are cached while the loop trains: the first step waits for ``views_per_step`` training
views only (one under a time budget); the rest of the training pool and the validation views
are cached between steps, :data:`CACHED_PER_STEP` after each step until they are all there.
Under a budget the pool stops growing and the validation sets freeze once
:data:`CACHING_SHARE` of it is spent, and the loop stops early enough for what must follow:
the validations still owed and the caller's own scoring and export (``reserve``).

Gutters are filled from the UV layout alone (:func:`geoscaler.uv.uvmaps.reachable_texels`), so
what ships never depends on which views the machine managed to cache.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import torch

from geoscaler.clock import Budget
from geoscaler.color import quantize_linear
from geoscaler.optim.adamw import AdamW
from geoscaler.optim.events import Controller, ProgressEvent
from geoscaler.optim.losses import PerceptualTerm, view_loss
from geoscaler.optim.majorize import Sloped, majorized_step
from geoscaler.optim.schedule import Schedule
from geoscaler.optim.validation import Best as _Best
from geoscaler.optim.validation import Scores, Validation, ViewCost
from geoscaler.process import release_free_memory, resident_bytes
from geoscaler.protocol import RANGE_S
from geoscaler.render.cameras import Camera, sample_training_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.soft import SoftSettings
from geoscaler.render.texture import fill_gutters
from geoscaler.render.views import ViewCache, ViewSet, mip_chains, training_views
from geoscaler.uv.uvmaps import reachable_masks

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
INVISIBLE_PSNR_FG = 50.0
"""PSNR-fg (dB) at and above which a render differs from its reference by less than a step of
8 bits can show: an RMS error of 0.81 of a code (rounding to 8 bits alone is 0.29, 58.9 dB). A
loop whose baselines validate at least this on every view of every set has nothing visible left
to gain and stops (``finish_when_invisible``; see docs/decisions/invisible-differences.md)."""
NOTHING_TO_GAIN = "nothing visible to gain"
"""``stopped_by`` of a loop that stopped at :data:`INVISIBLE_PSNR_FG`."""
VIEW_MEMORY = 2 << 30
"""Bytes the views a loop caches may hold, training pool and validation sets together (G-buffers,
references, taps and their transposes): past them the pool stops growing and the validation
freezes, as at the end of the caching window, so that a job's memory is bounded whatever its
budget (a view of a large texture holds tens of MB; see docs/refusals.md, memory)."""
METHOD_MEMORY = 1_000_000_000
"""Bytes a method's loops may add to the process's resident size, from the method's start
(:func:`geoscaler.methods.learned.loop_config`), before they cache no more views. What the job
holds before (the original, its reference mips, the filters), this, and a step's own passing
buffers make its peak: an 8192 x 8192 input at 4x peaked at 2.50 to 2.56 GB under a 180 s
budget, where 1.25 GB here gave 2.89 to 3.10 GB (``benchmarks/peak_memory.py``;
docs/refusals.md, memory)."""
CACHED_PER_STEP = 2
"""Views cached after each step while some are missing: a count, not a time share, so that a
run without a budget is the same on every machine."""
CACHING_PER_STEPPING = 1.0
"""Under a time budget, the seconds the loop may spend caching views between steps per second
its steps took: a view costs as much as 3 to 10 steps on the CPU, so two views after every step
left a short budget a handful of steps (bob at 15 s: 2). The first step's view and the
validation views that any validation needs (:data:`~geoscaler.optim.validation.MIN_FROZEN`)
and the pool's first ``views_per_step`` are not held back by it, nor counted: on a pool of one
view, 28 steps on the stool at 15 s validated no better than their start."""


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
            turn (:func:`~geoscaler.render.cameras.sample_training_cameras`).
        lr: peak learning rate; warm-up over ``warmup_steps``, then cosine decay to 0.
        short_run_boost: at most this factor on the learning rate when the time budget allows
            fewer steps than ``steps`` (1: none; :meth:`Schedule.boost`).
        backtrack: with a factor f (< 1), a validated candidate that ranks below the best so
            far sends the model back to the best (``Restorable.restore``), multiplies the
            learning rate by f and validates again after ``validate_every * f`` steps; with
            it the candidate is also validated as the validation sets freeze, so that a step
            size that hurts is found early (None: no backtracking).
        majorized_steps: the first steps are majorise-minimise steps
            (:func:`geoscaler.optim.majorize.majorized_step`), where the model is
            :class:`~geoscaler.optim.majorize.Sloped` and the loss the plain L2 on cached taps;
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
            :mod:`geoscaler.render.soft`, with ``soft`` settings). Validation is always exact.
        view_memory: bytes the cached views may hold (:data:`VIEW_MEMORY`; None: no limit).
        memory_limit: the process's resident bytes at which the loop caches no more views, as
            ``view_memory`` does (None: no limit; also where the system cannot tell,
            :func:`geoscaler.process.resident_bytes`); a method sets it :data:`METHOD_MEMORY`
            above what the process holds as it starts. Freed memory that glibc keeps
            (:func:`geoscaler.process.keep_freed_memory`) counts, so the resident size is the
            most the process has held, steps' passing buffers included. Where it stops the
            caching, a rerun may cache a view more or less (allocators differ).
        finish_when_invisible: stop (``stopped_by`` :data:`NOTHING_TO_GAIN`) as soon as every
            validation set has its least views cached, where a baseline validates at
            :data:`INVISIBLE_PSNR_FG` or more on every one of them (``downsample`` and
            ``batch`` unless ``--full-budget``; ``compare`` and ``bench`` measure whole runs).
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
    view_memory: int | None = VIEW_MEMORY
    memory_limit: int | None = None
    finish_when_invisible: bool = False

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
        stopped_by: ``"steps"``, ``"time budget"``, ``"plateau"``, ``"stopped"`` or
            :data:`NOTHING_TO_GAIN`.
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
    their charts (:func:`geoscaler.render.texture.fill_gutters`)."""
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


def nothing_visible_to_gain(validation: Validation) -> bool | None:
    """Whether a baseline already validates at :data:`INVISIBLE_PSNR_FG` or more on every view
    of every set; None until each set has its least views."""
    worst = validation.worst_baseline_views()
    return max(worst.values()) >= INVISIBLE_PSNR_FG if worst else None


def reaches_memory_limit(limit: int | None, more: int = 0) -> bool:
    """The process's resident size plus ``more`` bytes reaches ``limit`` (False without a
    limit, or where the system cannot tell the resident size)."""
    resident = None if limit is None else resident_bytes()
    return resident is not None and resident + more >= limit


class _Caching:
    """Caches the training pool and the validation views between steps.

    Before the first step :meth:`until_trainable` caches ``views_per_step`` training views
    (one under a budget).
    After each step :meth:`after_step` caches :data:`CACHED_PER_STEP` more, training and
    validation views in turn (whichever has fewer) until one is complete, then the other; the
    validation freezes once complete. Under a budget, once its caching share of it is spent
    (:data:`CACHING_SHARE` unless told), or once the cached views hold ``config.view_memory``
    bytes, the pool stops growing and the validation freezes at what is cached. While the
    process holds ``config.memory_limit`` the validation freezes and the pool waits for a step
    that leaves room. Under a budget the views owed in any case (:meth:`_cache_owed`) are
    cached past the caching window and both memory bounds.
    """

    def __init__(
        self,
        train: ViewCache,
        validation: Validation,
        config: OptimizeConfig,
        budget: Budget,
        emit: Callable[..., None],
        share: float = CACHING_SHARE,
        room_for_a_pool: bool = False,
    ):
        """``emit(kind, **fields)`` reports a progress event of the loop; views are cached
        within ``share`` of the budget (``room_for_a_pool``: :attr:`LoopSetup.room_for_a_pool`)."""
        self.train, self.validation, self.config = train, validation, config
        self.budget, self.emit = budget, emit
        self.view_cost = ViewCost()
        share = None if budget.seconds is None else share * budget.seconds
        self.window = Budget(budget.clock, budget.start, share)
        self.stepping = 0.0  # seconds the loop's steps took
        self.between_steps = 0.0  # seconds spent caching after them
        self.room_for_a_pool = room_for_a_pool

    @property
    def pool(self) -> ViewSet:
        return self.train.views

    def _cache_pool_view(self) -> bool:
        started = self.budget.now()
        if not self.pool.cache_next():
            return False
        self.train.find_taps(len(self.pool) - 1)
        self.view_cost.add(self.budget.now() - started)
        return True

    def _cache_one(self) -> bool:
        """Cache the next view due; False when nothing is left to cache."""
        pool_first = self.validation.frozen or len(self.pool) <= self.validation.num_views
        if pool_first:
            return self._cache_pool_view() or self.validation.cache_next()
        return self.validation.cache_next() or self._cache_pool_view()

    def until_trainable(self, fits: Callable[[float], bool]) -> bool:
        """Cache the training views the first step needs, where ``fits(0.0)`` says that what
        must follow the loop still fits the budget (no view is cached for a step that cannot
        be taken); False where it does not.

        Under a budget the first step needs one view: a step on one view moves the texels that
        view sees, and the views the later steps draw from are cached between steps, so the
        seconds of caching ``views_per_step`` views up front would be steps not taken. Without
        a budget, where a run is a step count, the first step sees as many views as the rest."""
        wanted = 1 if self.budget.limited else self.config.views_per_step
        needed = min(wanted, len(self.pool.cameras))
        if len(self.pool) >= needed:
            return True
        if not fits(0.0):
            return False
        while len(self.pool) < needed and self._cache_pool_view():
            self.emit("caching", done=len(self.pool), total=needed)
        return True

    def after_step(self, step_seconds: float, fits: Callable[[float], bool]) -> None:
        """After a step of ``step_seconds``, where ``fits(seconds)`` says that a view of the
        pool's mean cost and what must follow the loop still fit its budget (no view is
        cached past it, owed or not), under a budget first up to
        :data:`CACHED_PER_STEP` views owed in any case (:meth:`_cache_owed`, even past the
        caching window, the view memory and the memory limit: a few views, where a pool of
        one view trains a loop to that view alone), then :data:`CACHED_PER_STEP` views
        (under a budget, fewer where caching would take more than
        :data:`CACHING_PER_STEPPING` of the steps' seconds so far); past the caching window
        or the view memory, :meth:`close`; at the process's memory limit, none this step (the
        validation sets freeze at what they have; the pool grows again where a later step
        leaves room). Then, where the process holds its memory limit, give its free memory
        back (:func:`~geoscaler.process.release_free_memory`)."""
        self.stepping += step_seconds
        for _ in range(CACHED_PER_STEP if self.budget.limited else 0):
            if not fits(self.view_cost.mean) or not self._cache_owed():
                break
        if self.window.left() < 0 or self.views_full():
            self.close()
        elif self.memory_full():
            self.validation.freeze()
        else:
            for _ in range(CACHED_PER_STEP):
                if not self._room_for_a_view(fits) or not self._caching_pays():
                    break
                started = self.budget.now()
                cached = self._cache_one()
                self.between_steps += self.budget.now() - started
                if not cached:
                    break
            if self.validation.complete:
                self.validation.freeze()
        if self._resident_over(0):
            release_free_memory()

    def _room_for_a_view(self, fits: Callable[[float], bool]) -> bool:
        """One more view fits in the process's memory and, at the pool's mean cost, ``fits``
        the loop's budget."""
        return not self.memory_full() and fits(self.view_cost.mean)

    def _pool_owes(self) -> bool:
        """The pool has fewer views than a step draws (:attr:`OptimizeConfig.views_per_step`)."""
        return len(self.pool) < min(self.config.views_per_step, len(self.pool.cameras))

    def _cache_owed(self) -> bool:
        """Cache one view owed in any case, False where none is: the pool's first
        ``views_per_step`` views or the validation's least (:attr:`Validation.lacks_least`),
        in :meth:`_cache_one`'s turn where both are owed."""
        pool_owes, validation_owes = self._pool_owes(), self.validation.lacks_least
        if pool_owes and validation_owes:
            return self._cache_one()
        if pool_owes:
            return self._cache_pool_view()
        return validation_owes and self.validation.cache_next()

    def _caching_pays(self) -> bool:
        """Another view may be cached between steps: always without a budget (a count), under
        one while caching has taken at most :data:`CACHING_PER_STEPPING` of the steps' time."""
        limited = self.budget.limited
        return not limited or self.between_steps <= CACHING_PER_STEPPING * self.stepping

    def close(self) -> None:
        """No more training views; cache the validation views left within the caching window,
        the loop's own budget and the view memory (all of them, without a budget or a limit),
        and validate on those from now on. A loop whose budget ends before the window (a
        race's first trial) caches none past its end: they made the validations the race
        still owes too costly for its time. With :attr:`room_for_a_pool`, none where the
        process could then not hold one more pool's taps beside them: a race's first trial
        filled the memory limit with validation views, and a later layout's pool stopped at
        8 views against its 20 (ycb_banana at 8x and 60 s)."""
        self.pool.cameras = self.pool.cameras[: len(self.pool)]
        room = self.train.nbytes if self.room_for_a_pool else 0  # its views are shared
        while self.window.left() > 0 and self.budget.left() > 0 and not self.memory_full(room):
            if not self.validation.cache_next():
                break
        self.validation.freeze()

    def memory_full(self, room: int = 0) -> bool:
        """The cached views hold ``config.view_memory`` bytes or more, or one more view (of
        their mean size) and ``room`` bytes would take the process to ``config.memory_limit``
        resident bytes.

        Read right after a step, the resident size holds that step's passing buffers too
        (freed memory is kept), so a view is cached only where the next step still fits."""
        if self.views_full():
            return True
        views = self.view_bytes()
        cached = len(self.pool) + self.validation.num_views
        return self._resident_over(views // max(cached, 1) + room)

    def views_full(self) -> bool:
        """The cached views hold ``config.view_memory`` bytes or more."""
        limit = self.config.view_memory
        return limit is not None and self.view_bytes() >= limit

    def _resident_over(self, more: int) -> bool:
        """The process's resident size plus ``more`` bytes reaches ``config.memory_limit``
        (:func:`reaches_memory_limit`)."""
        return reaches_memory_limit(self.config.memory_limit, more)

    def view_bytes(self) -> int:
        """Bytes the training pool and the validation sets hold (:attr:`ViewSet.nbytes` and
        :attr:`ViewCache.nbytes`)."""
        caches = [self.train, *self.validation.sets.values()]
        return sum(cache.nbytes + cache.views.nbytes for cache in caches)

    @property
    def views_done(self) -> tuple[int, int]:
        """``(cached, planned)`` views, training and validation together."""
        cached = len(self.pool) + self.validation.num_views
        return cached, len(self.pool.cameras) + self.validation.planned


@dataclass(frozen=True)
class Phase:
    """Where a loop stands in a run of several loops (the layout race's trials and its
    continuation): its progress events count steps and seconds as the run does.

    Attributes:
        steps_before: steps the run made before this loop; events and ``best_step`` count on
            from them.
        total_steps: the run's step limit, reported in events (None: this loop's).
        run_start: the instant (on the budget's clock) events count seconds from (None: the
            loop's budget's start).
        reports_caching: this loop reports its caching before the first step (the run's first).
        reports_done: this loop reports the run's end (the run's last).
    """

    steps_before: int = 0
    total_steps: int | None = None
    run_start: float | None = None
    reports_caching: bool = True
    reports_done: bool = True


ALONE = Phase()
"""A loop that is a run of its own."""


@dataclass(frozen=True)
class LoopSetup:
    """How a loop trains, besides the model and its settings.

    Attributes:
        keeps_uvs: the model never changes UVs, so texture taps can be cached and gutters
            filled.
        perceptual: an extra loss term (the network's VGG-19 term).
        training_cameras: the views to train on (default: ``config.pool_views`` cameras drawn
            from ``config.distances``). Methods never train on the validation cameras; the
            texel-ceiling benchmark does, to bound what any texture could reach there.
        pool: the training pool to train on and grow to its cameras (default: a new one over
            the training cameras): an earlier loop's keeps its cached views and taps.
        start_scores: the validation scores of the model's start, when an earlier loop on the
            same validation validated it (it is not validated again).
        phase: where the loop stands in a run of several (its events' and ``best_step``'s
            count).
        caching_share: the share of the budget within which views are cached
            (:data:`CACHING_SHARE`; less where other preparation shares that time).
        room_for_a_pool: the validation views cached once the pool stops growing leave the
            process room under its memory limit for the taps of one more pool as large (a
            race's first trial: each later layout finds its own taps in the same views).
    """

    keeps_uvs: bool = True
    perceptual: PerceptualTerm | None = None
    training_cameras: Sequence[Camera] | None = None
    pool: ViewCache | None = None
    start_scores: Scores | None = None
    phase: Phase = ALONE
    caching_share: float = CACHING_SHARE
    room_for_a_pool: bool = False


PLAIN = LoopSetup()
"""A loop of its own on new training views, the mesh's UVs kept, no extra loss term."""


@dataclass
class LoopState:
    """What changes as the loop runs.

    Attributes:
        step: steps taken.
        loss: the last step's loss (nan before the first).
        stopped_by: why the loop ended (``"steps"``, ``"time budget"``, ``"stopped"``,
            ``"plateau"``, :data:`NOTHING_TO_GAIN`).
        step_seconds: the last step's wall-clock seconds (0 before one is timed: a step from
            cached views costs a fraction of caching them).
        first_step_seconds: seconds from the budget's start to the end of the first step.
        lr_scale: the learning rate's factor after backtracking.
        backtracks: times the loop went back to its best candidate.
        check_at: the step a backtrack asks to validate at (-1: none).
        validated_step: the last step validated (-1: none).
        looked_for_gain: whether the baselines were looked at for anything visible left to gain.
        history: one row per step.
    """

    step: int = 0
    loss: float = math.nan
    stopped_by: str = "steps"
    step_seconds: float = 0.0
    first_step_seconds: float = math.nan
    lr_scale: float = 1.0
    backtracks: int = 0
    check_at: int = -1
    validated_step: int = -1
    looked_for_gain: bool = False
    history: list[dict] = field(default_factory=list)


@dataclass(frozen=True)
class _Reporter:
    """Reports a loop's progress events at its current step, counted as the run counts
    (:class:`Phase`); a phase's caching and end are reported where it says so.

    Apart from the loop, so that the loop's caching reports through it without holding the
    loop: a reference cycle would keep a finished loop, and the training pool it holds, alive
    until the garbage collector runs (a race's losing pool then held the memory the winner's
    pool was to grow into).
    """

    phase: Phase
    state: LoopState
    steps: int
    budget: Budget
    emit: Callable[[ProgressEvent], None]

    def __call__(self, kind: str, **fields: object) -> None:
        phase = self.phase
        if (kind == "caching" and not phase.reports_caching) or (
            kind == "done" and not phase.reports_done
        ):
            return
        start = self.budget.start if phase.run_start is None else phase.run_start
        step = phase.steps_before + self.state.step
        total = phase.total_steps or self.steps
        self.emit(ProgressEvent(kind, step, total, self.budget.now() - start, **fields))


class TrainingLoop:
    """The loop of :func:`optimize`: cache the views the first step needs, then step,
    cache more views, validate when due and back-track, until the steps, the budget, a
    plateau or the controller end it; finally validate what it has not and report the best.

    Arguments as :func:`optimize`'s.
    """

    def __init__(
        self,
        renderer: Renderer,
        model: Model,
        config: OptimizeConfig,
        validation: Validation,
        budget: Budget,
        setup: LoopSetup,
        on_event: Callable[[ProgressEvent], None] | None = None,
        controller: Controller | None = None,
    ):
        """``setup.pool`` is the training pool (:func:`optimize` makes one where it has none)."""
        pool = setup.pool
        assert pool is not None, "the loop trains on a pool of views"
        self.renderer, self.model, self.config = renderer, model, config
        self.phase = setup.phase
        self.validation, self.budget = validation, budget
        self.emit = on_event or (lambda event: None)
        self.controller = controller or Controller()
        self.keeps_uvs, self.perceptual = setup.keeps_uvs, setup.perceptual
        self.start_scores = setup.start_scores
        self.train = pool
        validating = [c for cache in validation.sets.values() for c in cache.views.cameras]
        self.farthest = max(camera.distance for camera in (*pool.views.cameras, *validating))
        self.best = _Best(validation)
        self.state = LoopState()
        self._reachable: list[torch.Tensor | None] | None = None
        self.optimizer = AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        self.generator = torch.Generator().manual_seed(config.seed)
        self.schedule = config.schedule
        self.loop_start = math.nan
        plain_l2 = config.ssim_weight == 0 and self.perceptual is None and not config.loss_in_db
        self.majorizes = (
            isinstance(model, Sloped) and self.keeps_uvs and pool.with_taps and plain_l2
        )
        share = setup.caching_share
        self._report = _Reporter(self.phase, self.state, config.steps, budget, self.emit)
        room = setup.room_for_a_pool
        self.caching = _Caching(pool, validation, config, budget, self._report, share, room)
        self.start_state: Candidate | None = None

    def run(self) -> OptimizeResult:
        """Train, validate and return the best validated candidate."""
        self.renderer.reference_textures()  # made once, before views are timed: not a view's cost
        trainable = self.caching.until_trainable(self.fits)
        self.start_state = _detached(self.model)
        if not trainable:  # what must follow the loop leaves no time for a first view
            self.state.stopped_by = "time budget"
        self.loop_start = self.budget.now()
        while trainable and self.state.step < self.config.steps:
            if not self._may_step():
                break
            self._step()
            self.caching.after_step(self.state.step_seconds, self.fits)
            if self._nothing_to_gain():
                self.state.stopped_by = NOTHING_TO_GAIN
                break
            if self.validation.frozen and self._validate_when_due():
                break
        return self._finish()

    def _nothing_to_gain(self) -> bool:
        """Whether a baseline already validates at :data:`INVISIBLE_PSNR_FG` or more on every
        view of every set; looked at once, as soon as each set has its least views
        (``config.finish_when_invisible``)."""
        if self.state.looked_for_gain or not self.config.finish_when_invisible:
            return False
        invisible = nothing_visible_to_gain(self.validation)
        self.state.looked_for_gain = invisible is not None
        return bool(invisible)

    # --------------------------------------------------------------------------- the budget

    def seconds_needed(self) -> float:
        """What must follow the loop, with :data:`FINISH_MARGIN`: the last validation, the
        start's where it is still owed, and the views they need."""
        owed = 1 + (not self.best.has_start and self.start_scores is None)
        view_seconds = self.caching.view_cost.mean  # a validation view's cost, before one
        return FINISH_MARGIN * self.validation.seconds_needed(owed, True, view_seconds)

    def fits(self, seconds: float) -> bool:
        """``seconds`` of work, then what must follow the loop, fit in the budget."""
        return not self.budget.limited or self.budget.fits(seconds + self.seconds_needed())

    def reachable(self) -> list[torch.Tensor | None]:
        """Per material the texels a lookup can read, made after the first step (not before
        it: ~1 s on a 4096^2 original)."""
        if self._reachable is None:
            sizes = self.validation.sizes
            if not self.keeps_uvs:
                self._reachable = [None] * len(sizes)
            else:
                masks = reachable_masks(self.renderer.mesh, sizes, self.farthest,
                                        self.renderer.resolution)  # fmt: skip
                self._reachable = [None if m is None else m.to(self.renderer.device) for m in masks]
        return self._reachable

    # ------------------------------------------------------------------------------ a step

    def _may_step(self) -> bool:
        """Whether the next step may run: not stopped, and within the budget (at the last
        step's cost); pauses while the controller says so."""
        self.controller.wait_while_paused()
        if self.controller.stopped:
            self.state.stopped_by = "stopped"
            return False
        if not self.fits(self.state.step_seconds):
            self.state.stopped_by = "time budget"
            return False
        return True

    def _step(self) -> None:
        """One training step, timed and reported."""
        state, config = self.state, self.config
        step_start = self.budget.now()
        views = torch.randperm(len(self.train), generator=self.generator)[: config.views_per_step]
        if state.step < config.majorized_steps and self.majorizes:
            state.loss = majorized_step(self.train, self.model, views.tolist())
        else:
            lr_factor = functools.partial(self._lr_factor, state.step, state.lr_scale)
            state.loss = train_step(self.train, self.model, self.optimizer, views.tolist(),
                                    config, lr_factor, self.perceptual)  # fmt: skip
        state.step += 1
        state.step_seconds = self.budget.now() - step_start
        elapsed = self.budget.elapsed()
        if state.step == 1:
            state.first_step_seconds = elapsed
            self.reachable()  # now, before the budget's next look at the clock
        done, total = self.caching.views_done
        self._report("step", loss=state.loss, best_psnr=self.best.psnr, done=done, total=total,
                     candidate=self._candidate)  # fmt: skip
        state.history.append({"step": state.step, "loss": state.loss, "elapsed": elapsed})

    def _lr_factor(self, step: int, scale: float) -> float:
        spent = self.schedule.time_spent(self.budget.now(), self.budget.start, self.loop_start)
        return scale * self.schedule.factor(step, spent)

    def _candidate(self) -> Candidate:
        """The current state, on request (progress events carry it)."""
        return _detached(self.model)

    # ------------------------------------------------------------------------- validating

    def _validate_when_due(self) -> bool:
        """Validate the start once the views are frozen, then every ``validate_every`` steps,
        at the last and where backtracking asks; back-track on a candidate that does not
        improve. True where the loop should stop (a plateau)."""
        state, config = self.state, self.config
        if not self.best.has_start:
            self._validate_start()
            if config.backtrack is not None:  # is the step size hurting already?
                state.check_at = state.step
        due = state.step % config.validate_every == 0 or state.step in (config.steps,
                                                                         state.check_at)
        if not due:
            return False
        finished = finished_candidate(self.model, self.reachable())
        scores = validate(self.validation, finished)
        state.validated_step = state.step
        improved = self._offer(scores, finished)
        state.history[-1]["validation_psnr_fg"] = scores["Q"]
        if not improved and config.backtrack is not None and state.step < config.steps:
            self._backtrack()
        if not improved and config.patience is not None and self.best.stale >= config.patience:
            state.stopped_by = "plateau"
            return True
        return False

    def _backtrack(self) -> None:
        """Back to the best candidate, with a lower learning rate, validated again sooner."""
        state, config = self.state, self.config
        self.model.restore(self.best.textures)
        self.optimizer = AdamW(self.model.parameters(), weight_decay=config.weight_decay)
        state.lr_scale *= config.backtrack
        state.backtracks += 1
        state.check_at = state.step + max(round(config.validate_every * config.backtrack), 1)
        state.history[-1]["backtrack"] = state.lr_scale

    def _offer(self, scores: dict[str, float], finished: Candidate) -> bool:
        state = self.state
        improved = self.best.offer(scores, finished, state.step)
        self._report("validation", loss=state.loss, validation_psnr=scores["Q"],
                     best_psnr=self.best.psnr, scores=scores,
                     candidate=self._candidate)  # fmt: skip
        return improved

    def _validate_start(self) -> None:
        self._report("baselines", baselines=self.validation.baseline_scores())
        textures, uvs = self.start_state
        start_candidate = finish(textures, self.reachable()), uvs
        scores = self.start_scores
        if scores is None:
            scores = validate(self.validation, start_candidate)
        self.best.offer(scores, start_candidate, 0)

    def _finish(self) -> OptimizeResult:
        """Validate what is still owed (the start; a last step between validations, which may
        be better) and report."""
        state = self.state
        if state.stopped_by == NOTHING_TO_GAIN:
            self.validation.freeze()  # the views that showed it: no more to cache
        self.caching.close()
        if not self.best.has_start:
            self._validate_start()
        if state.validated_step != state.step and state.step > 0:
            finished = finished_candidate(self.model, self.reachable())
            self._offer(validate(self.validation, finished), finished)
        seconds = self.budget.elapsed()
        self._report("done", loss=state.loss, best_psnr=self.best.psnr)
        best = self.best
        return OptimizeResult(
            textures=best.textures,
            uvs=best.uvs,
            steps=state.step,
            best_step=best.step + self.phase.steps_before if best.step else 0,  # 0: its start
            scores=best.scores,
            clears_floor=best.clears,
            shortfall=best.rank[0],
            baselines=self.validation.baseline_scores(),
            stopped_by=state.stopped_by,
            seconds=seconds,
            first_step_seconds=state.first_step_seconds,
            training_views=len(self.train),
            validation_views=dict(self.validation.counts or {}),
            backtracks=state.backtracks,
            history=state.history,
        )


def optimize(
    renderer: Renderer,
    model: Model,
    config: OptimizeConfig,
    validation: Validation,
    setup: LoopSetup = PLAIN,
    budget: Budget | None = None,
    on_event: Callable[[ProgressEvent], None] | None = None,
    controller: Controller | None = None,
) -> OptimizeResult:
    """Optimise ``model`` so that renders of its candidate match renders of the original.

    Args:
        renderer: the mesh's renderer (its device is the device of the run).
        model: the candidate's parameters (:class:`Restorable` with ``config.backtrack``).
        config: loop settings.
        validation: the validation sets (their views may not be cached yet) with the taps of
            the candidate's texture sizes, which the training pool's taps take too, and the
            baselines whose floor the result must clear.
        setup: how the loop trains (:class:`LoopSetup`): UVs kept or not, an extra loss term,
            the training views or an earlier loop's pool, the start's scores, its phase.
        budget: the time the loop may take, counted from its start (so that the job's and the
            method's set-up count too), less its reserve for what the caller does after the
            loop returns (default: ``config.time_budget`` from now, on the validation's clock).
        on_event: receives :class:`ProgressEvent` reports.
        controller: lets another thread pause, resume or stop the loop.

    Returns:
        The best validated candidate (detached) by :meth:`Validation.rank`: the best on Q of
        those that clear the floor on every set, or the one that falls least below it; and the
        run's history.
    """
    budget = budget or Budget.from_now(validation.clock, config.time_budget)
    if setup.pool is None:
        cameras = setup.training_cameras or sample_training_cameras(
            config.pool_views, config.seed, config.distances
        )
        soft = config.soft if config.training_renderer == "soft" else None
        pool = training_views(renderer, cameras, validation.sizes, setup.keeps_uvs, soft)
        setup = replace(setup, pool=pool)
    loop = TrainingLoop(renderer, model, config, validation, budget, setup, on_event, controller)
    return loop.run()
