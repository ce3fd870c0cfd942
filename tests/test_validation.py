"""The validation sets a learned method is chosen on, the floor of the filters, and the budget's
account of what validation still costs."""

import math

import numpy as np
import pytest
from clocks import TickingClock

from geoscaler.color import texture_to_linear
from geoscaler.optim.validation import (
    FLOOR_CONFIDENCE,
    GUARD_VIEWS,
    Floor,
    QMetricsMemo,
    Scores,
    UnitCosts,
    Validation,
    ValidationViews,
    ViewCost,
    floor_margin,
    guard_cameras,
    mean_gap,
    paired_gap,
    sets_below,
    validation_view_sets,
)
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import FAR_DISTANCE, NEAR_DISTANCE, Evaluation
from geoscaler.render.cameras import fibonacci_directions, spread_order
from geoscaler.render.metrics import mean_metrics
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache
from geoscaler.resize.filters import bicubic, lanczos, output_sizes, reference_textures


def test_spread_order_is_a_permutation_whose_prefixes_span_the_sphere():
    order = spread_order(60)
    assert sorted(order) == list(range(60))
    assert order[:4] == [0, 23, 46, 9]  # steps of 23, coprime to 60: top, middle, bottom...
    heights = fibonacci_directions(60)[order[:6], 2]
    assert heights.max() > 0.6 and heights.min() < -0.5
    assert spread_order(1) == [0] and sorted(spread_order(12)) == list(range(12))


def test_guards_are_cameras_of_their_own_at_the_near_and_far_distances():
    protocol = fibonacci_directions(60)
    for distance in (NEAR_DISTANCE, FAR_DISTANCE):
        cameras = guard_cameras(distance)
        assert len(cameras) == GUARD_VIEWS and {c.distance for c in cameras} == {distance}
        directions = np.array([c.direction for c in cameras])
        np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
        closest = (directions @ protocol.T).max(axis=1)
        assert closest.max() < 0.9999  # none is a protocol view


def test_guards_never_outnumber_q():
    mesh = demo_mesh(subdivisions=3, texture_size=32)
    quick = validation_view_sets(Renderer(mesh, "cpu", Evaluation.quick((0, 7))))
    assert {name: len(v.cameras) for name, v in quick.items()} == {"Q": 2, "near": 2, "far": 2}
    full = validation_view_sets(Renderer(mesh, "cpu"))
    assert {name: len(v.cameras) for name, v in full.items()} == {"Q": 60, "near": 20, "far": 20}
    assert [full["Q"].cameras[i].direction for i in (0, 1)] == [
        tuple(fibonacci_directions(60)[i]) for i in (0, 23)
    ]


@pytest.fixture(scope="module")
def small():
    """The demo mesh at 4x, 32-pixel views: 6 views of Q, 2 near and 2 far guards, uncached."""
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=32, views=tuple(range(0, 60, 10))))
    return mesh, renderer


def _validation(small, **kwargs) -> Validation:
    mesh, renderer = small
    return Validation(validation_view_sets(renderer, 2), output_sizes(mesh, 4), **kwargs)


def test_views_are_cached_where_fewest_are_and_frozen_at_least_at_the_minimum(small):
    validation = _validation(small)
    assert validation.num_views == 0 and validation.planned == 10
    validation.cache_next()
    assert [len(c) for c in validation.sets.values()] == [1, 0, 0]
    validation.cache_next()
    validation.cache_next()
    assert [len(c) for c in validation.sets.values()] == [1, 1, 1]
    validation.freeze()  # Q keeps 3 at least, each guard 2
    assert validation.counts == {"Q": 3, "near": 2, "far": 2} and validation.num_views == 7
    assert not validation.cache_next() and validation.counts["Q"] == 3


def test_a_set_is_frozen_at_three_views_at_least(small):
    mesh, renderer = small
    validation = Validation(validation_view_sets(renderer, 3), output_sizes(mesh, 4))
    validation.freeze()  # nothing cached before: each set caches its three
    assert validation.counts == {"Q": 3, "near": 3, "far": 3}


def test_a_validation_for_rows_on_q_freezes_without_guard_views(small):
    validation = _validation(small)
    least = {"Q": 3}
    validation.cache_next()
    validation._view_cost.total, validation._view_cost.views = 10.0, 1  # round figures
    assert validation.seconds_needed(0, caching=True, least=least) == 2 * 10.0  # Q's two more
    validation.freeze(least)
    assert validation.counts == {"Q": 3, "near": 0, "far": 0}


def test_the_guards_get_as_many_views_as_q_until_they_are_complete(small):
    validation = _validation(small)  # Q has 6 views, each guard 2
    for _ in range(6):
        validation.cache_next()
    assert [len(c) for c in validation.sets.values()] == [2, 2, 2]
    while validation.cache_next():
        pass
    assert [len(c) for c in validation.sets.values()] == [6, 2, 2]


def test_the_floor_is_the_best_filter_on_each_set_and_the_rank_puts_clearing_it_first(small):
    mesh, _ = small
    (original,) = reference_textures(mesh)
    filters = {"bicubic": [bicubic(original, 4)], "lanczos": [lanczos(original, 4)]}
    validation = _validation(small, baselines=filters)
    validation.cache_all()
    scores = validation.baseline_scores()
    floor = validation.floor()
    assert {s: floor[s][s] for s in floor} == {
        s: max(scores["bicubic"][s], scores["lanczos"][s]) for s in floor
    }
    means = {s: floor[s][s] for s in floor}  # means alone: no per-view values to pair
    assert validation.shortfall(means) == 0.0
    below = {**means, "far": means["far"] - 0.25, "Q": means["Q"] + 2.0}
    assert validation.shortfall(below) == pytest.approx(-0.25)
    assert validation.rank(means) > validation.rank(below)  # no worse anywhere beats sharper Q
    unseen = {**below, "far": math.nan}  # nothing in view: says nothing
    assert validation.shortfall(unseen) == 0.0
    best = max(scores, key=lambda name: validation.rank(scores[name]))
    assert validation.shortfall(scores[best]) == 0.0  # the floor's baseline, paired with itself


def test_the_floor_margin_is_students_t_at_one_standard_errors_confidence():
    assert FLOOR_CONFIDENCE == pytest.approx(0.841345, abs=1e-6)  # P(Z < 1)
    p = FLOOR_CONFIDENCE
    assert floor_margin(2) == pytest.approx(math.tan(math.pi * (p - 0.5)))  # 1 degree: Cauchy
    assert floor_margin(3) == pytest.approx((2 * p - 1) / math.sqrt(2 * p * (1 - p)))
    assert floor_margin(2) > floor_margin(3) > floor_margin(20) > 1.0
    assert floor_margin(100_000) == pytest.approx(1.0, abs=1e-4)  # many views: one error


def test_a_candidate_clears_a_set_by_its_per_view_gains_less_their_margin():
    floor = Scores({"far": 60.0}, {"far": np.array([60.0, 61.0, 59.0, 60.0])})
    steady = Scores({"far": 60.5}, {"far": np.array([60.5, 61.5, 59.5, 60.5])})
    assert paired_gap(steady, floor, "far") == pytest.approx(0.5)  # no spread: the mean gain
    # Gains +3, -2, +3, -2: mean +0.5, standard deviation sqrt(25/3), standard error /2.
    noisy = Scores({"far": 60.5}, {"far": np.array([63.0, 59.0, 62.0, 58.0])})
    error = math.sqrt(25 / 3) / 2
    assert paired_gap(noisy, floor, "far") == pytest.approx(0.5 - floor_margin(4) * error)
    # Two views gaining +1.0 and +0.2: one standard error (0.4) would pass them; 1.84 do not.
    two = Scores({"far": 61.0}, {"far": np.array([61.0, 61.2, math.nan, math.nan])})
    assert paired_gap(two, floor, "far") == pytest.approx(0.6 - floor_margin(2) * 0.4)
    assert paired_gap(two, floor, "far") < 0
    # A view without foreground (nan) says nothing; one view left: its gain.
    one = Scores({"far": 61.0}, {"far": np.array([61.0, math.nan, math.nan, math.nan])})
    assert paired_gap(one, floor, "far") == pytest.approx(1.0)
    assert math.isnan(
        paired_gap(Scores({"far": math.nan}, {"far": np.full(4, math.nan)}), floor, "far")
    )
    assert mean_gap({"far": 59.0}, floor, "far") == -1.0  # means alone: their difference


def test_a_paired_gap_without_per_view_values_or_of_different_views_says_so():
    floor = Scores({"far": 60.0}, {"far": np.array([60.0, 61.0, 59.0, 60.0])})
    with pytest.raises(ValueError, match="candidate has no per-view values of set 'far'"):
        paired_gap({"far": 59.0}, floor, "far")
    with pytest.raises(ValueError, match="floor has no per-view values of set 'far'"):
        paired_gap(floor, Scores({"far": 60.0}), "far")
    three = Scores({"far": 60.0}, {"far": np.array([60.0, 61.0, 59.0])})
    with pytest.raises(ValueError, match="3 per-view values in the candidate and 4"):
        paired_gap(three, floor, "far")


def test_a_candidate_is_below_another_on_the_sets_where_that_one_clears_it():
    views = {"Q": np.array([30.0, 31.0, 29.0]), "near": np.array([28.0, 29.0, 27.0])}
    other = {**views, "far": np.array([40.0, 41.0, math.nan])}
    reference = Scores({"Q": 30.0, "near": 28.0, "far": 40.5}, other)
    # Better on Q by 1 dB in every view, 0.5 dB worse far in both views that show the mesh,
    # near: gains +1, -1, 0 (their mean, 0, clears nothing).
    candidate = Scores(
        {"Q": 31.0, "near": 28.0, "far": 40.0},
        {
            "Q": np.array([31.0, 32.0, 30.0]),
            "near": np.array([29.0, 28.0, 27.0]),
            "far": np.array([39.5, 40.5, math.nan]),
        },
    )
    assert sets_below(candidate, reference) == ["far"]
    assert sets_below(reference, candidate) == ["Q"]
    assert sets_below(reference, reference) == []  # paired with itself: a gap of 0 exactly
    # Far, -1.5 and +0.5 dB: a mean of -0.5 the noise of two views does not clear.
    noisy = Scores(candidate, {**candidate.per_view, "far": np.array([38.5, 41.5, math.nan])})
    assert sets_below(noisy, reference) == []


def test_views_still_to_cache_are_costed_at_the_mean_of_those_timed():
    cost = ViewCost()
    assert cost.mean == 0.0  # nothing timed yet
    for seconds in (0.25, 0.25, 1.0):  # one slow view among fast ones
        cost.add(seconds)
    assert cost.mean == 0.5


def test_the_budget_counts_the_validations_owed_in_views(small):
    validation = _validation(small, baselines={"lanczos": [None]}, scorings_after=2)
    assert validation.seconds_needed(1, caching=True) == 0.0  # nothing measured yet
    validation.cache_next()
    # What was measured on the first view, set to round figures to check the arithmetic:
    validation._render_seconds, validation._metric_seconds = 1, 3
    validation._view_cost.total, validation._view_cost.views = 10.0, 1
    # 1 view now (Q's); 1 own validation + 1 baseline's = 2 renders of it at 1, and Q's metrics
    # at 3 for each of them and for the 2 scorings after (which reuse the renders); while not
    # frozen, freezing must still cache 2 + 2 + 2 views.
    assert validation.seconds_needed(1, caching=False) == 1 * 2 * 1 + 1 * (2 + 2) * 3
    assert validation.seconds_needed(1, caching=True) == 14 + 6 * 10


def test_a_validated_candidates_q_row_reuses_its_renders_and_equals_a_fresh_scoring(small):
    mesh, _ = small
    validation = _validation(small)
    validation.freeze()
    shipped = [lanczos(t, 4) for t in reference_textures(mesh)]  # (16, 16, 3) uint8
    with_alpha = [np.dstack([t, np.full(t.shape[:2], 7, np.uint8)]) for t in shipped]
    validation.psnr([texture_to_linear(t) for t in shipped], None)
    q = validation.sets["Q"]
    fresh = mean_metrics(q.score(shipped, None, validation.counts["Q"]))

    def no_render(*args, **kwargs):
        raise AssertionError("a validated candidate was rendered again")

    q.render = no_render
    row = validation.score(with_alpha, None, ["Q"])["Q"]  # alpha does not render
    assert row.keys() == fresh.keys()
    assert row == pytest.approx(fresh, rel=0, abs=1e-5)  # per-view vs batched float sums
    other = [bicubic(t, 4) for t in reference_textures(mesh)]  # never validated: rendered
    with pytest.raises(AssertionError, match="rendered again"):
        validation.score(other, None, ["Q"])


def test_a_validation_prices_the_taps_it_must_find_again_once_they_are_dropped(small):
    mesh, _ = small
    validation = _validation(small)
    validation.cache_all()
    validation.freeze()
    assert validation.missing_taps == 0 and validation.tap_cost > 0
    held = validation.seconds_needed(1, caching=False)
    validation.drop_taps()
    assert validation.missing_taps == validation.num_views == 6 + 2 + 2
    owed = validation.seconds_needed(1, caching=False) - held
    assert owed == pytest.approx(10 * validation.tap_cost)
    validation.psnr([texture_to_linear(lanczos(t, 4)) for t in reference_textures(mesh)], None)
    assert validation.missing_taps == 0  # found again as each view was rendered


def test_each_validation_measures_the_unit_costs_again(small):
    mesh, _ = small
    validation = _validation(small, clock=TickingClock())
    validation.freeze()
    validation._render_seconds = validation._metric_seconds = 100.0  # a slow first probe
    validation.psnr([texture_to_linear(lanczos(t, 4)) for t in reference_textures(mesh)], None)
    # a clock that ticks once a call: every render and every Q metric took one "second"
    assert (validation._render_seconds, validation._metric_seconds) == (1.0, 1.0)


def _per_view_scores(**sets: list[float]) -> Scores:
    """Scores whose means are those of the hand-made per-view values (dB)."""
    per_view = {name: np.array(values) for name, values in sets.items()}
    return Scores({name: float(np.nanmean(v)) for name, v in per_view.items()}, per_view)


def test_the_floor_is_taken_and_ranked_on_alone_from_hand_made_scores():
    bicubic = _per_view_scores(Q=[29.0, 30.0, 28.0], far=[50.0, 51.0, math.nan])
    lanczos = _per_view_scores(Q=[30.0, 31.0, 29.0], far=[49.0, 50.0, math.nan])
    floor = Floor({"bicubic": bicubic, "lanczos": lanczos}, ["Q", "far"])
    assert floor.best == {"Q": lanczos, "far": bicubic}
    assert floor.rank(lanczos) == (pytest.approx(-1.0), 30.0)  # 1 dB below bicubic far, steadily
    sharper = _per_view_scores(Q=[32.0, 33.0, 31.0], far=[50.0, 51.0, math.nan])
    assert floor.rank(sharper) == (0.0, 32.0) and floor.rank(sharper) > floor.rank(lanczos)
    assert floor.gap({"Q": 29.0, "far": 50.0}, "Q") == -1.0  # means alone: mean_gap, by name
    assert Floor({}, ["Q", "far"]).best == {} and Floor({}, ["Q"]).shortfall(sharper) == 0.0


def test_the_seconds_needed_follow_from_given_unit_costs():
    costs = UnitCosts()
    costs.render_seconds, costs.metric_seconds = 0.5, 2.0
    # 7 views: 3 validations render in each; Q's 3 views get the metrics of 3 + 1 scorings.
    assert costs.seconds_needed(7, 3, 3, scorings_after=1) == 7 * 3 * 0.5 + 3 * 4 * 2.0
    assert costs.seconds_needed(7, 3, 3, to_cache=2, view_seconds=4.0) == 10.5 + 18 + 2 * 4.0
    costs.view_cost.add(1.5)  # a view timed: its mean replaces the caller's guess
    assert costs.seconds_needed(7, 3, 3, to_cache=2, view_seconds=4.0) == 10.5 + 18 + 2 * 1.5


def test_views_are_frozen_on_their_own_and_say_what_freezing_still_caches(small):
    mesh, renderer = small
    sizes = output_sizes(mesh, 4)
    sets = {
        name: ViewCache(view_set, sizes, with_taps=True)
        for name, view_set in validation_view_sets(renderer, 2).items()
    }
    views = ValidationViews(sets)
    assert views.next_set() == "Q" and views.to_cache() == 3 + 2 + 2
    views.cache_view("Q")
    assert views.next_set() == "near" and views.to_cache({"Q": 3}) == 2
    views.freeze({"Q": 2})
    assert views.counts == {"Q": 2, "near": 0, "far": 0} and views.next_set() is None


def test_the_q_metrics_memo_knows_a_candidate_by_its_bytes():
    memo = QMetricsMemo()
    codes = [np.full((2, 2, 3), 7, np.uint8), None]
    memo.keep(codes, None, {"psnr_fg": 30.0})
    assert memo.get([c.copy() if c is not None else None for c in codes], None) == {"psnr_fg": 30.0}
    assert memo.get(codes, np.zeros((3, 2), np.float32)) is None  # other UVs: another candidate
    assert memo.get([np.full((2, 2, 3), 8, np.uint8), None], None) is None
