"""What a learned method validates on, and the floor its result must clear.

:class:`Validation` composes four parts, each its own class:

- :class:`~geoscaler.optim.validation_views.ValidationViews`: three view sets (Q and the near
  and far guards), cached between the loop's steps (:meth:`Validation.cache_next`) and, under
  a time budget, *frozen* at the views cached by then (:meth:`Validation.freeze`), so that
  every candidate is compared on the same views;
- :class:`~geoscaler.optim.unit_costs.UnitCosts`: the unit costs of caching a view, rendering
  a candidate and scoring it, and the seconds validation still needs
  (:meth:`Validation.seconds_needed`);
- :class:`QMetricsMemo`: the protocol metrics on Q of each candidate validated, by a digest of
  its 8-bit textures, so that its report row renders nothing again (:meth:`Validation.score`);
- :class:`~geoscaler.optim.floor.Floor`: the filters the job runs beside the method (its
  *baselines*) are scored on the frozen sets; per set the best of them is the *floor*, and
  candidates are ranked by how far they fall below it on their worst set, then by Q
  (:meth:`Validation.rank`), the gain on a set taken view by view with
  :data:`~geoscaler.optim.floor.FLOOR_CONFIDENCE` (:func:`~geoscaler.optim.floor.paired_gap`).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence

import numpy as np
import torch

from geoscaler.clock import WALL_CLOCK, Clock
from geoscaler.color import linear_to_texture, texture_to_linear, to_rgb
from geoscaler.optim.floor import (
    FLOOR_CONFIDENCE,
    Floor,
    Scores,
    floor_margin,
    mean_gap,
    paired_gap,
    sets_below,
)
from geoscaler.optim.unit_costs import UnitCosts, ViewCost
from geoscaler.optim.validation_views import (
    GUARD_VIEWS,
    MIN_FROZEN,
    SET_NAMES,
    ValidationViews,
    guard_cameras,
    validation_view_sets,
)
from geoscaler.render.metrics import evaluate, mean_metrics, psnr_fg
from geoscaler.render.views import ViewCache, ViewSet, mip_chains

__all__ = [
    "FLOOR_CONFIDENCE",
    "GUARD_VIEWS",
    "MIN_FROZEN",
    "SET_NAMES",
    "Best",
    "Floor",
    "QMetricsMemo",
    "Scores",
    "UnitCosts",
    "Validation",
    "ValidationViews",
    "ViewCost",
    "floor_margin",
    "guard_cameras",
    "mean_gap",
    "paired_gap",
    "sets_below",
    "validation_view_sets",
]


class QMetricsMemo:
    """The mean protocol metrics on Q of candidates validated, by a digest of their 8-bit
    textures (and UVs): equal digests, equal candidates, the same metrics."""

    def __init__(self) -> None:
        self._metrics: dict[bytes, dict[str, float]] = {}

    def keep(
        self,
        codes: Sequence[np.ndarray | None],
        uvs: torch.Tensor | np.ndarray | None,
        metrics: dict[str, float],
    ) -> None:
        """Keep ``metrics`` (metric name -> mean over Q's frozen views) of the candidate whose
        textures are the 8-bit sRGB ``(h, w, 3)`` ``codes`` (None: untextured) with ``uvs``."""
        self._metrics[_fingerprint(codes, uvs)] = metrics

    def get(
        self, codes: Sequence[np.ndarray | None], uvs: torch.Tensor | np.ndarray | None
    ) -> dict[str, float] | None:
        """The metrics kept for the candidate ``codes`` with ``uvs``; None: never validated."""
        return self._metrics.get(_fingerprint(codes, uvs))


class _Seconds:
    """Seconds summed over one validation's views: renders and Q's metrics."""

    def __init__(self) -> None:
        self.render = self.metric = 0.0


class Validation:
    """The validation sets of one output size, the baselines and their floor: the composition
    of :class:`ValidationViews`, :class:`UnitCosts`, :class:`QMetricsMemo` and :class:`Floor`
    that the loop, the job and the methods use.

    Args:
        views: set name -> its views (:func:`validation_view_sets`), in :data:`SET_NAMES`.
        sizes: per material the output texture ``(h, w)`` (None: untextured).
        baselines: filter name -> its 8-bit output textures, scored once the sets are frozen.
        scorings_after: full-metric scorings of Q's frozen views the caller will run after
            the method (a downsampling job's report: the result and each baseline); the loop
            keeps time for them under a budget (validated textures are not rendered again).
        clock: what the unit costs of caching, rendering and scoring are timed on.

    Attributes:
        views: the sets' caches, cached and frozen (:class:`ValidationViews`).
        costs: the unit costs (:class:`UnitCosts`).
        memo: validated candidates' Q metrics (:class:`QMetricsMemo`).
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
        self.costs = UnitCosts()
        self.memo = QMetricsMemo()
        self._baseline_scores: dict[str, Scores] | None = None

    # ------------------------------------------------------------------ the views

    @property
    def sets(self) -> dict[str, ViewCache]:
        return self.views.sets

    @sets.setter
    def sets(self, sets: dict[str, ViewCache]) -> None:
        """New caches of the sets (another layout's taps of the same views): the frozen counts
        stay."""
        views = getattr(self, "views", None)
        if views is None:
            self.views = ValidationViews(sets)
        else:
            views.sets = dict(sets)

    @property
    def counts(self) -> dict[str, int] | None:
        return self.views.counts

    @counts.setter
    def counts(self, counts: dict[str, int] | None) -> None:
        self.views.counts = counts

    @property
    def frozen(self) -> bool:
        return self.counts is not None

    @property
    def complete(self) -> bool:
        """Every view of every set is cached."""
        return self.views.complete

    @property
    def num_views(self) -> int:
        """Views validated on: the frozen counts, or all that are cached."""
        return self.views.num_views

    @property
    def planned(self) -> int:
        """Views of every set, cached or not."""
        return self.views.planned

    def cache_next(self) -> bool:
        """Cache one view, and its taps, in the set with the fewest views cached
        (:meth:`ValidationViews.next_set`), timing it; False when there is nothing left to
        cache (every set complete, or frozen)."""
        name = None if self.frozen else self.views.next_set()
        if name is None:
            return False
        started = self.clock.now()
        cache, tapping = self.views.cache_view(name, self.clock)
        self.costs.view_cost.add(self.clock.now() - started)
        self.costs.tap_cost.add(tapping)
        if not self.costs.render_seconds:
            self.costs.measure(cache, self.sizes, self.clock)
        return True

    @property
    def lacks_least(self) -> bool:
        """Not frozen, and some set still lacks the views any validation needs
        (:data:`MIN_FROZEN`, which :meth:`freeze` would cache first)."""
        return not self.frozen and self.views.to_cache() > 0

    def cache_all(self) -> None:
        """Cache every view of every set (nothing once frozen)."""
        while self.cache_next():
            pass

    def find_taps(self) -> None:
        """Find the taps of every view validated on (the frozen ones), which the first
        validation would find otherwise."""
        self.freeze()
        self.views.find_taps()

    def drop_taps(self) -> None:
        """Forget every view's taps (:meth:`ViewCache.drop_taps`; found again as each view is
        next rendered); the views, their counts and the scores kept stay."""
        for cache in self.sets.values():
            cache.drop_taps()

    def freeze(self, least: Mapping[str, int] = MIN_FROZEN) -> None:
        """Validate on the views cached so far from now on, caching first the ``least`` views of
        each set (:data:`MIN_FROZEN`; a set not named there: none more)."""
        if self.frozen:
            return
        self.views.freeze(least)

    # ------------------------------------------------------------------ the unit costs

    @property
    def view_cost(self) -> float:
        """Mean seconds to cache one validation view with its taps (0 before one is cached)."""
        return self.costs.view_cost.mean

    @property
    def tap_cost(self) -> float:
        """Mean seconds to find one validation view's taps, part of :attr:`view_cost` (0 before
        one is cached): what a view costs a new UV layout of the mesh, whose G-buffer and
        reference are the same."""
        return self.costs.tap_cost.mean

    @property
    def missing_taps(self) -> int:
        """Frozen views whose taps are not found (0 before the validation freezes)."""
        if not self.frozen:
            return 0
        return sum(max(self.counts[n] - len(c.taps), 0) for n, c in self.sets.items())

    def taps_seconds(self, views: int, view_seconds: float = 0.0) -> float:
        """Seconds to find the taps of ``views`` views whose G-buffers and references are
        cached: the mean taps' seconds a view, or a whole view's cost until a view's taps are
        timed (``view_seconds`` before either)."""
        return views * (self.tap_cost or self.view_cost or view_seconds)

    @property
    def _view_cost(self) -> ViewCost:
        return self.costs.view_cost

    @property
    def _render_seconds(self) -> float:
        return self.costs.render_seconds

    @_render_seconds.setter
    def _render_seconds(self, seconds: float) -> None:
        self.costs.render_seconds = seconds

    @property
    def _metric_seconds(self) -> float:
        return self.costs.metric_seconds

    @_metric_seconds.setter
    def _metric_seconds(self, seconds: float) -> None:
        self.costs.metric_seconds = seconds

    def seconds_needed(
        self,
        validations: int,
        caching: bool,
        view_seconds: float = 0.0,
        least: Mapping[str, int] = MIN_FROZEN,
    ) -> float:
        """An estimate of the seconds to finish (:meth:`UnitCosts.seconds_needed`):
        ``validations`` candidate validations (a render in every view, the metrics in Q's), the
        baselines' if not yet scored, the caller's scorings after (counted as one more
        computation of Q's metrics: they reuse the validation's renders, see :meth:`score`),
        and (``caching``) the views :meth:`freeze` must still cache to have ``least`` views in
        each set, each taking ``view_seconds`` until one of these views is cached and timed
        (the renders are not counted before); and the taps the next validation finds in
        frozen views that have none (:attr:`missing_taps`: views :meth:`freeze` cached, or
        whose taps :meth:`drop_taps` forgot; :meth:`taps_seconds`). Priced at the unit costs
        of :attr:`pricing`."""
        source = self.pricing
        if source._baseline_scores is None:
            validations += len(source.baselines)
        to_cache = source.views.to_cache(least) if caching and not source.frozen else None
        work = source.costs.seconds_needed(
            source.num_views,
            source.views.q_views,
            validations,
            scorings_after=source.scorings_after,
            to_cache=to_cache,
            view_seconds=view_seconds,
        )
        return work + self.taps_seconds(self.missing_taps, view_seconds)

    @property
    def pricing(self) -> Validation:
        """The validation whose unit costs, views and baselines price this one's work: itself."""
        return self

    # ------------------------------------------------------------------ scoring

    @torch.no_grad()
    def psnr(self, textures: Sequence[torch.Tensor | None], uvs: torch.Tensor | None) -> Scores:
        """Mean PSNR-fg of a candidate per set over its frozen views, with the per-view values
        (:class:`Scores`).

        On Q all the protocol metrics are computed from the same renders and kept
        (:class:`QMetricsMemo`), so that :meth:`score` of the candidate's 8-bit textures on Q
        (a report's row) renders nothing again. The unit costs of a render and of Q's metrics
        are measured again from it.

        Args:
            textures: per material the ``(h, w, 3)`` linear texture as it ships (8-bit
                quantised) or None.
            uvs: UVs (:meth:`geoscaler.render.renderer.Renderer.footprint`), or None for the mesh's
            own.
        """
        self.freeze()
        mips = mip_chains(textures)
        scores, per_view = {}, {}
        seconds = _Seconds()
        self.find_taps()  # once per view: not a render's unit cost
        for name, cache in self.sets.items():
            values = self._view_values(name, cache, mips, uvs, seconds)
            if name == "Q":
                values = [self._keep_q_metrics(values, textures, uvs)]
            psnrs = torch.cat(values)
            per_view[name] = psnrs.double().cpu().numpy()
            scores[name] = float(psnrs.nanmean())  # nan: no foreground
        # the unit costs follow the machine: what this validation took, not the first probe
        self.costs.render_seconds = seconds.render / self.num_views
        self.costs.metric_seconds = seconds.metric / max(self.counts["Q"], 1)
        return Scores(scores, per_view)

    def _view_values(
        self, name: str, cache: ViewCache, mips: list, uvs: torch.Tensor | None, seconds: _Seconds
    ) -> list:
        """Per frozen view of set ``name`` the candidate's metrics (Q: every protocol metric,
        a dict of ``(1,)`` tensors) or PSNR-fg (a ``(1,)`` tensor, dB), the seconds of its
        renders and Q's metrics added to ``seconds``."""
        values = []
        for view in range(self.counts[name]):
            reference, foreground = cache.views.reference(view)
            started = self.clock.now()
            image = cache.render(view, mips, uvs)
            rendered = self.clock.now()
            if name == "Q":
                values.append(evaluate(image[None], reference[None], foreground[None]))
                seconds.metric += self.clock.now() - rendered
            else:
                values.append(psnr_fg(image[None], reference[None], foreground[None]))
            seconds.render += rendered - started
        return values

    def _keep_q_metrics(
        self,
        values: list[dict[str, torch.Tensor]],
        textures: Sequence[torch.Tensor | None],
        uvs: torch.Tensor | None,
    ) -> torch.Tensor:
        """Keep the mean of Q's per-view protocol metrics ``values`` for the candidate in the
        memo; Q's ``(N,)`` per-view PSNR-fg (dB)."""
        metrics = {k: torch.cat([v[k] for v in values]) for k in values[0]}
        self.memo.keep(_codes(textures), uvs, mean_metrics(metrics))
        return metrics["psnr_fg"]

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
            validated = self.memo.get(colours, uvs) if name == "Q" else None
            scores[name] = validated or mean_metrics(
                self.sets[name].score(textures, uvs, self.counts[name])
            )
        return scores

    # ------------------------------------------------------------------ the floor

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

    def worst_baseline_views(self, least: Mapping[str, int] = MIN_FROZEN) -> dict[str, float]:
        """Baseline name -> its lowest PSNR-fg (dB) over the views cached (once frozen: validated
        on) in every set, views with nothing in view aside; empty until each set has its
        ``least`` views (fewer where it has fewer) or without baselines. Once frozen, read
        from :meth:`baseline_scores` (the floor needs them anyway: nothing rendered twice)."""
        if not self.frozen and self.views.to_cache(least):
            return {}
        if self.frozen:
            return {
                name: min(_finite_min(values) for values in scores.per_view.values())
                for name, scores in self.baseline_scores().items()
            }
        worst = {}
        for name, textures in self.baselines.items():
            colours = [None if t is None else to_rgb(t) for t in textures]
            lowest = math.inf
            for set_name, cache in self.sets.items():
                count = self.counts[set_name] if self.frozen else len(cache)
                values = cache.score(colours, None, count)["psnr_fg"]
                values = values[~torch.isnan(values)]
                lowest = min([lowest, *values.tolist()])
            worst[name] = lowest
        return worst

    def _floor(self) -> Floor:
        """The :class:`Floor` of the baselines on the sets."""
        return Floor(self.baseline_scores(), list(self.sets))

    def floor(self) -> dict[str, Scores]:
        """Set name -> the scores of the best baseline there (by its mean; empty without
        baselines)."""
        return self._floor().best

    def shortfall(self, scores: Mapping[str, float]) -> float:
        """How far (dB, <= 0) a candidate falls below the floor on its worst set
        (:meth:`Floor.shortfall`): 0 when it clears the best baseline on every set (a set with
        nothing in view, nan, says nothing)."""
        return self._floor().shortfall(scores)

    def rank(self, scores: Scores) -> tuple[float, float]:
        """The order candidates are chosen in: the smallest :meth:`shortfall`, then the best
        PSNR-fg on Q. A candidate that clears the floor outranks every one that does not."""
        return self.shortfall(scores), scores["Q"]


def _finite_min(values: np.ndarray) -> float:
    """The lowest of ``values`` that is not nan (views with nothing in view); inf: none."""
    values = values[~np.isnan(values)]
    return float(values.min()) if len(values) else math.inf


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
