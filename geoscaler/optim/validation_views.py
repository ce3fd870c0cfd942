"""The three validation view sets, and their caching and freezing.

Each set is a :class:`~geoscaler.render.views.ViewCache` with the taps of the output sizes:

- ``Q``: the protocol's validation set (the evaluation's views) in
  :func:`~geoscaler.render.cameras.spread_order`, so that any prefix of it covers the sphere;
- ``near`` and ``far``: cameras of the loop's own (:func:`guard_cameras`) at the protocol's
  near and far distances, so that a texture is not sharpened for close views at the cost of
  distant ones. The protocol's near and far sets are not used here: they stay for evaluation.

Views are cached one at a time (:meth:`ValidationViews.cache_view`), and under a time budget
the sets are *frozen* at the views cached by then (:meth:`ValidationViews.freeze`), so that
every candidate is compared on the same views.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from geoscaler.clock import WALL_CLOCK, Clock
from geoscaler.protocol import FAR_DISTANCE, NEAR_DISTANCE, VALIDATION_DISTANCE, Evaluation
from geoscaler.render.cameras import Camera, fibonacci_directions, spread_order, view_set_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, ViewSet

GUARD_VIEWS = 20
"""Views of each guard set (near, far): the views on which a sharpened scan fails from far away
are a few directions, which a smaller set misses too easily (see
docs/decisions/validation-guard-sets.md)."""
MIN_FROZEN = {"Q": 3, "near": 3, "far": 3}
"""Views a set keeps at least when frozen (fewer where it has fewer): one view has no spread to
judge its gain by, and with two the floor's margin (:func:`~geoscaler.optim.floor.floor_margin`,
1.84 standard errors) turns away candidates well above the filters (see
docs/decisions/validation-guard-sets.md)."""
SET_NAMES = ("Q", "near", "far")


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


def validation_set_cameras(
    evaluation: Evaluation, guard_views: int = GUARD_VIEWS
) -> dict[str, list[Camera]]:
    """The three sets' cameras: Q (the views of ``evaluation``, in spread order), near and far
    guards of ``guard_views`` each."""
    q = view_set_cameras(VALIDATION_DISTANCE, evaluation)
    return {
        "Q": [q[i] for i in spread_order(len(q))],
        "near": guard_cameras(NEAR_DISTANCE, guard_views),
        "far": guard_cameras(FAR_DISTANCE, guard_views),
    }


def validation_view_sets(renderer: Renderer, guard_views: int = GUARD_VIEWS) -> dict[str, ViewSet]:
    """The three sets' views (:func:`validation_set_cameras`), none cached yet, the guards
    never more than Q has (a quick evaluation's one view gets one guard at each distance).
    Views are shared by every scale's :class:`~geoscaler.optim.validation.Validation`."""
    guard_views = min(guard_views, len(renderer.evaluation.view_indices))
    cameras = validation_set_cameras(renderer.evaluation, guard_views)
    return {name: ViewSet(renderer, cams, eager=False) for name, cams in cameras.items()}


class ValidationViews:
    """The validation sets' caches, what is cached of them and where they are frozen.

    Args:
        sets: set name -> a :class:`ViewCache` of its views with the taps of the output sizes,
            in :data:`SET_NAMES`.

    Attributes:
        sets: as given.
        counts: set name -> frozen number of views (None until :meth:`freeze`).
    """

    def __init__(self, sets: Mapping[str, ViewCache]):
        self.sets = dict(sets)
        self.counts: dict[str, int] | None = None

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
    def q_views(self) -> int:
        """Views of Q validated on: its frozen count, or those cached."""
        return self.counts["Q"] if self.counts else len(self.sets["Q"])

    @property
    def planned(self) -> int:
        """Views of every set, cached or not."""
        return sum(len(cache.views.cameras) for cache in self.sets.values())

    def next_set(self) -> str | None:
        """The set to cache a view of next: the one with the fewest views cached (the first of
        :data:`SET_NAMES` on a tie); None when there is nothing left to cache (every set
        complete, or frozen).

        Fewest, not the smallest share: a candidate ships only where it clears the floor on
        every set (:func:`~geoscaler.optim.floor.paired_gap`), so the set with the fewest views
        decides, and its margin grows fast as its views get few: caching by shares leaves the
        guards too few (see docs/decisions/validation-guard-sets.md)."""
        if self.frozen:
            return None
        waiting = [name for name, cache in self.sets.items() if not cache.views.complete]
        if not waiting:
            return None
        return min(waiting, key=lambda n: len(self.sets[n]))

    def cache_view(self, name: str, clock: Clock = WALL_CLOCK) -> tuple[ViewCache, float]:
        """Cache the next view of set ``name`` and find its taps: the set's cache and the
        seconds on ``clock`` the taps took (all a new UV layout of the same views pays)."""
        cache = self.sets[name]
        cache.views.cache_next()
        started = clock.now()
        cache.find_taps(len(cache) - 1)
        return cache, clock.now() - started

    def freeze(self, least: Mapping[str, int] = MIN_FROZEN) -> None:
        """Validate on the views cached so far from now on, caching first the ``least`` views of
        each set (:data:`MIN_FROZEN`; a set not named there: none more). Once only."""
        if self.frozen:
            return
        for name, cache in self.sets.items():
            while len(cache) < least.get(name, 0) and cache.views.cache_next():
                pass
        self.counts = {name: len(cache) for name, cache in self.sets.items()}

    def find_taps(self) -> None:
        """Find the taps of every frozen view."""
        for name, cache in self.sets.items():
            cache.find_taps(self.counts[name] - 1)

    def to_cache(self, least: Mapping[str, int] = MIN_FROZEN) -> int:
        """Views :meth:`freeze` must still cache to have ``least`` views in each set (fewer
        where a set has fewer)."""
        wanted = {n: min(least.get(n, 0), len(c.views.cameras)) for n, c in self.sets.items()}
        return sum(max(wanted[n] - len(c), 0) for n, c in self.sets.items())
