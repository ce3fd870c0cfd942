"""The floor a candidate must clear: per validation set the best baseline's scores, and how far
(dB) a candidate falls below it.

A set has few views under a budget and the per-view differences between two textures are
large (1.5 dB on a scan seen from far away), so a candidate clears the floor on a set only
where its mean gain over the floor's baseline, view by view, clears zero with
:data:`FLOOR_CONFIDENCE` (:func:`paired_gap`). Scores with means alone (no per-view values) are
compared by the difference of their means, by name (:func:`mean_gap`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import numpy as np

FLOOR_CONFIDENCE = 0.5 * (1.0 + math.erf(1.0 / math.sqrt(2.0)))
"""One-sided confidence (0.84) with which a candidate's mean per-view gain over the floor's
baseline must clear zero on each set: the mean less Student's t quantile for the views' count
(:func:`floor_margin`) times its standard error. On many views that is one standard error; on
the few views a short budget validates on, t widens it (1.84 for 2), since a few views' mean
can disagree with the protocol's full set (``benchmarks/budget.py``; see
docs/decisions/validation-floor-confidence.md)."""


@functools.cache
def floor_margin(views: int) -> float:
    """Standard errors by which a mean gain over ``views`` (>= 2) views must clear zero: the
    :data:`FLOOR_CONFIDENCE` quantile of Student's t with ``views - 1`` degrees of freedom.
    (scipy.special is imported here, at the first validation: 0.27 s a job without one, such
    as a filter's, need not wait for.)"""
    from scipy.special import stdtrit

    return float(stdtrit(views - 1, FLOOR_CONFIDENCE))


class Scores(dict):
    """Set name -> mean PSNR-fg (dB) over the set's frozen views, a plain dict for reports;
    ``per_view`` keeps each set's ``(N,)`` per-view values for :func:`paired_gap` (empty for
    scores made elsewhere: then only the means are compared, by :func:`mean_gap`)."""

    def __init__(self, means: Mapping[str, float], per_view: Mapping[str, np.ndarray] = ()):
        super().__init__(means)
        self.per_view = dict(per_view)


def per_view(scores: Mapping[str, float], name: str) -> np.ndarray | None:
    """The ``(N,)`` per-view values (dB) of set ``name`` in ``scores``; None where it has only
    the mean (a plain mapping, or :class:`Scores` without that set's values)."""
    return getattr(scores, "per_view", {}).get(name)


def mean_gap(candidate: Mapping[str, float], floor: Mapping[str, float], name: str) -> float:
    """How far (dB) a candidate's mean is above the floor's on set ``name``: the difference of
    the means, for scores without per-view values (no noise to allow for)."""
    return candidate[name] - floor[name]


def paired_gap(candidate: Mapping[str, float], floor: Mapping[str, float], name: str) -> float:
    """How far (dB) a candidate is above the floor's baseline on set ``name``: the mean of its
    per-view gains less :func:`floor_margin` standard errors of them (views without foreground
    left out). A baseline paired with itself gains 0 exactly. nan: no view of the set shows
    the mesh.

    Raises:
        ValueError: either side has no per-view values of the set (compare means with
            :func:`mean_gap`), or they are of different lengths (not the same views).
    """
    mine, theirs = per_view(candidate, name), per_view(floor, name)
    for side, values in (("candidate", mine), ("floor", theirs)):
        if values is None:
            raise ValueError(
                f"paired_gap: the {side} has no per-view values of set {name!r}; "
                "compare means alone with mean_gap"
            )
    if len(mine) != len(theirs):
        raise ValueError(
            f"paired_gap: set {name!r} has {len(mine)} per-view values in the candidate and "
            f"{len(theirs)} in the floor: not the same views"
        )
    return _gain_less_margin((mine - theirs)[np.isfinite(mine) & np.isfinite(theirs)])


def _gain_less_margin(gains: np.ndarray) -> float:
    """The mean of ``(N,)`` per-view gains (dB) less :func:`floor_margin` standard errors: the
    gain itself for one view, nan for none."""
    if len(gains) == 0:
        return math.nan
    if len(gains) == 1:
        return float(gains[0])
    error = gains.std(ddof=1) / math.sqrt(len(gains))
    return float(gains.mean() - floor_margin(len(gains)) * error)


def sets_below(candidate: Scores, reference: Scores) -> list[str]:
    """The sets on which ``candidate`` is below ``reference`` beyond the noise: the reference's
    :func:`paired_gap` over the candidate is positive (sets neither shows, nan, say nothing).
    Both need per-view values of every set the candidate names."""
    return [name for name in candidate if paired_gap(reference, candidate, name) > 0]


class Floor:
    """Per set the scores of the best baseline there, and a candidate's standing against them.

    Args:
        baselines: baseline name -> its :class:`Scores` (per-view values of every set).
        sets: the set names the floor is taken on.

    Attributes:
        best: set name -> the :class:`Scores` of the best baseline there, by its mean (a nan
            mean, nothing in view, last); empty without baselines.
    """

    def __init__(self, baselines: Mapping[str, Scores], sets: Sequence[str]):
        self.best: dict[str, Scores] = {}
        if baselines:
            self.best = {
                name: max(baselines.values(), key=lambda s, n=name: _ranked(s[n])) for name in sets
            }

    def gap(self, scores: Mapping[str, float], name: str) -> float:
        """How far (dB) ``scores`` is above the floor on set ``name``: :func:`paired_gap` where
        the candidate has per-view values of the set, :func:`mean_gap` where it has its mean
        alone."""
        if per_view(scores, name) is None:
            return mean_gap(scores, self.best[name], name)
        return paired_gap(scores, self.best[name], name)

    def shortfall(self, scores: Mapping[str, float]) -> float:
        """How far (dB, <= 0) a candidate falls below the floor on its worst set (:meth:`gap`):
        0 when it clears the best baseline on every set (a set with nothing in view, nan, says
        nothing)."""
        gaps = [self.gap(scores, name) for name in self.best]
        return min([0.0, *(gap for gap in gaps if gap == gap)])

    def rank(self, scores: Mapping[str, float]) -> tuple[float, float]:
        """The order candidates are chosen in: the smallest :meth:`shortfall` (dB), then the
        best PSNR-fg (dB) on Q. A candidate that clears the floor outranks every one that does
        not."""
        return self.shortfall(scores), scores["Q"]


def _ranked(value: float) -> float:
    """A mean PSNR for ordering: nan (nothing in view) last."""
    return value if value == value else -math.inf
