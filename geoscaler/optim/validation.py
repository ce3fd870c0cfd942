"""What a learned method validates on, and the floor its result must clear.

Three view sets, each a :class:`~geoscaler.render.views.ViewCache` with the taps of the output
sizes:

- ``Q``: the protocol's validation set (the evaluation's views) in
  :func:`~geoscaler.render.cameras.spread_order`, so that any prefix of it covers the sphere;
- ``near`` and ``far``: cameras of the loop's own (:func:`guard_cameras`) at the protocol's
  near and far distances, so that a texture is not sharpened for close views at the cost of
  distant ones. The protocol's near and far sets are not used here: they stay for evaluation.

The optimisation loop caches their views between its steps (:meth:`Validation.cache_next`).
Under a time budget the sets are *frozen* at the views cached by then (:meth:`freeze`), so
that every candidate is compared on the same views. The filters the job runs beside the method
(its *baselines*) are scored on the frozen sets; per set the best of them is the *floor*, and
candidates are ranked by how far they fall below it on their worst set, then by Q
(:meth:`Validation.rank`). A set has few views under a budget and the per-view differences
between two textures are large (1.5 dB on a scan seen from far away), so a candidate clears the
floor on a set only where its mean gain over the floor's baseline, view by view, clears zero
with :data:`FLOOR_CONFIDENCE` (:func:`paired_gap`).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence

import numpy as np
import torch
from scipy.special import ndtr, stdtrit

from geoscaler.clock import WALL_CLOCK, Clock
from geoscaler.color import linear_to_texture, texture_to_linear, to_rgb
from geoscaler.protocol import FAR_DISTANCE, NEAR_DISTANCE, VALIDATION_DISTANCE
from geoscaler.render.cameras import Camera, fibonacci_directions, spread_order, view_set_cameras
from geoscaler.render.metrics import evaluate, mean_metrics, psnr_fg
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, ViewSet, mip_chains

GUARD_VIEWS = 20
"""Views of each guard set (near, far): the views on which a sharpened scan fails from far away
are a few directions, which a smaller set misses too easily (see
docs/decisions/validation-guard-sets.md)."""
MIN_FROZEN = {"Q": 3, "near": 3, "far": 3}
"""Views a set keeps at least when frozen (fewer where it has fewer): one view has no spread to
judge its gain by, and with two the floor's margin (:func:`floor_margin`, 1.84 standard errors)
turns away candidates well above the filters (see docs/decisions/validation-guard-sets.md)."""
SET_NAMES = ("Q", "near", "far")

FLOOR_CONFIDENCE = float(ndtr(1.0))
"""One-sided confidence (0.84) with which a candidate's mean per-view gain over the floor's
baseline must clear zero on each set: the mean less Student's t quantile for the views' count
(:func:`floor_margin`) times its standard error. On many views that is one standard error; on
the few views a short budget validates on, t widens it (1.84 for 2), since a few views' mean
can disagree with the protocol's full set (``benchmarks/budget.py``; see
docs/decisions/validation-floor-confidence.md)."""


def floor_margin(views: int) -> float:
    """Standard errors by which a mean gain over ``views`` (>= 2) views must clear zero: the
    :data:`FLOOR_CONFIDENCE` quantile of Student's t with ``views - 1`` degrees of freedom."""
    return float(stdtrit(views - 1, FLOOR_CONFIDENCE))


class Scores(dict):
    """Set name -> mean PSNR-fg (dB) over the set's frozen views, a plain dict for reports;
    ``per_view`` keeps each set's ``(N,)`` per-view values for :func:`paired_gap` (empty for
    scores made elsewhere: then only the means are compared)."""

    def __init__(self, means: Mapping[str, float], per_view: Mapping[str, np.ndarray] = ()):
        super().__init__(means)
        self.per_view = dict(per_view)


def paired_gap(candidate: Mapping[str, float], floor: Mapping[str, float], name: str) -> float:
    """How far (dB) a candidate is above the floor's baseline on set ``name``: the mean of its
    per-view gains less :func:`floor_margin` standard errors of them (views without foreground
    left out), or the difference of the means where per-view values are missing. A baseline
    paired with itself gains 0 exactly. nan: no view of the set shows the mesh."""
    mine = getattr(candidate, "per_view", {}).get(name)
    theirs = getattr(floor, "per_view", {}).get(name)
    if mine is None or theirs is None or len(mine) != len(theirs):
        return candidate[name] - floor[name]
    gains = (mine - theirs)[np.isfinite(mine) & np.isfinite(theirs)]
    if len(gains) == 0:
        return math.nan
    if len(gains) == 1:
        return float(gains[0])
    error = gains.std(ddof=1) / math.sqrt(len(gains))
    return float(gains.mean() - floor_margin(len(gains)) * error)


def sets_below(candidate: Scores, reference: Scores) -> list[str]:
    """The sets on which ``candidate`` is below ``reference`` beyond the noise: the reference's
    :func:`paired_gap` over the candidate is positive (sets neither shows, nan, say nothing)."""
    return [name for name in candidate if paired_gap(reference, candidate, name) > 0]


def guard_cameras(distance: float, count: int = GUARD_VIEWS) -> list[Camera]:
    """``count`` validation cameras at ``distance``: a Fibonacci sphere of ``count`` directions,
    turned half a golden angle about the z axis so that none is a protocol view, in spread
    order."""
    directions = fibonacci_directions(count)
    turn = math.pi * (3.0 - math.sqrt(5.0)) / 2
    rotation = np.array(
        [[math.cos(turn), -math.sin(turn), 0.0], [math.sin(turn), math.cos(turn), 0.0], [0, 0, 1]]
    )
    turned = directions @ rotation.T
    return [Camera(tuple(turned[i]), float(distance)) for i in spread_order(count)]


def validation_view_sets(renderer: Renderer, guard_views: int = GUARD_VIEWS) -> dict[str, ViewSet]:
    """The three sets' views, none cached yet: Q (the views of ``renderer.evaluation``, in
    spread order), near and far guards of ``guard_views`` each, but never more than Q has (a
    quick evaluation's one view gets one guard at each distance). Views are shared by every
    scale's :class:`Validation`."""
    q = view_set_cameras(VALIDATION_DISTANCE, renderer.evaluation)
    guard_views = min(guard_views, len(q))
    cameras = {
        "Q": [q[i] for i in spread_order(len(q))],
        "near": guard_cameras(NEAR_DISTANCE, guard_views),
        "far": guard_cameras(FAR_DISTANCE, guard_views),
    }
    return {name: ViewSet(renderer, cams, eager=False) for name, cams in cameras.items()}


class ViewCost:
    """Seconds per cached view, averaged over the views timed so far: what each view still to
    cache is costed at. The mean, not the costliest: a budget is spent on many views, and one
    slow view (a frame-filling close-up, a page fault) says little about the rest."""

    def __init__(self) -> None:
        self.total, self.views = 0.0, 0

    def add(self, seconds: float) -> None:
        self.total += seconds
        self.views += 1

    @property
    def mean(self) -> float:
        """Mean seconds per view; 0.0 before a view is timed."""
        return self.total / self.views if self.views else 0.0


class Validation:
    """The validation sets of one output size, the baselines and their floor.

    Args:
        views: set name -> its views (:func:`validation_view_sets`), in :data:`SET_NAMES`.
        sizes: per material the output texture ``(h, w)`` (None: untextured).
        baselines: filter name -> its 8-bit output textures, scored once the sets are frozen.
        scorings_after: full-metric scorings of Q's frozen views the caller will run after
            the method (a downsampling job's report: the result and each baseline); the loop
            keeps time for them under a budget (validated textures are not rendered again).
        clock: what the unit costs of caching, rendering and scoring are timed on.

    Attributes:
        sets: set name -> a :class:`ViewCache` of its views with the taps of ``sizes``.
        counts: set name -> frozen number of views (None until :meth:`freeze`).
    """

    def __init__(
        self,
        views: Mapping[str, ViewSet],
        sizes: Sequence[tuple[int, int] | None],
        baselines: Mapping[str, Sequence[np.ndarray | None]] | None = None,
        scorings_after: int = 0,
        clock: Clock = WALL_CLOCK,
    ):
        self.clock = clock
        self.sets = {
            name: ViewCache(view_set, sizes, with_taps=True) for name, view_set in views.items()
        }
        self.sizes = list(sizes)
        self.baselines = dict(baselines or {})
        self.scorings_after = scorings_after
        self.counts: dict[str, int] | None = None
        self._baseline_scores: dict[str, Scores] | None = None
        self._view_cost = ViewCost()
        self._render_seconds = 0.0  # a candidate's render in one view, as last measured
        self._metric_seconds = 0.0  # the protocol metrics of one view, as last measured
        self._q_metrics: dict[bytes, dict[str, float]] = {}  # validated candidates' Q metrics

    @property
    def frozen(self) -> bool:
        return self.counts is not None

    @property
    def complete(self) -> bool:
        """Every view of every set is cached."""
        return all(cache.views.complete for cache in self.sets.values())

    @property
    def num_views(self) -> int:
        """Views validated on: the frozen counts, or all that are cached."""
        return sum(self.counts.values()) if self.counts else sum(map(len, self.sets.values()))

    @property
    def view_cost(self) -> float:
        """Mean seconds to cache one validation view with its taps (0 before one is cached)."""
        return self._view_cost.mean

    @property
    def planned(self) -> int:
        """Views of every set, cached or not."""
        return sum(len(cache.views.cameras) for cache in self.sets.values())

    def cache_next(self) -> bool:
        """Cache one view, and its taps, in the set with the fewest views cached (the first of
        :data:`SET_NAMES` on a tie); False when there is nothing left to cache (every set
        complete, or frozen).

        Fewest, not the smallest share: a candidate ships only where it clears the floor on
        every set (:func:`paired_gap`), so the set with the fewest views decides, and its
        margin grows fast as its views get few: caching by shares leaves the guards too few
        (see docs/decisions/validation-guard-sets.md)."""
        if self.frozen:
            return False
        waiting = [name for name, cache in self.sets.items() if not cache.views.complete]
        if not waiting:
            return False
        name = min(waiting, key=lambda n: len(self.sets[n]))
        started = self.clock.now()
        cache = self.sets[name]
        cache.views.cache_next()
        cache.find_taps(len(cache) - 1)
        self._view_cost.add(self.clock.now() - started)
        if not self._render_seconds:
            self._measure(cache)
        return True

    def cache_all(self) -> None:
        """Cache every view of every set (nothing once frozen)."""
        while self.cache_next():
            pass

    def find_taps(self) -> None:
        """Find the taps of every view validated on (the frozen ones), which the first
        validation would find otherwise."""
        self.freeze()
        for name, cache in self.sets.items():
            cache.find_taps(self.counts[name] - 1)

    def freeze(self, least: Mapping[str, int] = MIN_FROZEN) -> None:
        """Validate on the views cached so far from now on, caching first the ``least`` views of
        each set (:data:`MIN_FROZEN`; a set not named there: none more)."""
        if self.frozen:
            return
        for name, cache in self.sets.items():
            while len(cache) < least.get(name, 0) and cache.views.cache_next():
                pass
        self.counts = {name: len(cache) for name, cache in self.sets.items()}

    @torch.no_grad()
    def psnr(self, textures: Sequence[torch.Tensor | None], uvs: torch.Tensor | None) -> Scores:
        """Mean PSNR-fg of a candidate per set over its frozen views, with the per-view values
        (:class:`Scores`).

        On Q all the protocol metrics are computed from the same renders and kept, so that
        :meth:`score` of the candidate's 8-bit textures on Q (a report's row) renders nothing
        again.

        Args:
            textures: per material the ``(h, w, 3)`` linear texture as it ships (8-bit
                quantised) or None.
            uvs: UVs (:meth:`geoscaler.render.renderer.Renderer.footprint`), or None for the mesh's
            own.
        """
        self.freeze()
        mips = mip_chains(textures)
        scores, per_view = {}, {}
        render_seconds = metric_seconds = 0.0
        self.find_taps()  # once per view: not a render's unit cost
        for name, cache in self.sets.items():
            values = []
            for view in range(self.counts[name]):
                reference, foreground = cache.views.reference(view)
                started = self.clock.now()
                image = cache.render(view, mips, uvs)
                rendered = self.clock.now()
                if name == "Q":
                    values.append(evaluate(image[None], reference[None], foreground[None]))
                    metric_seconds += self.clock.now() - rendered
                else:
                    values.append(psnr_fg(image[None], reference[None], foreground[None]))
                render_seconds += rendered - started
            if name == "Q":
                metrics = {k: torch.cat([v[k] for v in values]) for k in values[0]}
                self._q_metrics[_fingerprint(_codes(textures), uvs)] = mean_metrics(metrics)
                values = [metrics["psnr_fg"]]
            psnrs = torch.cat(values)
            per_view[name] = psnrs.double().cpu().numpy()
            scores[name] = float(psnrs.nanmean())  # nan: no foreground
        # the unit costs follow the machine: what this validation took, not the first probe
        self._render_seconds = render_seconds / self.num_views
        self._metric_seconds = metric_seconds / max(self.counts["Q"], 1)
        return Scores(scores, per_view)

    def score(
        self,
        textures: Sequence[np.ndarray | None],
        uvs: np.ndarray | None = None,
        sets: Sequence[str] | None = None,
    ) -> dict[str, dict[str, float]]:
        """Set name -> mean protocol metrics of 8-bit textures (and UVs) over its frozen views,
        for the ``sets`` named (all by default). On Q, textures validated before (a learned
        method's best, the baselines) are not rendered again: :meth:`psnr` kept their metrics."""
        self.freeze()
        colours = [None if t is None else to_rgb(t) for t in textures]  # what renders
        scores = {}
        for name in self.sets if sets is None else sets:
            validated = self._q_metrics.get(_fingerprint(colours, uvs)) if name == "Q" else None
            scores[name] = validated or mean_metrics(
                self.sets[name].score(textures, uvs, self.counts[name])
            )
        return scores

    def baseline_scores(self) -> dict[str, Scores]:
        """Baseline name -> its :meth:`psnr` (scored once, after the sets are frozen)."""
        if self._baseline_scores is None:
            device = next(iter(self.sets.values())).renderer.device
            self._baseline_scores = {
                name: self.psnr(
                    [
                        None if t is None else texture_to_linear(t[..., :3], device)
                        for t in textures
                    ],
                    None,
                )
                for name, textures in self.baselines.items()
            }
        return self._baseline_scores

    def floor(self) -> dict[str, Scores]:
        """Set name -> the scores of the best baseline there (by its mean; empty without
        baselines)."""
        scores = self.baseline_scores()
        if not scores:
            return {}
        return {name: max(scores.values(), key=lambda s: _ranked(s[name])) for name in self.sets}

    def shortfall(self, scores: Mapping[str, float]) -> float:
        """How far (dB, <= 0) a candidate falls below the floor on its worst set
        (:func:`paired_gap`): 0 when it clears the best baseline on every set (a set with
        nothing in view, nan, says nothing)."""
        gaps = [paired_gap(scores, floor, name) for name, floor in self.floor().items()]
        return min([0.0, *(gap for gap in gaps if gap == gap)])

    def rank(self, scores: Scores) -> tuple[float, float]:
        """The order candidates are chosen in: the smallest :meth:`shortfall`, then the best
        PSNR-fg on Q. A candidate that clears the floor outranks every one that does not."""
        return self.shortfall(scores), scores["Q"]

    def seconds_needed(
        self,
        validations: int,
        caching: bool,
        view_seconds: float = 0.0,
        least: Mapping[str, int] = MIN_FROZEN,
    ) -> float:
        """An estimate of the seconds to finish: ``validations`` candidate validations (a
        render in every view, the metrics in Q's), the baselines' if not yet scored, the
        caller's scorings after (counted as one more computation of Q's metrics: they reuse
        the validation's renders, see :meth:`score`), and (``caching``) the views
        :meth:`freeze` must still cache to have ``least`` views in each set, each taking
        ``view_seconds`` until one of these views is cached and timed (the renders are not
        counted before)."""
        if self._baseline_scores is None:
            validations += len(self.baselines)
        q_views = self.counts["Q"] if self.counts else len(self.sets["Q"])
        seconds = self.num_views * validations * self._render_seconds
        seconds += q_views * (validations + self.scorings_after) * self._metric_seconds
        if caching and not self.frozen:
            wanted = {n: min(least.get(n, 0), len(c.views.cameras)) for n, c in self.sets.items()}
            missing = (max(wanted[n] - len(c), 0) for n, c in self.sets.items())
            seconds += (self._view_cost.mean or view_seconds) * sum(missing)
        return seconds

    @torch.no_grad()
    def _measure(self, cache: ViewCache) -> None:
        """Time a candidate's render and the protocol metrics in the first cached view: the
        unit costs until the first validation measures them again."""
        device = cache.renderer.device
        probe = [None if s is None else torch.zeros(*s, 3, device=device) for s in self.sizes]
        started = self.clock.now()
        image = cache.render(0, probe, None)
        self._render_seconds = self.clock.now() - started
        reference, foreground = cache.views.reference(0)
        started = self.clock.now()
        evaluate(image[None], reference[None], foreground[None])
        self._metric_seconds = self.clock.now() - started


def _ranked(value: float) -> float:
    """A mean PSNR for ordering: nan (nothing in view) last."""
    return value if value == value else -math.inf


def _codes(textures: Sequence[torch.Tensor | None]) -> list[np.ndarray | None]:
    """8-bit quantised linear textures as the 8-bit sRGB codes they ship as."""
    return [None if t is None else linear_to_texture(t) for t in textures]


def _fingerprint(
    textures: Sequence[np.ndarray | None], uvs: torch.Tensor | np.ndarray | None
) -> bytes:
    """A digest of 8-bit textures (and UVs): equal digests, equal candidates."""
    digest = hashlib.blake2b(digest_size=20)
    for texture in textures:
        digest.update(b"-" if texture is None else np.ascontiguousarray(texture).tobytes())
    if uvs is not None:
        uvs = uvs.detach().cpu().numpy() if isinstance(uvs, torch.Tensor) else uvs
        digest.update(np.ascontiguousarray(uvs, dtype=np.float32).tobytes())
    return digest.digest()


class Best:
    """The best validated candidate so far, by :meth:`Validation.rank`: the best on Q of those
    that clear the floor, or the one that falls least below it (what the optimisation loop
    keeps)."""

    def __init__(self, validation: Validation):
        self.validation = validation
        self.scores: dict[str, float] = {}
        self.rank = (-math.inf, -math.inf)
        self.step = -1
        self.stale = 0
        self.textures: list[torch.Tensor | None] = []
        self.uvs: torch.Tensor | None = None
        self.has_start = False

    @property
    def psnr(self) -> float:
        return self.scores.get("Q", -math.inf)

    @property
    def clears(self) -> bool:
        return self.rank[0] == 0.0

    def offer(
        self,
        scores: dict[str, float],
        candidate: tuple[list[torch.Tensor | None], torch.Tensor | None],
        step: int,
    ) -> bool:
        """Keep ``candidate`` (finished, as validated) if it ranks above the best."""
        self.has_start = self.has_start or step == 0
        rank = self.validation.rank(scores)
        if rank <= self.rank:
            self.stale += 1
            return False
        self.textures, self.uvs = candidate
        self.scores, self.rank, self.step, self.stale = scores, rank, step, 0
        return True
