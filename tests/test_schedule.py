"""The learning-rate schedule of the optimisation loop."""

import pytest

from geoscaler.optim.schedule import Schedule


def test_learning_rate_warms_up_then_decays_with_the_steps_or_the_time_whichever_is_further():
    schedule = Schedule(steps=110, warmup_steps=10)
    assert schedule.factor(0, 0.0) == pytest.approx(0.1)
    assert schedule.factor(9, 0.0) == pytest.approx(1.0)
    assert schedule.factor(60, 0.0) == pytest.approx(0.5)  # half the steps
    assert schedule.factor(60, 1.0) == pytest.approx(0.0)  # the time is up
    assert schedule.factor(10, 0.5) == pytest.approx(0.5)  # half the time


def test_a_run_the_budget_cuts_short_takes_larger_steps_up_to_the_boost():
    schedule = Schedule(steps=301, warmup_steps=1, short_run_boost=2.0)
    # 100 steps in half the time: 200 expected of 301, sqrt(301 / 200) times the rate
    assert schedule.factor(100, 0.5) == pytest.approx((301 / 200) ** 0.5 * 0.5)
    # 10 steps in half the time: 20 expected, sqrt(15.05) capped at 2
    assert schedule.factor(10, 0.5) == pytest.approx(2.0 * 0.5)
    # on pace for every step, without a budget (no time spent), or no boost allowed: none
    assert schedule.factor(151, 0.5) == pytest.approx(0.5)
    assert schedule.factor(151, 0.0) == pytest.approx(0.5)
    unboosted = Schedule(steps=301, warmup_steps=1)
    assert unboosted.factor(10, 0.5) == pytest.approx(0.5)


def test_the_schedule_spends_the_time_left_after_caching():
    # a 60 s budget of which caching took 20 s: 10 s into the steps is a quarter of their time
    schedule = Schedule(steps=400, warmup_steps=10, time_budget=60.0)
    assert schedule.time_spent(130.0, 100.0, 120.0) == pytest.approx(0.25)
    assert schedule.time_spent(161.0, 100.0, 170.0) == 1.0  # caching used the whole budget
    assert Schedule(110, 10).time_spent(130.0, 100.0, 120.0) == 0.0
