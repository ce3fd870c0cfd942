"""What validation costs, in seconds: the unit costs of caching a validation view, rendering a
candidate in one and computing the protocol metrics of one, and the estimate a budget keeps
time by (:meth:`UnitCosts.seconds_needed`)."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from geoscaler.clock import Clock
from geoscaler.render.metrics import evaluate
from geoscaler.render.views import ViewCache


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


class UnitCosts:
    """The unit costs of validation, as last measured.

    Attributes:
        view_cost: seconds to cache one view with its taps (:class:`ViewCost`).
        tap_cost: seconds of those to find its taps.
        render_seconds: seconds to render a candidate in one view (0.0 before measured).
        metric_seconds: seconds to compute the protocol metrics of one view (0.0 before).
    """

    def __init__(self) -> None:
        self.view_cost = ViewCost()
        self.tap_cost = ViewCost()
        self.render_seconds = 0.0
        self.metric_seconds = 0.0

    def seconds_needed(
        self,
        views: int,
        q_views: int,
        validations: int,
        scorings_after: int = 0,
        to_cache: int | None = None,
        view_seconds: float = 0.0,
    ) -> float:
        """Seconds for ``validations`` candidate validations (a render in each of ``views``
        views, the metrics in the ``q_views`` of Q), ``scorings_after`` more computations of
        Q's metrics, and (``to_cache`` not None) ``to_cache`` views still to cache, each at the
        mean view cost, or ``view_seconds`` before a view is timed."""
        seconds = views * validations * self.render_seconds
        seconds += q_views * (validations + scorings_after) * self.metric_seconds
        if to_cache is not None:
            seconds += (self.view_cost.mean or view_seconds) * to_cache
        return seconds

    @torch.no_grad()
    def measure(
        self, cache: ViewCache, sizes: Sequence[tuple[int, int] | None], clock: Clock
    ) -> None:
        """Time a candidate's render (blank textures of ``sizes``, per material ``(h, w)`` or
        None) and the protocol metrics in the first cached view of ``cache``, on ``clock``:
        the unit costs until the first validation measures them again."""
        device = cache.renderer.device
        probe = [None if s is None else torch.zeros(*s, 3, device=device) for s in sizes]
        started = clock.now()
        image = cache.render(0, probe, None)
        self.render_seconds = clock.now() - started
        reference, foreground = cache.views.reference(0)
        started = clock.now()
        evaluate(image[None], reference[None], foreground[None])
        self.metric_seconds = clock.now() - started
