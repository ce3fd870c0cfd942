"""The job ships what it validated, and never less than the filters it scored beside it.

A training pool cut to one view (as a busy machine's caching deadline can leave it) reads few
texels. Before, the texels it did not read were filled from the charts after the last
validation, so the job shipped a texture nobody had scored: on this mesh 14.89 dB PSNR-fg on
Q while its validated start scored 20.65 (Lanczos). Now gutters come from the UV layout alone
and the candidate is validated as it ships.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from geoscaler.cli import main
from geoscaler.clock import WALL_CLOCK, ManualClock
from geoscaler.io import save_mesh
from geoscaler.methods import LoopFacts, MethodOptions, MethodResult, get_method, registry
from geoscaler.optim.validation import Validation
from geoscaler.pipeline.job import JobBudget, compare_on_validation, no_worse_than_filters
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.render.renderer import Renderer
from geoscaler.report.documents import method_details

ONE_VIEW_POOL = {"pool_views": 1, "views_per_step": 1, "validate_every": 1}


@pytest.fixture(scope="module")
def cut_short():
    """``direct`` trained on a pool of one view, beside Lanczos (and bicubic), on two views;
    rows on the validation's Q, as a downsampling job reports them."""
    mesh = demo_mesh(subdivisions=8, texture_size=128)
    options = MethodOptions(device="cpu", steps=2, settings={"optimize": ONE_VIEW_POOL})
    renderer = Renderer(mesh, "cpu", Evaluation.quick((0, 31), image_size=128))
    return compare_on_validation(
        mesh, 4, ["direct", "lanczos"], options=options, renderer=renderer
    )


def test_what_ships_is_what_was_validated(cut_short):
    details = method_details(cut_short.outputs["direct", 4])
    rows = {row["method"]: row for row in cut_short.rows}
    assert details["shipped"] == rows["direct"]["shipped"] == "direct"
    # the loop's score of its finished candidate is the job's score of the 8-bit file's texture
    assert rows["direct"]["psnr_fg"] == pytest.approx(details["validation_scores"]["Q"], abs=1e-4)


def test_a_pool_cut_short_never_ships_below_the_filters(cut_short):
    rows = {row["method"]: row for row in cut_short.rows}
    details = method_details(cut_short.outputs["direct", 4])
    assert details["validation_views"] == {"Q": 2, "near": 2, "far": 2}
    assert details["shortfall_db"] == 0.0  # no worse than the best filter on every set
    assert rows["direct"]["psnr_fg"] >= rows["lanczos"]["psnr_fg"]
    assert details["baseline_scores"]["lanczos"]["Q"] > details["baseline_scores"]["bicubic"]["Q"]


class _Scored(Validation):
    """A validation whose baselines scored ``baselines`` (set name -> PSNR-fg) on Q, near, far."""

    def __init__(self, baselines: dict[str, dict[str, float]]):
        self.sets = dict.fromkeys(["Q", "near", "far"])
        self._scores = baselines

    def baseline_scores(self):
        return self._scores


FILTERS = {
    "bicubic": {"Q": 29.0, "near": 28.0, "far": 33.0},
    "lanczos": {"Q": 30.0, "near": 29.0, "far": 32.5},
}


def _learned(q: float, near: float, far: float) -> MethodResult:
    scores = {"Q": q, "near": near, "far": far}
    texture = np.full((2, 2, 3), 7, np.uint8)
    return MethodResult([texture], np.zeros((3, 2), np.float32), 1.0, loop=loop_facts(scores))


def loop_facts(scores: dict[str, float], views: dict[str, int] | None = None) -> LoopFacts:
    """A loop's facts with these validation scores (the rest as a loop of no step leaves
    them)."""
    return LoopFacts(0, 0, scores, False, {}, "steps", math.nan, 0, views or {}, 0)


def _filters() -> dict[str, MethodResult]:
    return {name: MethodResult([np.full((2, 2, 3), i, np.uint8)]) for i, name in enumerate(FILTERS)}


def test_a_learned_result_no_worse_than_every_filter_everywhere_ships_itself():
    result = _learned(31.0, 30.0, 33.0)
    shipped = no_worse_than_filters("direct", result, _Scored(FILTERS), _filters())
    assert shipped is result and shipped.shipping.shipped == "direct"


def test_a_learned_result_sharper_near_but_worse_far_away_ships_the_filter():
    result = _learned(31.0, 30.0, 32.0)  # 1 dB below bicubic far away; Lanczos is 0.5 below
    shipped = no_worse_than_filters("direct", result, _Scored(FILTERS), _filters())
    assert shipped.shipping.shipped == "lanczos"
    assert shipped.textures[0][0, 0, 0] == 1 and shipped.uvs is None  # Lanczos's, its UVs
    assert shipped.seconds == 1.0


def test_the_learned_result_ships_where_it_falls_less_below_the_floor_than_any_filter():
    result = _learned(31.0, 30.0, 32.8)  # 0.2 dB below bicubic far away, Lanczos 0.5 dB
    shipped = no_worse_than_filters("direct", result, _Scored(FILTERS), _filters())
    assert shipped is result and shipped.shipping.shipped == "direct"  # 1 dB below on Q


def test_without_filters_or_scores_the_learned_result_ships():
    result = _learned(10.0, 10.0, 10.0)
    assert no_worse_than_filters("direct", result, _Scored({}), {}) is result
    unscored = MethodResult([np.zeros((2, 2, 3), np.uint8)])
    assert no_worse_than_filters("x", unscored, _Scored(FILTERS), _filters()) is unscored


def test_the_report_says_what_shipped(tmp_path, capsys):
    def spoiler(mesh, scale, options, context):
        """A learned method whose result scores 5 dB on every validation set."""
        result = get_method("bicubic").run(mesh, scale, options, context)
        context.validation.freeze()
        scores = {"Q": 5.0, "near": 5.0, "far": 5.0}
        result.loop = loop_facts(scores, context.validation.counts)
        return result

    mesh_path, out, report = tmp_path / "mesh.glb", tmp_path / "out.glb", tmp_path / "r.json"
    save_mesh(demo_mesh(subdivisions=8, texture_size=128), mesh_path)
    argv = ["downsample", str(mesh_path), "-o", str(out), "--method", "spoiler"]
    quick = Evaluation.quick((0, 31), image_size=128)
    registry.register("spoiler", spoiler, learned=True)
    try:
        assert main([*argv, "--report", str(report)], evaluation=quick) == 0
    finally:
        registry.unregister("spoiler")
    printed = capsys.readouterr().out
    assert "shipped lanczos: spoiler's own result fell" in printed
    document = json.loads(report.read_text())
    assert document["details"]["shipped"] == document["results"][0]["shipped"] == "lanczos"


@pytest.fixture
def budget_spy():
    """A learned method (bicubic's texture) that records the budget, reserve and re-bake's
    reserve the job hands it."""
    budgets: list[tuple[float | None, float, float]] = []

    def learned(mesh, scale, options, context):
        budgets.append((context.time_budget, context.reserve, context.relayout_reserve))
        return get_method("bicubic").run(mesh, scale, options, context)

    registry.register("budget-spy", learned, learned=True)
    yield budgets
    registry.unregister("budget-spy")


@pytest.mark.parametrize("already_spent", [20.0, 25.0])
def test_a_whole_job_budget_leaves_the_method_only_what_is_left(budget_spy, already_spent):
    """Under a job's budget the time is the job's wall clock: the method gets the budget less
    everything spent since the job began (here 20 s or 25 s before the comparison, as a slow
    load would), the reserve for what comes after the job to keep, and the seconds a new
    layout's re-bake would add to it."""
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    options = MethodOptions(device="cpu", time_budget=30.0)
    renderer = Renderer(mesh, "cpu", Evaluation.quick((0,), image_size=64))
    clock = ManualClock(100.0)  # stands still: the job's own work takes no time
    compare_on_validation(
        mesh, 4, ["budget-spy", "lanczos"], options=options, renderer=renderer,
        budget=JobBudget(100.0 - already_spent, reserve=2.0, relayout=3.0), clock=clock,
    )  # fmt: skip
    assert budget_spy == [(30.0 - already_spent, 2.0, 3.0)]


def test_a_learned_method_the_budget_cannot_hold_is_not_run_and_lanczos_ships(budget_spy, capsys):
    """A budget spent before the method could cache a view and validate a step (here 40 s of a
    30 s budget went on loading) does not run it: what ships is Lanczos, the learned methods'
    start, unvalidated, and the rows score it on Q alone."""
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    options = MethodOptions(device="cpu", time_budget=30.0)
    renderer = Renderer(mesh, "cpu", Evaluation.quick((0, 31), image_size=64))
    done = compare_on_validation(
        mesh, 4, ["budget-spy", "lanczos"], options=options, renderer=renderer,
        budget=JobBudget(WALL_CLOCK.now() - 40.0),
    )  # fmt: skip
    assert budget_spy == []  # never called
    result, lanczos = done.outputs["budget-spy", 4], done.outputs["lanczos", 4]
    assert result.shipping.shipped == "lanczos" and result.loop is None
    assert "cannot hold the validation budget-spy owes" in result.shipping.not_run
    assert np.array_equal(result.textures[0], lanczos.textures[0])
    rows = {row["method"]: row for row in done.rows}
    assert rows["budget-spy"]["psnr_fg"] == rows["lanczos"]["psnr_fg"]
    assert rows["lanczos"]["views"] == 2  # Q's two views: the rows need no guard views
