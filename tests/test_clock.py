"""The clock and its budgets, on a clock the test moves by hand."""

import math

import pytest

from geoscaler.clock import Budget, ManualClock, WallClock


def test_a_manual_clock_moves_only_forward_and_only_when_told():
    clock = ManualClock(10.0)
    assert clock.now() == 10.0
    clock.advance(2.5)
    clock.set(20.0)
    assert clock.now() == 20.0
    with pytest.raises(ValueError):
        clock.advance(-1.0)


def test_a_budget_counts_from_its_start_and_keeps_its_reserve():
    clock = ManualClock(100.0)
    budget = Budget(clock, start=95.0, seconds=60.0, reserve=10.0)
    assert budget.elapsed() == 5.0
    assert budget.end == 145.0
    assert budget.left() == 45.0
    assert budget.fits(45.0) and not budget.fits(45.5)
    clock.advance(46.0)
    assert budget.expired() and budget.left() == -1.0


def test_an_unlimited_budget_fits_everything():
    budget = Budget.from_now(ManualClock(), None)
    assert not budget.limited and budget.left() == math.inf
    assert budget.fits(1e12) and not budget.expired()
    assert budget.share(0.5).seconds is None and budget.until(50.0).seconds == 50.0


def test_a_share_and_a_limit_are_counted_from_now():
    clock = ManualClock(0.0)
    budget = Budget(clock, 0.0, 100.0, reserve=20.0)
    clock.advance(40.0)
    share = budget.share(0.25)  # a quarter of the 40 s left before the reserve
    assert (share.start, share.seconds, share.end) == (40.0, 10.0, 50.0)
    assert budget.until(60.0).end == 60.0 and budget.until(90.0).end == 80.0
    assert budget.keeping(5.0).end == 75.0


def test_the_wall_clock_runs_and_the_process_started_before_now():
    clock = WallClock()
    first = clock.now()
    assert clock.process_start() <= first <= clock.now()
