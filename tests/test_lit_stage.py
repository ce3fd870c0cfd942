"""Lit optimisation (protocol 2): the trainable maps, the loop's promises, and the job's lit
stage after ``direct``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from mesh_support import pbr_demo

from geoscaler.clock import Budget, ManualClock
from geoscaler.io import load_mesh, save_mesh
from geoscaler.optim.events import Controller
from geoscaler.optim.lit import (
    NOT_AFFORDED,
    TRAINED,
    LitMaps,
    LitSettings,
    optimize_lit,
)
from geoscaler.pipeline.shipping import every_map_by
from geoscaler.protocol import Evaluation
from geoscaler.render.lit import NORMAL
from geoscaler.resize.sizes import SizePlan, SizeRule

QUICK = Evaluation.quick((0, 31), image_size=48)
PLAN = SizePlan(SizeRule(scale=4), SizeRule(scale=4), SizeRule(scale=4))
FEW = LitSettings(steps=12, validation_views=2, pool_views=4, views_per_step=2, lr=0.01)


@pytest.fixture(scope="module")
def mesh():
    return pbr_demo(texture_size=64, subdivisions=6)


def flat_start(mesh):
    """Every map at a quarter of its size, flat: grey base colour, a flat normal map, mid
    roughness: a start far from the original that training must improve."""
    replacements = {}
    for pixels, places in mesh.images():
        slot = places[0][1]
        value = {NORMAL: (128, 128, 255), "metallicRoughnessTexture": (0, 128, 0)}
        out = np.empty((16, 16, pixels.shape[2]), np.uint8)
        out[...] = 255
        out[..., :3] = value.get(slot, (128, 128, 128))
        replacements[id(pixels)] = out
    return mesh.with_images(replacements)


def unlimited():
    return Budget(ManualClock(), 0.0)


def test_maps_keep_normals_unit_and_facing_out_and_values_in_range(mesh):
    maps = LitMaps(flat_start(mesh), "cpu")
    with torch.no_grad():
        for values in maps.values.values():
            values.add_(torch.linspace(-2, 2, values.numel()).reshape(values.shape))
    maps.project()
    (normal,) = (maps.values[k] for k in maps.normal)
    vector = 2 * normal - 1
    torch.testing.assert_close(vector.norm(dim=-1), torch.ones(16, 16))
    assert float(vector[..., 2].min().detach()) >= 0
    assert all(0 <= float(v.min().detach()) and float(v.max().detach()) <= 1
               for v in maps.values.values())  # fmt: skip


def test_maps_write_8_bits_and_read_them_back(mesh):
    start = flat_start(mesh)
    maps = LitMaps(start, "cpu")
    with torch.no_grad():
        for values in maps.values.values():
            values.copy_(torch.rand(values.shape, generator=torch.Generator().manual_seed(1)))
    asset = maps.asset()
    for pixels, _ in asset.images():
        assert pixels.dtype == np.uint8 and pixels.shape == (16, 16, 3)
    base = asset.materials[0].base_color_texture
    stored = maps.values[id(start.materials[0].base_color_texture)]
    np.testing.assert_array_equal(base, stored.mul(255).round().byte().numpy())  # sRGB codes
    before = [v.clone() for v in maps.values.values()]
    with torch.no_grad():
        for values in maps.values.values():
            values.zero_()
    maps.restore(asset)
    for mine, old in zip(maps.values.values(), before, strict=True):
        torch.testing.assert_close(mine, old.mul(255).round() / 255)


def test_kept_slots_are_not_trained(mesh):
    start = flat_start(mesh)
    maps = LitMaps(start, "cpu", kept=("baseColorTexture",))
    base = start.materials[0].base_color_texture
    assert id(base) not in maps.values and len(maps.values) == 2
    assert maps.asset().materials[0].base_color_texture is base


def test_training_improves_a_flat_start_on_every_set(mesh):
    start = flat_start(mesh)
    best, facts = optimize_lit(mesh, start, {}, unlimited(), FEW, "cpu", evaluation=QUICK)
    assert facts.steps == 12 and facts.stopped_by == "steps"
    assert facts.shipped == TRAINED and facts.best_step > 0
    start_scores = facts.baseline_scores["start"]
    for name in ("Q", "near", "far"):
        assert facts.validation_scores[name] > start_scores[name] + 0.5
    assert best is not start


def test_what_returns_is_never_below_the_best_baseline_on_any_set(mesh):
    lanczos = every_map_by(mesh, PLAN, "lanczos")
    settings = LitSettings(steps=3, validation_views=2, pool_views=2, views_per_step=1)
    best, facts = optimize_lit(
        mesh, flat_start(mesh), {"lanczos": lanczos}, unlimited(), settings, "cpu",
        evaluation=QUICK,
    )  # fmt: skip
    # three steps from a flat start cannot reach Lanczos: Lanczos ships, and says so
    assert facts.shipped == "lanczos" and best is lanczos and facts.clears_floor
    assert facts.validation_scores == facts.baseline_scores["lanczos"]


def test_training_starts_from_the_other_start_that_validates_best(mesh):
    lanczos, flat = every_map_by(mesh, PLAN, "lanczos"), flat_start(mesh)
    settings = LitSettings(steps=0, validation_views=2, pool_views=2, views_per_step=1)
    others = {"flat": flat_start(mesh), "lanczos": lanczos}
    best, facts = optimize_lit(
        mesh, flat, {}, unlimited(), settings, "cpu", evaluation=QUICK, other_starts=others
    )
    assert facts.start_maps == "lanczos" and facts.shipped == "start" and best is lanczos
    assert facts.validation_scores == facts.baseline_scores["start"]
    # an other start below the start is scored and left
    best, facts = optimize_lit(
        mesh, lanczos, {}, unlimited(), settings, "cpu", evaluation=QUICK,
        other_starts={"flat": flat},
    )  # fmt: skip
    assert facts.start_maps is None and best is lanczos
    # one that ranks the same (here the same maps) leaves the start as it is
    best, facts = optimize_lit(
        mesh, lanczos, {}, unlimited(), settings, "cpu", evaluation=QUICK,
        other_starts={"same": every_map_by(mesh, PLAN, "lanczos")},
    )  # fmt: skip
    assert facts.start_maps is None and best is lanczos


def test_a_chosen_start_is_what_training_goes_back_to(mesh):
    from geoscaler.optim.lit import LitRun

    lanczos, flat = every_map_by(mesh, PLAN, "lanczos"), flat_start(mesh)
    settings = LitSettings(validation_views=2, pool_views=2, views_per_step=1, lr=10.0)
    run = LitRun(mesh, flat, {}, settings, "cpu", QUICK, {"lanczos": lanczos})
    run.begin()
    assert run.facts.start_maps == "lanczos"
    run.step(cache=False)  # a step far too large: it validates below the start
    run.validate()
    assert run.facts.backtracks == 1
    for (went_back, _), (chosen, _) in zip(
        run.maps.asset().images(), lanczos.images(), strict=True
    ):
        assert np.array_equal(went_back, chosen)


def test_the_other_starts_are_the_base_colours_with_every_other_map_by_a_filter(mesh):
    from geoscaler.pipeline.lit import EVERY_MAP, _baselines, _starts

    made = [None if m.base_color_texture is None else np.full((16, 16, 3), 7, np.uint8)
            for m in mesh.materials]  # fmt: skip
    baselines = _baselines(mesh, PLAN, None)
    start, others = _starts(mesh, PLAN, made, baselines)
    assert set(others) == set(EVERY_MAP)
    for name, other in others.items():
        for (pixels, places), (filtered, _) in zip(
            other.images(), baselines[name].images(), strict=True
        ):
            if places[0][1] == "baseColorTexture":
                assert (pixels[..., :3] == 7).all()
            else:
                assert np.array_equal(pixels, filtered)


def test_a_stopped_controller_or_a_spent_budget_takes_no_step(mesh):
    start = flat_start(mesh)
    controller = Controller()
    controller.stop()
    best, facts = optimize_lit(
        mesh, start, {}, unlimited(), FEW, "cpu", controller, evaluation=QUICK
    )
    assert (facts.steps, facts.stopped_by, facts.shipped) == (0, "stopped", "start")
    assert best is start
    spent = Budget(ManualClock(), -10.0, 5.0)
    best, facts = optimize_lit(mesh, start, {}, spent, FEW, "cpu", evaluation=QUICK)
    assert (facts.steps, facts.stopped_by, best) == (0, NOT_AFFORDED, start)
    assert not facts.validation_scores and not facts.clears_floor


SHARES = 2 * 1.0 + 2 * (2.4 / 1.5) ** 2 + 2 * (2.4 / 4.0) ** 2
"""Two views a set counted by their screen share against a Q view's (Q at 2.4, near guards
at 1.5, far ones at 4.0): 7.84."""


class SlowClock(ManualClock):
    """A clock that moves a second every time it is read: every view, score and step costs
    one second, whatever the machine."""

    def now(self) -> float:
        self.advance(1.0)
        return super().now()


def test_the_loop_runs_only_where_the_budget_holds_its_set_up_and_a_few_steps(mesh):
    start = flat_start(mesh)
    settings = LitSettings(validation_views=2, pool_views=4, views_per_step=2)
    # 2 + 2 + 2 views by their screen share, each with the start scored there: 7.84 x (1 + 1)
    # s, and 5 steps of 2 views: 25.68 s
    clock = SlowClock()
    _, facts = optimize_lit(mesh, start, {}, Budget(clock, clock.now(), 25.0), settings,
                            "cpu", evaluation=QUICK)  # fmt: skip
    assert facts.stopped_by == NOT_AFFORDED
    clock = SlowClock()
    budget = Budget(clock, clock.now(), 60.0)
    _, facts = optimize_lit(mesh, start, {}, budget, settings, "cpu", evaluation=QUICK)
    assert facts.stopped_by == "time budget" and facts.steps > 0
    assert budget.left() >= -1.0  # at most the last reading's second past the end


def test_the_training_pool_stops_growing_at_its_memory(mesh):
    settings = LitSettings(steps=6, validation_views=2, pool_views=6, views_per_step=1,
                           view_memory=1)  # fmt: skip
    _, facts = optimize_lit(mesh, flat_start(mesh), {}, unlimited(), settings, "cpu",
                            evaluation=QUICK)  # fmt: skip
    assert facts.training_views == 1  # the least a step needs, nothing more


def test_downsample_under_protocol_2_ships_every_map_trained_lit(tmp_path, capsys):
    from geoscaler.cli import main

    source = tmp_path / "pbr.glb"
    save_mesh(pbr_demo(texture_size=64, subdivisions=6), source)
    out = tmp_path / "out.gltf"
    argv = ["downsample", str(source), "-o", str(out), "--scale", "4", "--steps", "4",
            "--device", "cpu", "--report", str(tmp_path / "r.json")]  # fmt: skip
    assert main(argv, evaluation=QUICK) == 0
    printed = capsys.readouterr().out
    assert "lit (protocol 2): normal and data maps trained through lit views" in printed
    report = json.loads((tmp_path / "r.json").read_text())
    lit = report["details"]["lit"]
    assert lit["steps"] == 4 and set(lit["baseline_scores"]) == {
        "start", "lanczos", "bicubic", "class filters",
    }  # fmt: skip
    methods = {m["slots"][0].split("/")[1]: m["method"] for m in report["maps"]}
    chosen = lit["shipped"]
    if chosen == TRAINED:
        assert methods[NORMAL] == "trained through lit views (protocol 2)"
    assert lit["clears_floor"]
    shipped = load_mesh(out)
    assert shipped.materials[0].maps[NORMAL].shape[:2] == (16, 16)


def budgeted_lit_stage(folder) -> dict:
    """The report's lit stage of ``downsample`` on a small PBR asset, 4 steps, with a time
    budget (the job prices the stage under a budget only)."""
    from geoscaler.cli import main

    source = folder / "pbr.glb"
    save_mesh(pbr_demo(texture_size=64, subdivisions=6), source)
    argv = ["downsample", str(source), "-o", str(folder / "out.glb"), "--scale", "4",
            "--steps", "4", "--time-budget", "300", "--device", "cpu", "--uv", "keep",
            "--report", str(folder / "r.json")]  # fmt: skip
    assert main(argv, evaluation=QUICK) == 0
    return json.loads((folder / "r.json").read_text())["details"]["lit"]


def test_under_a_time_budget_the_job_trains_the_lit_run_it_priced(tmp_path, monkeypatch):
    from geoscaler.optim.lit import LitRun

    built, build = [], LitRun.__init__

    def counted(self, *args, **kwargs):
        built.append(self)
        build(self, *args, **kwargs)

    monkeypatch.setattr(LitRun, "__init__", counted)
    lit = budgeted_lit_stage(tmp_path)
    assert lit["steps"] == 4 and not lit["other_starts_left_out"]
    assert len(built) == 1  # priced before direct, then trained from direct's result


def test_protocol_1_leaves_the_other_maps_to_their_class_and_2_keeps_its_base_colour(tmp_path):
    from geoscaler.cli import main

    source = tmp_path / "pbr.glb"
    save_mesh(pbr_demo(texture_size=64, subdivisions=6), source)
    outputs = {}
    for protocol in ("1", "2"):
        out = tmp_path / f"out{protocol}.glb"
        argv = ["downsample", str(source), "-o", str(out), "--scale", "4", "--steps", "4",
                "--device", "cpu", "--protocol", protocol,
                "--report", str(tmp_path / f"r{protocol}.json")]  # fmt: skip
        assert main(argv, evaluation=QUICK) == 0
        outputs[protocol] = load_mesh(out)
    report = json.loads((tmp_path / "r1.json").read_text())
    assert "lit" not in report["details"]
    assert not any("lit views" in facts["method"] for facts in report["maps"])
    # the lit stage trains the maps only light shows; the base colour is direct's, unlit
    unlit, lit = (outputs[p].materials[0] for p in ("1", "2"))
    np.testing.assert_array_equal(lit.base_color_texture, unlit.base_color_texture)
    assert not np.array_equal(lit.maps[NORMAL], unlit.maps[NORMAL])


def test_a_method_the_lit_stage_does_not_follow_says_so(tmp_path, capsys):
    from geoscaler.cli import main

    source = tmp_path / "pbr.glb"
    save_mesh(pbr_demo(texture_size=64, subdivisions=6), source)
    argv = ["downsample", str(source), "-o", str(tmp_path / "out.glb"), "--scale", "4",
            "--method", "lanczos", "--device", "cpu"]  # fmt: skip
    assert main(argv, evaluation=QUICK) == 0
    assert "lit (protocol 2): not run: the lit stage follows direct only" in capsys.readouterr().out


def test_a_lit_run_is_priced_once_and_decides_on_that_price(mesh):
    from geoscaler.optim.lit import LEAST_STEPS, LitRun, least_seconds, train

    settings = LitSettings(validation_views=2, pool_views=4, views_per_step=2)
    run = LitRun(mesh, flat_start(mesh), {}, settings, "cpu", QUICK)
    clock = SlowClock()  # one second a reading: the view cached and the start's score, 1 s each
    price = run.price(clock)
    assert price.least == least_seconds(1.0, 1.0, SHARES, 1, settings)
    assert price.least == pytest.approx(SHARES * 2 + LEAST_STEPS * 2)  # 25.68 s
    readings = clock.now()
    assert run.price(clock) is price and clock.now() == readings + 1.0  # not priced again
    assert len(run.sets["Q"]) == 1  # its first view stays cached for the run
    _, facts = train(run, Budget(clock, clock.now(), 25.0))  # 26 s do not hold it
    assert facts.stopped_by == NOT_AFFORDED


def test_views_are_priced_by_the_screen_the_object_fills_in_them():
    from geoscaler.optim.lit import screen_shares
    from geoscaler.render.cameras import Camera

    timed = Camera((0.0, 0.0, 1.0), 2.4)
    halfway, twice = Camera((1.0, 0.0, 0.0), 1.2), Camera((0.0, 1.0, 0.0), 4.8)
    assert screen_shares([timed, halfway, twice], timed) == 1 + 4 + 0.25


def test_the_other_starts_are_weighed_only_where_the_time_holds_them_on_top(mesh):
    from geoscaler.optim.lit import LitRun, train

    settings = LitSettings(steps=1, validation_views=2, pool_views=4, views_per_step=2)
    others = {"lanczos": every_map_by(mesh, PLAN, "lanczos")}
    # least 7.84 x (1 + 1) + 5 x 2 = 25.68 s; the other start's scoring 7.84 x 1 s on top
    for seconds, weighed in ((35.0, True), (30.0, False)):
        run = LitRun(mesh, flat_start(mesh), {}, settings, "cpu", QUICK, others)
        clock = SlowClock()
        price = run.price(clock)
        assert (price.least, price.other_starts) == pytest.approx((SHARES * 2 + 10, SHARES))
        _, facts = train(run, Budget(clock, clock.now(), seconds))
        assert facts.other_starts_left_out is not weighed
        assert facts.start_maps == ("lanczos" if weighed else None)
        assert facts.steps == 1


def test_the_bound_under_the_price_counts_the_views_and_steps_at_an_unlit_views_cost(mesh):
    from geoscaler.optim.lit import LEAST_STEPS, LitRun, least_seconds_bound

    settings = LitSettings(validation_views=2, pool_views=4, views_per_step=2)
    bound = least_seconds_bound(1.0, QUICK, settings)
    assert bound == pytest.approx(SHARES * 1.0 + LEAST_STEPS * 2 * 1.0)
    run = LitRun(mesh, flat_start(mesh), {}, settings, "cpu", QUICK)
    assert bound < run.price(SlowClock()).least  # 1 s a view


def test_a_priced_stage_refused_its_share_is_not_held_through_the_method(tmp_path, monkeypatch):
    import geoscaler.pipeline.job as job

    given, train_lit = [], job.train_lit

    def recorded(*args):
        given.append(args[-2])  # the priced stage, or None
        return train_lit(*args)

    shares = iter([10.0, 0.0])  # the bound fits its share, the price found then does not
    monkeypatch.setattr(job, "lit_share", lambda seconds, price: next(shares))
    monkeypatch.setattr(job, "train_lit", recorded)
    lit = budgeted_lit_stage(tmp_path)
    assert given == [None]  # priced, refused: the method ran without it in memory
    assert lit["steps"] == 4  # the time left after the method's 4 steps held a stage built anew


def test_a_lit_stage_whose_bound_exceeds_its_share_is_never_built(tmp_path, monkeypatch):
    import geoscaler.pipeline.job as job
    from geoscaler.optim.lit import LitRun

    def unbuilt(*args, **kwargs):
        raise AssertionError("a lit run was built")

    monkeypatch.setattr(job, "least_seconds_bound", lambda view_seconds, evaluation: 1e6)
    monkeypatch.setattr(LitRun, "__init__", unbuilt)
    lit = budgeted_lit_stage(tmp_path)
    assert lit["stopped_by"] == NOT_AFFORDED and lit["steps"] == 0


def test_a_lit_share_too_short_for_the_stage_goes_to_the_method_before_it():
    from geoscaler.pipeline.job import lit_share
    from geoscaler.pipeline.lit import LIT_SHARE

    assert lit_share(20.0, 9.0) == LIT_SHARE * 20.0  # 10 s hold a stage of 9
    assert lit_share(15.0, 9.0) == 0.0  # 7.5 s do not: the method has all 15


def test_a_lit_stage_the_time_left_cannot_hold_spends_nothing(mesh, monkeypatch):
    import geoscaler.pipeline.lit as lit_stage
    from geoscaler.methods import MethodResult

    def untouched(*args, **kwargs):
        raise AssertionError("the stage was run")

    monkeypatch.setattr(lit_stage, "train", untouched)
    monkeypatch.setattr(lit_stage, "ship_asset", untouched)
    result = MethodResult([None])
    budget = Budget(ManualClock(), 0.0, 8.0)  # 8 s left for a stage priced at 8.8
    out = lit_stage.train_lit(mesh, PLAN, "direct", result, None, budget, "cpu", price=8.8)
    assert out.lit.stopped_by == NOT_AFFORDED and not out.lit.clears_floor
    assert out.textures == result.textures
