"""The optimisation loop's learning-rate schedule: a linear warm-up, then a cosine decay that
follows whichever runs out first, the steps or the time budget, with a boost for runs that the
budget cuts short."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Schedule:
    """The factor on the peak learning rate at each step.

    Attributes:
        steps: the step limit.
        warmup_steps: steps of the linear warm-up.
        time_budget: wall-clock seconds of the whole run (None: none).
        short_run_boost: at most this factor when the budget allows fewer steps than
            ``steps`` (1: none; :meth:`boost`).
    """

    steps: int
    warmup_steps: int
    time_budget: float | None = None
    short_run_boost: float = 1.0

    def time_spent(self, now: float, start: float, loop_start: float) -> float:
        """Fraction of the optimisation's share of the budget used at ``now``: the share runs
        from the first step (``loop_start``) to the budget's end, counted from ``start`` (all
        instants on one clock, in seconds; 0 without a budget)."""
        if self.time_budget is None:
            return 0.0
        span = start + self.time_budget - loop_start
        return 1.0 if span <= 0 else (now - loop_start) / span

    def factor(self, step: int, time_spent: float) -> float:
        """Linear warm-up over ``warmup_steps``, then cosine decay to 0, times :meth:`boost`.

        The decay follows whichever runs out first, the steps or the time budget (so a
        budgeted run ends at a low learning rate too); with a budget the schedule, and so the
        result, depends on the machine's speed.
        """
        boost = self.boost(step, time_spent)
        if step < self.warmup_steps:
            return boost * (step + 1) / self.warmup_steps
        span = max(self.steps - self.warmup_steps, 1)
        progress = max((step - self.warmup_steps) / span, time_spent)
        return boost * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))

    def boost(self, step: int, time_spent: float) -> float:
        """``sqrt(steps / expected steps)``, at most ``short_run_boost``: Adam moves a
        parameter by about the learning rate a step, so a run the budget allows fewer steps
        than ``steps`` takes larger ones. The expected steps are those made so far over the
        budget's share spent (1 without a budget, or before the first step is timed)."""
        if self.short_run_boost <= 1 or time_spent <= 0 or step < 1:
            return 1.0
        expected = min(step / time_spent, self.steps)
        return min(self.short_run_boost, math.sqrt(self.steps / expected))
