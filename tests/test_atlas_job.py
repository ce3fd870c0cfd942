"""``direct --uv repack|auto`` through the job: new UVs, every map following them,
references from the original, and the files written."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from geoscaler.cli import main
from geoscaler.errors import GeoscalerError
from geoscaler.io import load_mesh, save_mesh
from geoscaler.methods import MethodOptions, run_method
from geoscaler.methods.registry import RunContext, get_method, register, unregister
from geoscaler.pipeline.job import compare_mesh
from geoscaler.protocol import Evaluation
from geoscaler.report.documents import comparison_json, dumps, method_details
from geoscaler.uv.uvmaps import chart_labels

sys.path.insert(0, str(Path(__file__).parent))
from mesh_support import ribbon_mesh  # noqa: E402
from test_atlas import cube_mesh  # noqa: E402

QUICK = Evaluation.quick((0, 20, 40))
LOOP = {"pool_views": 8, "validate_every": 2}


def options(uv: str, steps: int = 2) -> MethodOptions:
    return MethodOptions(device="cpu", steps=steps, settings={"uv": uv, "optimize": LOOP})


@pytest.fixture
def cube():
    return cube_mesh(texture_size=256)


def test_repack_returns_new_uvs_of_every_face_corner_and_its_layout(cube):
    from geoscaler.render.renderer import Renderer

    renderer = Renderer(cube, "cpu", QUICK)
    result = run_method("direct", cube, 4, options("repack"), RunContext(renderer))
    assert result.layout is not None and result.uvs.shape == (len(cube.faces), 3, 2)
    np.testing.assert_array_equal(result.uvs, result.layout.uvs)
    assert result.textures[0].shape == (64, 64, 3)
    assert method_details(result)["layout_used"] == "repack"
    assert method_details(result)["layout"]["k"] > 1.5
    assert "race" not in method_details(result)


def raced(cube, steps: int, on_event=None, floor: bool = False):
    """``direct --uv auto`` on the cube; ``floor``: validated against Lanczos, as the job
    validates against its filters."""
    from geoscaler.optim.validation import Validation, validation_view_sets
    from geoscaler.render.renderer import Renderer
    from geoscaler.resize.filters import lanczos

    renderer = Renderer(cube, "cpu", QUICK)
    context = RunContext(renderer, on_event=on_event)
    if floor:
        baseline = {"lanczos": [lanczos(renderer.reference_maps()[0], 4)]}
        sets = validation_view_sets(renderer)
        context = replace(context, validation=Validation(sets, [(64, 64)], baseline))
    return run_method("direct", cube, 4, options("auto", steps), context)


def test_auto_tries_both_layouts_and_the_better_validated_goes_on(cube):
    result = raced(cube, steps=10)
    race = method_details(result)["race"]
    assert [trial["steps"] for trial in race.values()] == [2, 2]  # 20% of the steps each
    ranks = {name: (t["shortfall_db"], t["validation_psnr_fg"]) for name, t in race.items()}
    winner = max(ranks, key=lambda name: (ranks[name], name == "keep"))
    assert method_details(result)["layout_used"] == winner
    for trial in race.values():  # every set's mean, Q's the one ranked
        assert set(trial["validation_sets"]) == {"Q", "near", "far"}
        assert trial["validation_sets"]["Q"] == trial["validation_psnr_fg"]
    assert (result.uvs is not None) == (winner == "repack")
    assert method_details(result)["steps"] == 2 + 2 + 8  # the winner goes on with what it has left
    # the continuation starts from the winner's best and validates it: never below it
    assert method_details(result)["validation_psnr_fg"] >= race[winner]["validation_psnr_fg"]


def test_a_new_layout_whose_start_is_below_a_filter_on_every_set_gets_no_trial(cube, monkeypatch):
    import geoscaler.methods.repacked as repacked

    plain = repacked._new_layout
    made = []

    def black_start(*args):
        """The new layout with its bake replaced by black: far below every filter."""
        layout = plain(*args)
        layout.starts = [None if s is None else torch.zeros_like(s) for s in layout.starts]
        made.append(layout)
        return layout

    monkeypatch.setattr(repacked, "_new_layout", black_start)
    result = raced(cube, steps=10, floor=True)
    race = method_details(result)["race"]
    assert list(race) == ["keep", "repack"]
    gated = race["repack"]
    assert gated["gated"] and gated["steps"] == 0
    assert min(gated["start_below"].values()) > 10.0  # black is far below on every set
    assert set(gated["start_below"]) == {"Q", "near", "far"}
    assert not race["keep"]["gated"] and race["keep"]["start_below"] is None
    assert method_details(result)["layout_used"] == "keep" and result.uvs is None
    assert method_details(result)["steps"] == 10  # the own layout went on with the steps left
    (new,) = made  # no trial: the taps its start was validated with went at once
    assert new.validation.missing_taps == new.validation.num_views > 0


def test_a_new_layout_whose_start_is_a_little_below_a_filter_on_one_set_gets_no_trial(
    cube, monkeypatch
):
    import geoscaler.methods.repacked as repacked

    # its trial would have to out-learn the own layout's there: none on the development set did
    monkeypatch.setattr(repacked, "start_below", lambda *args: {"far": 0.05})
    result = raced(cube, steps=10, floor=True)
    race = method_details(result)["race"]
    assert race["repack"]["start_below"] == {"far": 0.05}
    assert race["repack"]["gated"] and race["repack"]["steps"] == 0
    assert method_details(result)["layout_used"] == "keep"
    assert method_details(result)["steps"] == 10  # the own layout went on with the steps left


def test_a_new_layout_whose_start_is_below_no_filter_has_a_trial(cube, monkeypatch):
    import geoscaler.methods.repacked as repacked

    monkeypatch.setattr(repacked, "start_below", lambda *args: {})
    race = method_details(raced(cube, steps=10, floor=True))["race"]
    assert not race["repack"]["gated"] and race["repack"]["steps"] == 2
    assert race["repack"]["start_below"] == {}


def test_a_new_layout_below_the_own_one_on_any_set_stays_out_of_the_race():
    from types import SimpleNamespace

    from geoscaler.methods.registry import LayoutFacts, LoopFacts, MethodResult
    from geoscaler.methods.repacked import _winner
    from geoscaler.optim.validation import Scores

    def trial(q: float, far: list[float], steps: int = 5) -> MethodResult:
        per_view = {"Q": np.array([q, q + 1, q - 1]), "far": np.array(far)}
        scores = Scores({"Q": q, "far": float(np.mean(far))}, per_view)
        loop = LoopFacts(steps, 0, scores, True, {}, "steps", 0.0, 0, {}, 0)
        return MethodResult([None], loop=loop)

    ranked_by_q = SimpleNamespace(rank=lambda scores: (0.0, scores["Q"]))
    names = ("keep", "repack", "unaligned")
    layouts = {n: SimpleNamespace(validation=ranked_by_q, atlas=None) for n in names}
    own = trial(30.0, [50.0, 51.0, 49.0])
    # The repacked trial leads on Q by 3 dB but loses 0.5 dB far in every view; the unaligned
    # one leads by 1 dB and is level far away (+0.5, -0.5, 0): it goes on.
    trials = {
        "keep": own,
        "repack": trial(33.0, [49.5, 50.5, 48.5]),
        "unaligned": trial(31.0, [50.5, 50.5, 49.0]),
    }
    facts = LayoutFacts(uv="auto")
    assert _winner(trials, layouts, facts, 5) == "unaligned"
    below = {name: trial.below_own_on for name, trial in facts.race.items()}
    assert below == {"keep": [], "repack": ["far"], "unaligned": []}
    # Below far, the only new layout: the own one goes on though it is 3 dB lower on Q.
    del trials["unaligned"]
    assert _winner(trials, layouts, facts, 5) == "keep" == facts.used
    # A trial cut short of the first's steps that already ranks above the first wins: more
    # steps could only have raised its validated best.
    trials["repack"] = trial(33.0, [51.0, 52.0, 50.0], steps=3)
    assert _winner(trials, layouts, facts, 5) == "repack"
    assert facts.race["repack"].unfinished and not facts.race["keep"].unfinished
    # A start (no step) never decides, however well it validates.
    trials["repack"] = trial(33.0, [51.0, 52.0, 50.0], steps=0)
    assert _winner(trials, layouts, facts, 5) == "keep"


def fake_race(
    monkeypatch,
    first_made: int,
    first_stopped_by: str,
    steps: int = 10,
    context: RunContext | None = None,
    winner: str | None = None,
    ends: list | None = None,
    worst: dict[str, float] | None = None,
    trial_times: list | None = None,
    view_cost: float = 0.0,
    tap_cost: float = 0.0,
    validation_seconds: float = 0.0,
    dropped: list | None = None,
):
    """``--uv auto``'s race with every phase's loop faked: the first trial makes
    ``first_made`` steps and stops for ``first_stopped_by`` (taking 2.5 s where the context's
    clock is a ManualClock), later phases make the steps they are given; every layout
    validates alike, or ``winner``'s better, on 9 views, each cached in ``view_cost`` seconds
    (``tap_cost`` of them its taps) and each validation taking ``validation_seconds``.
    ``trial_times`` receives the price of a later trial's least each time the new layouts are
    planned. Returns the result, the
    facts, ``(layout, steps)`` per phase, how many times the new layouts were planned, and the
    layouts whose training pool was still held as the race's last phase started; ``ends``
    receives ``(layout, loop end, reserve)`` per phase. The race runs in ``context`` (default:
    no budget); the new layout has an atlas. With ``worst`` (each filter's lowest PSNR-fg
    over the validation's views) the job finishes where nothing visible is left to gain.
    ``dropped`` receives the layouts whose validation taps were dropped."""
    import gc
    import weakref
    from types import SimpleNamespace

    import geoscaler.methods.repacked as repacked
    from geoscaler.clock import ManualClock
    from geoscaler.methods.registry import LayoutFacts, LoopFacts, MethodResult
    from geoscaler.optim.loop import OptimizeConfig
    from geoscaler.optim.validation import Scores

    fits, planned, pools, alive = [], [], {}, []
    scores = Scores({"Q": 40.0}, {"Q": np.array([40.0, 41.0, 39.0])})  # every trial's, tied
    better = Scores({"Q": 41.0}, {"Q": np.array([41.0, 42.0, 40.0])})
    ends = [] if ends is None else ends
    dropped = [] if dropped is None else dropped

    def fit(self, mesh, rule, layout, model, loop_end, reserve, steps, facts=None, **handover):
        made, stopped_by = (first_made, first_stopped_by) if self.first else (steps, "steps")
        if self.first and isinstance(self.context.clock, ManualClock):
            self.context.clock.advance(2.5)
        fits.append((layout.name, made))
        ends.append((layout.name, loop_end, reserve))
        # the trial before the planning caches views in what the planning leaves of the share
        expected = repacked.FIRST_TRIAL_CACHING if self.first else None
        assert handover.get("caching_share") == expected
        # ... and leaves room for a later layout's pool (none after it, in its place)
        assert handover.get("room_for_a_pool") == (True if self.first else None)
        if self.last:
            gc.collect()
            alive.extend(name for name, pool in pools.items() if pool() is not None)
        validated = better if layout.name == winner else scores
        loop = LoopFacts(made, 0, validated, True, {}, stopped_by, 0.0, 4, {"Q": 3}, 0)
        return MethodResult([None], loop=loop)

    class Pool:
        views = SimpleNamespace(cameras=[])

    def training_views(renderer, *args):
        pool = Pool()
        pools[renderer.layout] = weakref.ref(pool)
        return pool

    monkeypatch.setattr(repacked._Phase, "fit", fit)
    monkeypatch.setattr(repacked, "training_views", training_views)
    monkeypatch.setattr(repacked, "validate", lambda *args: scores)  # a new layout's start
    monkeypatch.setattr(repacked, "start_below", lambda *args: {})  # ... within the margin
    validation = SimpleNamespace(
        rank=lambda scores: (0.0, scores["Q"]),
        find_taps=lambda: None,
        sizes=[(64, 64)],
        seconds_needed=lambda validations, *args: validations * validation_seconds,
        view_cost=view_cost,
        tap_cost=tap_cost,
        taps_seconds=lambda views, seconds=0.0: views * (tap_cost or view_cost or seconds),
        num_views=9,
        worst_baseline_views=lambda: worst or {},
    )

    def layout(name: str) -> SimpleNamespace:
        cpu = SimpleNamespace(device="cpu", layout=name)
        atlas = None if name == "keep" else SimpleNamespace(facts=None)
        mine = SimpleNamespace(**vars(validation), drop_taps=lambda: dropped.append(name))
        return SimpleNamespace(name=name, validation=mine, atlas=atlas, starts=[], renderer=cpu)

    def later(trial_seconds: float) -> dict:
        planned.append(True)
        if trial_times is not None:
            trial_times.append(trial_seconds)
        return {"repack": layout("repack")}

    model = SimpleNamespace(restore=lambda textures: None, candidate=lambda: None)
    facts = LayoutFacts(uv="auto")
    context = context or RunContext()
    config = OptimizeConfig(
        steps=steps,
        pool_views=4,
        time_budget=context.time_budget,
        finish_when_invisible=worst is not None,
    )
    own = {"keep": layout("keep")}
    start_model = lambda *args: model  # noqa: E731
    result = repacked.raced(None, None, own, start_model, config, context, 0.0, facts, later)
    return result, facts, fits, len(planned), alive


@pytest.mark.parametrize("winner", ["keep", "repack"])
def test_a_new_layout_ends_its_trial_and_loop_before_the_rebake_of_the_other_maps(
    monkeypatch, winner
):
    """The export re-bakes a new layout's other maps: a new layout's trial and loop end that
    long before the method's end; the own layout's keep it for steps."""
    from geoscaler.clock import ManualClock

    context = RunContext(time_budget=100.0, reserve=1.0, clock=ManualClock(), relayout_reserve=3.0)
    ends = []
    fake_race(monkeypatch, 2, "steps", context=context, winner=winner, ends=ends)
    first, trial, last = ends
    assert first[0] == "keep" and first[1] < 96.0  # the first trial's share, as before
    assert trial == ("repack", 96.0, 0.0)  # 100 s less the export's 1, less the re-bake's 3
    assert last == ((winner, 96.0, 4.0) if winner == "repack" else ("keep", 99.0, 1.0))


def test_the_winner_goes_on_without_the_losers_training_pools(monkeypatch):
    """The trials fill the method's memory limit between them: the loser's pool and its
    validation taps are dropped before the winner's loop goes on, so that the winner's pool
    can grow."""
    dropped = []
    result, facts, fits, plans, alive = fake_race(monkeypatch, 2, "steps", dropped=dropped)
    assert plans == 1 and fits == [("keep", 2), ("repack", 2), ("keep", 8)]  # a tie: the own
    assert alive == ["keep"] and result.loop.steps == 12  # the loser's 2 on top
    assert dropped == ["repack"]
    dropped.clear()
    fake_race(monkeypatch, 2, "steps", winner="repack", dropped=dropped)
    assert dropped == ["keep"]  # the job's validation's taps, found again where needed


def test_a_first_trial_of_no_step_ends_the_race_and_its_layout_goes_on(monkeypatch):
    result, facts, fits, plans, _ = fake_race(monkeypatch, 0, "time budget")
    assert fits == [("keep", 0), ("keep", 10)]  # no trial of the new layout; the own goes on
    assert list(facts.race) == ["keep"] and facts.used == "keep"
    assert result.loop.steps == 10
    assert plans == 0 and "no step" in facts.skipped  # no layout planned for a race that ended


def test_a_first_trial_with_nothing_visible_to_gain_ships_before_any_layout_is_planned(
    monkeypatch,
):
    from geoscaler.optim.loop import NOTHING_TO_GAIN

    result, facts, fits, plans, _ = fake_race(monkeypatch, 2, NOTHING_TO_GAIN)
    assert fits == [("keep", 2)] and result.loop.steps == 2  # it ships what the trial found
    assert plans == 0 and "beyond what is visible" in facts.skipped
    assert facts.used == "keep"


def test_a_first_trial_whose_views_show_nothing_visible_to_gain_plans_no_layout(monkeypatch):
    # the trial's loop ended at its share before it looked; its validation, frozen as it
    # ended, has a filter at the invisible level on every view: the race ends there
    from geoscaler.optim.loop import INVISIBLE_PSNR_FG, NOTHING_TO_GAIN

    worst = {"lanczos": INVISIBLE_PSNR_FG, "bicubic": 45.0}
    result, facts, fits, plans, _ = fake_race(monkeypatch, 2, "time budget", worst=worst)
    assert fits == [("keep", 2)] and plans == 0
    assert result.loop.stopped_by == NOTHING_TO_GAIN
    assert "beyond what is visible" in facts.skipped and facts.used == "keep"
    worst = {"lanczos": INVISIBLE_PSNR_FG - 0.01}
    _, _, fits, plans, _ = fake_race(monkeypatch, 2, "time budget", worst=worst)
    assert plans == 1 and fits[:2] == [("keep", 2), ("repack", 2)]


def test_the_new_layouts_are_planned_after_the_own_layouts_trial(cube, monkeypatch):
    import geoscaler.methods.repacked as repacked

    events, planned_after = [], []
    plain = repacked.plan_layout

    def plan(*args, **kwargs):
        planned_after.append([event.step for event in events if event.phase == "step"])
        return plain(*args, **kwargs)

    monkeypatch.setattr(repacked, "plan_layout", plan)
    result = raced(cube, steps=10, on_event=events.append)
    assert planned_after == [[1, 2]]  # the own layout's 2 trial steps came first
    assert list(method_details(result)["race"]) == ["keep", "repack"]


def test_the_first_trials_share_is_of_the_time_left_after_what_the_race_pays_once():
    """Caching the validation views and scoring the baselines is paid once, whatever layout
    wins: the first trial's share of the time is taken after it, not out of it."""
    from types import SimpleNamespace

    import geoscaler.methods.repacked as repacked
    from geoscaler.clock import ManualClock
    from geoscaler.optim.loop import FINISH_MARGIN, OptimizeConfig

    clock = ManualClock()
    clock.set(4.0)  # the race starts 4 s into the method; it ends at 24 s
    config = OptimizeConfig(steps=10, views_per_step=4)
    trials = repacked._Trials(config, RunContext(clock=clock), 0.0, 24.0, cameras=[])
    asked = []

    def seconds_needed(validations, caching, view_seconds):
        asked.append((validations, caching, view_seconds))
        # the views to cache and the baselines' scoring, at 0.25 s a view; 0.1 s a validation
        return 2.0 + 0.1 * validations

    validation = SimpleNamespace(seconds_needed=seconds_needed, view_cost=0.25)
    once = FINISH_MARGIN * 2.0
    expected = 4.0 + once + repacked.TRIAL_SHARE * (20.0 - once)
    assert trials._first_deadline(validation) == pytest.approx(expected)
    assert asked[0] == (0, True, 0.25)  # no candidate's validation: those are the trial's
    clock.set(17.0)  # 7 s left: the share (0.8 s) cannot hold the trial's first step
    least = 4 * 0.25 + FINISH_MARGIN * 0.2  # its 4 training views and 2 validations
    assert trials._first_deadline(validation) == pytest.approx(17.0 + once + least)
    clock.set(23.0)  # almost no time left: never past the method's end
    assert trials._first_deadline(validation) == 24.0
    unbudgeted = repacked._Trials(OptimizeConfig(steps=10), RunContext(), 0.0, None, [])
    assert unbudgeted._first_deadline(validation) is None


def test_a_later_trial_takes_the_earlier_layouts_taps_where_the_memory_limit_holds_no_more(
    monkeypatch,
):
    """A later trial trains on the first trial's cameras and validates on its views, their
    G-buffers shared: its pool adds taps as large as the earlier pools'. Where the process
    cannot hold them under the method's memory limit, the earlier pools' taps go, and where
    that is not room enough, the earlier validations' taps too (each found again where its
    layout goes on)."""
    import geoscaler.methods.repacked as repacked
    import geoscaler.optim.loop as loop_module
    from geoscaler.optim.loop import OptimizeConfig

    class Taps:
        nbytes, dropped = 300, False

        def drop_taps(self):
            self.dropped = True

    released = []
    monkeypatch.setattr(repacked, "release_free_memory", lambda: released.append(True))
    config = OptimizeConfig(steps=10, memory_limit=1000)

    def room(resident_besides_the_pool: int | None) -> tuple[bool, bool]:
        """(pool dropped, validation dropped) where the process holds the earlier pool's 300
        bytes of taps and ``resident_besides_the_pool`` more (None: the system cannot say)."""
        trials = repacked._Trials(config, RunContext(), 0.0, None, [])
        pool, validation = Taps(), Taps()
        trials.pools, trials.validations = {"keep": pool}, {"keep": validation}

        def resident():
            if resident_besides_the_pool is None:
                return None
            return resident_besides_the_pool + (0 if pool.dropped else pool.nbytes)

        monkeypatch.setattr(loop_module, "resident_bytes", resident)
        released.clear()
        trials._room_for_a_pool()
        return pool.dropped, validation.dropped

    assert room(399) == (False, False) and not released  # 699 + 300 < 1000: room
    assert room(400) == (True, False) and released == [True]  # 700 + 300; then 400 + 300
    assert room(700) == (True, True) and released == [True, True]  # 700 + 300 once it went
    assert room(None) == (False, False)


def test_a_later_phase_times_its_first_step_from_the_methods_start():
    """A trial after the first, and the winner's continuation, time their loops from their
    own start; the race reports first steps from the method's."""
    import math
    from types import SimpleNamespace

    import geoscaler.methods.repacked as repacked
    from geoscaler.clock import ManualClock
    from geoscaler.methods.registry import LoopFacts, MethodResult
    from geoscaler.optim.loop import OptimizeConfig

    clock = ManualClock()
    clock.set(5.0)  # the phase starts 5 s after the method

    def fit(mesh, rule, model, config, context, start, facts, setup):
        loop = LoopFacts(3, 0, {}, True, {}, "steps", 1.0, 4, {"Q": 3}, 0)
        return MethodResult([None], loop=loop)

    config = OptimizeConfig(steps=10, pool_views=4)
    phase = repacked._Phase(config, RunContext(clock=clock), 0.0, 2, first=False, last=True)
    result = phase.fit(None, None, SimpleNamespace(fit=fit), None, None, 0.0, 3)
    assert result.loop.first_step_seconds == 6.0  # 1 s into a phase that began at 5 s

    def made(first_step: float) -> MethodResult:
        loop = LoopFacts(0, 0, {}, True, {}, "steps", first_step, 4, {"Q": 3}, 0)
        return MethodResult([None], loop=loop)

    assert repacked._first_step([made(math.nan), made(6.0), made(9.0)]) == 6.0
    assert math.isnan(repacked._first_step([made(math.nan)]))


def test_a_layout_sparser_than_the_own_one_is_not_weighed(monkeypatch):
    from types import SimpleNamespace

    import geoscaler.methods.repacked as repacked
    from geoscaler.clock import WALL_CLOCK
    from geoscaler.methods.registry import LayoutFacts

    def planned(aligned_k: float, unaligned_k: float = 1.4) -> tuple[list[bool], LayoutFacts]:
        """The layouts offered where the aligned plan has density ``aligned_k`` and the
        unaligned one ``unaligned_k``, and the facts."""

        def plan(mesh, rule, renderer, config, budget, align, views):
            k = aligned_k if align else unaligned_k
            return SimpleNamespace(moved=True, aligned=align, facts=SimpleNamespace(k=k))

        monkeypatch.setattr(repacked, "plan_layout", plan)
        facts = LayoutFacts(uv="auto")
        validation = SimpleNamespace(clock=WALL_CLOCK)
        offered = repacked._timely_layouts(None, None, None, None, validation, None, facts)
        return [atlas.aligned for atlas in offered], facts

    # Rounded down to powers of two of the original's texels, half the own density: its bake
    # starts below Lanczos in the own layout (10 dB on a 4096 scan at 4x); only the unaligned
    # layout is offered, and its facts are the planned ones.
    offered, facts = planned(0.5)
    assert offered == [False] and facts.planned.k == 1.4 and facts.skipped is None
    offered, facts = planned(1.2)  # denser than the own layout: both weighed
    assert offered == [True, False] and facts.planned.k == 1.2
    offered, facts = planned(1.2, 0.99)  # the unaligned one a hair sparser: only the aligned
    assert offered == [True] and facts.skipped is None
    offered, facts = planned(0.5, 0.99)  # both sparser: none, and the report says why
    assert offered == [] and facts.skipped == repacked.SPARSER
    assert facts.planned.k == 0.99  # the unaligned plan's, as where only it is weighed


def test_an_unaligned_plan_sparser_than_the_own_layout_is_not_weighed(monkeypatch):
    from types import SimpleNamespace

    import geoscaler.methods.repacked as repacked
    from geoscaler.clock import WALL_CLOCK
    from geoscaler.methods.registry import LayoutFacts

    plans = []  # where the far views do not minify, the first plan is already unaligned

    def plan(mesh, rule, renderer, config, budget, align, views):
        plans.append(align)
        return SimpleNamespace(moved=True, aligned=False, facts=SimpleNamespace(k=0.8))

    monkeypatch.setattr(repacked, "plan_layout", plan)
    facts = LayoutFacts(uv="auto")
    offered = repacked._timely_layouts(
        None, None, None, None, SimpleNamespace(clock=WALL_CLOCK), None, facts
    )
    assert offered == [] and plans == [True]  # planned once: no second, unaligned plan
    assert facts.skipped == repacked.SPARSER and facts.planned.k == 0.8


def minifying(uv: str, steps: int):
    """``direct`` at 4x on a cube whose 256-texel output even the far views minify (64 pixels
    a side: a far sample spans more than a texel), so its charts are aligned."""
    from geoscaler.render.renderer import Renderer

    cube = cube_mesh(texture_size=1024)
    renderer = Renderer(cube, "cpu", Evaluation.quick((0, 20, 40), image_size=64))
    return run_method("direct", cube, 4, options(uv, steps), RunContext(renderer))


def test_where_charts_are_aligned_the_race_weighs_the_unaligned_layout_too():
    result = minifying("auto", steps=10)
    race = method_details(result)["race"]
    assert list(race) == ["keep", "repack", "unaligned"]
    assert [trial["steps"] for trial in race.values()] == [2, 2, 2]
    ranks = {name: (t["shortfall_db"], t["validation_psnr_fg"]) for name, t in race.items()}
    winner = max(ranks, key=lambda name: (ranks[name], name == "keep"))
    assert method_details(result)["layout_used"] == winner
    if winner != "keep":  # the report describes the layout that went on
        assert result.layout_facts.planned == result.layout.facts
        assert result.layout.aligned == (winner == "repack")


def test_repack_races_its_aligned_and_unaligned_layouts():
    result = minifying("repack", steps=10)
    assert list(method_details(result)["race"]) == ["repack", "unaligned"]
    assert method_details(result)["layout_used"] in ("repack", "unaligned")
    assert result.uvs is not None and result.layout.aligned == (
        method_details(result)["layout_used"] == "repack"
    )
    assert method_details(result)["layout"]["alignment_texels"] == (
        16 if method_details(result)["layout_used"] == "repack" else 1
    )


def test_the_aligned_and_unaligned_plans_render_the_training_views_once(monkeypatch):
    from geoscaler.methods.registry import LayoutFacts
    from geoscaler.methods.repacked import offered_layouts
    from geoscaler.optim.loop import OptimizeConfig
    from geoscaler.render.renderer import Renderer
    from geoscaler.resize.sizes import SizeRule

    cube = cube_mesh(texture_size=1024)  # its charts are aligned (minifying)
    renderer = Renderer(cube, "cpu", Evaluation.quick((0, 20, 40), image_size=64))
    rendered = []
    rasterize = renderer.rasterize

    def counted(camera, *args, **kwargs):
        rendered.append(camera)
        return rasterize(camera, *args, **kwargs)

    monkeypatch.setattr(renderer, "rasterize", counted)
    config = OptimizeConfig(pool_views=8)
    offered = offered_layouts(cube, SizeRule(scale=4), renderer, config, LayoutFacts(uv="auto"))
    assert [atlas.aligned for atlas in offered] == [True, False]
    assert len(rendered) == 8


def slow_planning_views(seconds_a_view: float):
    """:class:`PlanningViews` of 8 cameras whose each view takes ``seconds_a_view`` on a manual
    clock, and that clock."""
    from types import SimpleNamespace

    from geoscaler.clock import ManualClock
    from geoscaler.methods.repacked import PlanningViews
    from geoscaler.optim.loop import OptimizeConfig

    clock = ManualClock()

    def rasterize(camera, size):
        clock.advance(seconds_a_view)
        return SimpleNamespace(tri_ids=torch.zeros((size, size), dtype=torch.long))

    renderer = SimpleNamespace(rasterize=rasterize, image_size=4)
    return PlanningViews(renderer, OptimizeConfig(pool_views=8)), clock


def test_a_plans_views_take_at_most_half_the_time_to_its_deadline():
    views, clock = slow_planning_views(0.125)  # 8 views: 1 s
    assert views.render_by(deadline=2.0, clock=clock)  # half the time to it: rendered
    assert len(views.tri_ids) == 8 and clock.now() == 1.0
    views, clock = slow_planning_views(0.125)
    assert not views.render_by(deadline=1.75, clock=clock)  # the first view: 1 s > 0.875
    assert clock.now() == 0.125 and len(views._tri_ids) == 1


def test_no_layout_is_planned_where_its_views_would_leave_the_packing_too_little_time(
    monkeypatch,
):
    import geoscaler.methods.repacked as repacked
    from geoscaler.methods.registry import LayoutFacts
    from geoscaler.methods.repacked import offered_layouts
    from geoscaler.optim.loop import OptimizeConfig
    from geoscaler.resize.sizes import SizeRule

    views, clock = slow_planning_views(0.125)
    monkeypatch.setattr(repacked, "PlanningViews", lambda renderer, config: views)
    monkeypatch.setattr(repacked, "plan_layout", lambda *args: pytest.fail("planned"))
    facts = LayoutFacts(uv="auto")
    config = OptimizeConfig(pool_views=8)
    assert offered_layouts(None, SizeRule(scale=4), None, config, facts, clock, 1.75) == []
    assert "no time to plan" in facts.skipped and clock.now() == 0.125


def test_fewer_steps_than_layouts_run_the_first_layout_alone(cube):
    result = raced(cube, steps=1)
    assert method_details(result)["steps"] == 1 and "race" not in method_details(result)
    assert method_details(result)["layout_used"] == "keep" and result.uvs is None
    assert "too few steps" in method_details(result)["layout_skipped"]  # none planned


def test_the_race_reports_one_run_of_steps_and_one_end(cube):
    events = []
    result = raced(cube, steps=5, on_event=events.append)
    steps = [event.step for event in events if event.phase == "step"]
    assert steps == list(range(1, 7))  # trials of 1 step each, then the winner's 4 left
    # The shipped candidate's step is the one its validation was reported at (0: a start).
    best = method_details(result)["validation_psnr_fg"]
    found = [e.step for e in events if e.phase == "validation" and e.validation_psnr == best]
    assert method_details(result)["best_step"] == (found[0] if found else 0)
    # the steps asked, until the loser's trial step is known to come on top
    assert [e.total_steps for e in events if e.phase == "step"] == [5, 5, 6, 6, 6, 6]
    assert [event.phase for event in events].count("done") == 1
    assert events[-1].phase == "done"
    phases = [event.phase for event in events]
    caching = [i for i, phase in enumerate(phases) if phase == "caching"]
    assert caching and max(caching) < phases.index("step")  # the first trial's only


def test_a_new_layouts_validation_prices_the_taps_it_has_still_to_find(cube):
    from geoscaler.methods.repacked import LayoutValidation
    from geoscaler.optim.validation import Validation, validation_view_sets
    from geoscaler.render.renderer import Renderer

    renderer = Renderer(cube, "cpu", QUICK)
    base = Validation(validation_view_sets(renderer, guard_views=2), [(64, 64)])
    base.cache_all()
    base.freeze()
    shifted = renderer.relaid(cube.uvs * 0.5 + 0.25)
    layout = LayoutValidation(base, shifted)
    frozen = sum(base.counts.values())
    assert frozen == 3 + 2 + 2 and base.view_cost > base.tap_cost > 0
    owed = layout.seconds_needed(1, False) - base.seconds_needed(1, False)
    assert owed == pytest.approx(frozen * base.tap_cost)  # the views are cached: their taps
    layout.psnr([torch.rand(64, 64, 3)], shifted.uvs)
    assert all(len(cache.taps) == base.counts[n] for n, cache in layout.sets.items())
    assert layout.seconds_needed(1, False) == pytest.approx(
        layout.num_views * layout._render_seconds + 3 * layout._metric_seconds
    )


def test_a_budget_without_time_for_a_trial_step_keeps_the_own_layout_unplanned(cube):
    from geoscaler.render.renderer import Renderer

    context = RunContext(Renderer(cube, "cpu", QUICK), time_budget=0.05)
    result = run_method("direct", cube, 4, options("auto"), context)
    assert method_details(result)["layout_used"] == "keep" and result.uvs is None
    assert method_details(result)["layout_skipped"] == (
        "the first trial made no step in its share of the time"
    )
    assert "layout" not in method_details(result) and method_details(result)["steps"] == 0


def test_no_layout_is_planned_where_the_time_left_cannot_hold_its_plan_and_bake(cube):
    from geoscaler.clock import ManualClock
    from geoscaler.methods.registry import LayoutFacts
    from geoscaler.methods.repacked import PREPARING_SHARE, _timely_layouts, bake_seconds
    from geoscaler.optim.loop import OptimizeConfig
    from geoscaler.optim.validation import Validation, validation_view_sets
    from geoscaler.render.renderer import Renderer
    from geoscaler.resize.sizes import SizeRule

    clock = ManualClock(100.0)
    renderer = Renderer(cube, "cpu", QUICK)
    validation = Validation(validation_view_sets(renderer), [(64, 64)], clock=clock)
    baking = bake_seconds([(64, 64)], renderer.reference_maps())
    config = OptimizeConfig(pool_views=8)
    rule = SizeRule(scale=4)

    def offered(end: float, trial: float | None = None) -> tuple[int, LayoutFacts]:
        facts = LayoutFacts(uv="auto")
        layouts = _timely_layouts(cube, rule, renderer, config, validation, end, facts, trial)
        return len(layouts), facts

    # The plan's share of the time left cannot hold the bake: nothing planned.
    count, facts = offered(end=100.0 + 0.9 * baking / PREPARING_SHARE)
    assert count == 0 and facts.skipped == (
        "the time budget left no time to plan and bake a new layout"
    )
    assert facts.planned is None
    count, facts = offered(end=100.0 + 1000 * baking)  # time enough: the layout is offered
    assert count == 1 and facts.skipped is None and facts.planned is not None


def test_after_the_own_trial_a_layout_is_planned_while_the_time_left_holds_its_bake_and_trial(
    cube,
):
    """The share of the time left cannot hold the bake, but the time left holds the bake and
    a new layout's least trial: the first new layout is planned; a trial longer than that
    leaves none."""
    from geoscaler.clock import ManualClock
    from geoscaler.methods.registry import LayoutFacts
    from geoscaler.methods.repacked import PREPARING_SHARE, _timely_layouts, bake_seconds
    from geoscaler.optim.loop import OptimizeConfig
    from geoscaler.optim.validation import Validation, validation_view_sets
    from geoscaler.render.renderer import Renderer
    from geoscaler.resize.sizes import SizeRule

    clock = ManualClock(100.0)
    renderer = Renderer(cube, "cpu", QUICK)
    validation = Validation(validation_view_sets(renderer), [(64, 64)], clock=clock)
    baking = bake_seconds([(64, 64)], renderer.reference_maps())
    config, rule = OptimizeConfig(pool_views=8), SizeRule(scale=4)
    end = 100.0 + 2.25 * baking
    assert PREPARING_SHARE * (end - 100.0) < baking  # the share alone: no time to plan

    def offered(trial: float | None) -> int:
        facts = LayoutFacts(uv="auto")
        return len(_timely_layouts(cube, rule, renderer, config, validation, end, facts, trial))

    assert offered(None) == 0  # no trial came first (--uv repack): the share decides
    assert offered(0.25 * baking) == 1  # 2.25 bakes left: a bake and a trial of 0.25 fit
    assert offered(1.5 * baking) == 0  # a bake and a trial of 1.5 do not


def test_the_planning_after_the_own_trial_is_told_what_a_new_layouts_least_trial_takes(
    monkeypatch,
):
    """Not the own trial's 2.5 s, its views' caching included: a new layout's taps in the 9
    frozen validation views and 4 training views (0.04 s a view, where a whole view costs
    0.1 s), its start's validation, the one after its step and the step (0.2 s each), with the
    loop's finish margin."""
    from geoscaler.clock import ManualClock
    from geoscaler.optim.loop import FINISH_MARGIN

    times = []
    context = RunContext(time_budget=100.0, clock=ManualClock())
    fake_race(
        monkeypatch, 2, "steps", context=context, trial_times=times, view_cost=0.1,
        tap_cost=0.04, validation_seconds=0.2,
    )  # fmt: skip
    assert times == [pytest.approx(FINISH_MARGIN * (3 * 0.2 + (9 + 4) * 0.04))]


def test_the_bake_is_priced_per_sample_of_its_grids():
    from geoscaler.methods.repacked import bake_seconds
    from geoscaler.uv.bake import BAKE_SECONDS_PER_SAMPLE

    image = np.zeros((256, 256, 3), np.uint8)
    # 64^2 texels at 4 samples a side (the original's density)
    assert bake_seconds([(64, 64)], [image]) == pytest.approx(256**2 * BAKE_SECONDS_PER_SAMPLE)
    # one image shown by two materials is baked once; an untextured material not at all
    assert bake_seconds([(64, 64), (64, 64), None], [image, image, None]) == (
        pytest.approx(256**2 * BAKE_SECONDS_PER_SAMPLE)
    )
    # 128^2 texels: 2 samples a side (the original's density)
    assert bake_seconds([(128, 128)], [image]) == pytest.approx(256**2 * BAKE_SECONDS_PER_SAMPLE)
    # ... or 4 (the most) from a 1024^2 original: 512^2 samples
    large = np.zeros((1024, 1024, 3), np.uint8)
    assert bake_seconds([(128, 128)], [large]) == pytest.approx(512**2 * BAKE_SECONDS_PER_SAMPLE)


def test_the_job_scores_repack_beside_direct_on_the_same_views(cube):
    from geoscaler.render.renderer import Renderer

    direct = get_method("direct")
    register("direct-repack-test", direct.run, learned=True, settings={"uv": "repack"})
    try:
        comparison = compare_mesh(
            cube,
            [4],
            ["bicubic", "direct", "direct-repack-test"],
            options=MethodOptions(device="cpu", steps=4, settings={"optimize": LOOP}),
            renderer=Renderer(cube, "cpu", QUICK),
        )
        document = json.loads(dumps(comparison_json("cube.glb", comparison)))
    finally:
        unregister("direct-repack-test")
    rows = {row["method"]: row for row in comparison.rows}
    assert rows["direct-repack-test"]["views"] == rows["direct"]["views"] == 3
    # a sparse atlas at 4x: twice the texel density is worth more than 4 steps of direct
    assert rows["direct-repack-test"]["gain_db"] > rows["direct"]["gain_db"]
    # the compare document says how each learned run went and in which layout it shipped
    runs = document["runs"]
    assert [(run["method"], run["scale"], run["steps"]) for run in runs] == [
        ("direct", 4, 4),
        ("direct-repack-test", 4, 4),
    ]
    assert [run.get("layout_used") for run in runs] == [None, "repack"]
    assert runs[1]["layout"]["k"] > 1.0


def test_downsample_writes_the_new_uvs_and_rebakes_every_map(tmp_path, cube):
    normal = np.zeros((256, 256, 3), np.uint8)
    normal[..., :] = (128, 128, 255)
    normal[::16, :, 0] = 200  # stripes: some detail to bake
    data = np.random.default_rng(1).integers(0, 256, (256, 256, 3), dtype=np.uint8)
    maps = {"normalTexture": normal, "metallicRoughnessTexture": data}
    cube.materials[0] = replace(cube.materials[0], maps=maps)
    save_mesh(cube, tmp_path / "cube.glb")
    status = main(
        [
            "downsample", str(tmp_path / "cube.glb"), "-o", str(tmp_path / "small.glb"),
            "--scale", "4", "--uv", "repack", "--steps", "2", "--device", "cpu",
            "--report", str(tmp_path / "report.json"),
        ],
        evaluation=QUICK,
        optimize=LOOP,
    )  # fmt: skip
    assert status == 0
    written = load_mesh(tmp_path / "small.glb")
    assert len(written.uvs) == len(cube.uvs)  # the same vertices
    assert not np.allclose(written.uvs, cube.uvs)
    assert written.uvs.min() >= 0 and written.uvs.max() <= 1
    material = written.materials[0]
    assert material.base_color_texture.shape == (64, 64, 3)
    assert material.maps["normalTexture"].shape == (64, 64, 3)
    assert material.maps["metallicRoughnessTexture"].shape == (64, 64, 3)
    report = (tmp_path / "report.json").read_text()
    assert "re-baked into the new UV layout" in report and '"layout_used": "repack"' in report


def test_downsample_output_passes_the_gltf_validator(tmp_path, cube):
    from gltf_validator import ValidatorMissing, validate

    save_mesh(cube, tmp_path / "cube.glb")
    main(
        ["downsample", str(tmp_path / "cube.glb"), "-o", str(tmp_path / "small.glb"),
         "--uv", "repack", "--steps", "1", "--device", "cpu"],
        evaluation=QUICK,
        optimize=LOOP,
    )  # fmt: skip
    try:
        _, reports = validate([tmp_path / "small.glb"])
    except ValidatorMissing as missing:
        pytest.skip(str(missing))
    assert reports[str(tmp_path / "small.glb")]["errors"] == 0


def test_a_cut_layout_is_written_with_its_vertices_split_on_the_cuts(tmp_path):
    from gltf_validator import ValidatorMissing, validate

    ribbon = ribbon_mesh(quads=16, texture_size=256)
    save_mesh(ribbon, tmp_path / "ribbon.glb")
    status = main(
        ["downsample", str(tmp_path / "ribbon.glb"), "-o", str(tmp_path / "small.glb"),
         "--scale", "4", "--uv", "repack", "--steps", "2", "--device", "cpu",
         "--report", str(tmp_path / "report.json")],
        evaluation=QUICK,
        optimize=LOOP,
    )  # fmt: skip
    assert status == 0
    layout = json.loads((tmp_path / "report.json").read_text())["details"]["layout"]
    assert layout["cut"] and layout["vertices_added"] > 0
    written = load_mesh(tmp_path / "small.glb")
    assert len(written.uvs) == len(ribbon.uvs) + layout["vertices_added"]
    assert sorted(map(tuple, written.positions[written.faces].reshape(-1, 9))) == sorted(
        map(tuple, ribbon.positions[ribbon.faces].reshape(-1, 9))
    )  # the same triangles in 3D
    assert chart_labels(written).max() + 1 == layout["charts"]  # the pieces are charts
    try:
        _, reports = validate([tmp_path / "small.glb"])
    except ValidatorMissing as missing:
        pytest.skip(str(missing))
    assert reports[str(tmp_path / "small.glb")]["errors"] == 0


def test_uv_needs_the_direct_method(tmp_path, cube, capsys):
    save_mesh(cube, tmp_path / "cube.glb")
    status = main(
        ["downsample", str(tmp_path / "cube.glb"), "-o", str(tmp_path / "small.glb"),
         "--method", "lanczos", "--uv", "repack"]
    )  # fmt: skip
    assert status == 2
    assert "--uv repack: only the direct method repacks UV charts" in capsys.readouterr().err


def test_repack_refuses_the_soft_renderer(cube):
    soft = MethodOptions(device="cpu", steps=1, settings={"uv": "repack", "optimize": {
        "training_renderer": "soft"}})  # fmt: skip
    with pytest.raises(GeoscalerError, match="exact renderer only"):
        run_method("direct", cube, 4, soft)


def test_the_report_says_what_happened_to_the_layout():
    from geoscaler.report.documents import _layout_lines

    layout = {"charts": 6, "k": 2.1, "k_area": 1.9, "padding_texels": 2, "kept": {"b": "why"}}
    repacked = {"uv": "repack", "layout": layout, "layout_used": "repack", "shipped": "direct"}
    assert _layout_lines("direct", repacked) == [
        "UV layout (repack): 6 charts repacked, texel density x2.10 where the views look "
        "(x1.90 by UV area), padding 2 texels; new UVs written, every map of those materials "
        "re-baked",
        "  b: layout kept, why",
    ]
    race = {
        "keep": {"steps": 60, "validation_psnr_fg": 30.0, "shortfall_db": 0.0,
                 "training_views": 14},
        "repack": {
            "steps": 55,
            "validation_psnr_fg": 30.5,
            "validation_sets": {"Q": 30.5, "near": 29.25, "far": 31.0},
            "shortfall_db": -0.25,
            "below_own_on": ["far"],
            "unfinished": True,
            "training_views": 1,
        },
    }
    kept = {**repacked, "uv": "auto", "layout_used": "keep", "race": race}
    assert _layout_lines("direct", kept) == [
        "UV layout (auto): the mesh's own layout kept",
        "  trials (validation PSNR-fg): own layout Q 30.00 dB after 60 steps on 14 training "
        "views; repacked Q 30.50 dB, near 29.25, far 31.00 after 55 steps on 1 training view "
        "(-0.25 dB below a filter) (below the own layout on far) (short of the first trial's "
        "steps: ranked only above it); the best on Q not below the own layout went on",
        "  b: layout kept, why",
    ]
    floored = {**repacked, "shipped": "lanczos"}
    assert _layout_lines("direct", floored)[0] == (
        "UV layout (repack): the repacked result did not ship (lanczos did, on the own UVs)"
    )
    assert _layout_lines("direct", {"uv": "keep"}) == []
    cut = {**layout, "charts_cut": 2, "cut": True, "k_whole": 1.02, "vertices_added": 40}
    assert _layout_lines("direct", {**repacked, "layout": cut})[1] == (
        "  2 charts longer than half the atlas cut along face edges (x1.02 whole): 40 vertices "
        "added on the cuts"
    )
    whole = {**cut, "charts_cut": 1, "cut": False, "k_cut": 1.05}
    assert _layout_lines("direct", {**repacked, "layout": whole})[1] == (
        "  1 chart longer than half the atlas kept whole: cut, x1.05, not 1.1 times x1.02"
    )
    late = {**cut, "charts_cut": 1, "cut": False, "cut_skipped": "no time"}
    assert _layout_lines("direct", {**repacked, "layout": late})[1] == (
        "  1 chart longer than half the atlas kept whole: no time"
    )
    skipped = {"uv": "auto", "layout_used": "keep", "layout_skipped": "no time"}
    assert _layout_lines("direct", skipped) == [
        "UV layout (auto): the mesh's own layout kept: no time"
    ]
