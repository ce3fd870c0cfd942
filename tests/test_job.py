"""The job ships what it validated, and never less than the filters it scored beside it.

A training pool cut to one view (as a busy machine's caching deadline can leave it) reads few
texels; the rest are filled from the charts. Before, that fill came after the last validation,
so the job shipped a texture nobody had scored: on this mesh 14.89 dB PSNR-fg on Q while its
validated start scored 20.65 (Lanczos).
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from geoscaler.cli import main
from geoscaler.io import save_mesh
from geoscaler.job import compare_mesh, no_worse_than_filters
from geoscaler.methods import MethodOptions, MethodResult, get_method, registry
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.render import Renderer

ONE_VIEW_POOL = {"pool_views": 1, "views_per_step": 1, "validate_every": 1}


@pytest.fixture(scope="module")
def cut_short():
    """``direct`` trained on a pool of one view, beside Lanczos (and bicubic), on two views."""
    mesh = demo_mesh(subdivisions=8, texture_size=128)
    options = MethodOptions(device="cpu", steps=2, settings={"optimize": ONE_VIEW_POOL})
    renderer = Renderer(mesh, "cpu", Evaluation.quick((0, 31), image_size=128))
    return compare_mesh(mesh, [4], ["direct", "lanczos"], options=options, renderer=renderer)


def test_what_ships_is_what_was_validated(cut_short):
    details = cut_short.outputs["direct", 4].details
    # the loop's best validation score is the job's score of the optimised texture on Q
    assert details["optimised_psnr_fg"] == pytest.approx(details["validation_psnr_fg"], abs=1e-4)


def test_a_pool_cut_short_never_ships_below_the_filters(cut_short):
    rows = {row["method"]: row for row in cut_short.rows}
    details = cut_short.outputs["direct", 4].details
    assert details["optimised_psnr_fg"] < rows["lanczos"]["psnr_fg"]  # the premise
    assert rows["direct"]["shipped"] == details["shipped"] == "lanczos"
    assert rows["direct"]["psnr_fg"] == rows["lanczos"]["psnr_fg"]
    shipped = cut_short.outputs["direct", 4].textures[0]
    np.testing.assert_array_equal(shipped, cut_short.outputs["lanczos", 4].textures[0])


def _scored(name: str, psnr: float) -> tuple[MethodResult, dict]:
    texture = np.full((2, 2, 3), int(psnr), np.uint8)
    return MethodResult([texture], seconds=1.0), {"method": name, "psnr_fg": psnr}


def test_a_learned_result_that_beats_every_filter_ships_itself():
    result, row = _scored("direct", 31.0)
    filters = dict([("bicubic", _scored("bicubic", 29.0)), ("lanczos", _scored("lanczos", 30.0))])
    shipped, shipped_row = no_worse_than_filters("direct", result, row, filters)
    assert shipped is result and shipped_row is row
    assert shipped.details == {"optimised_psnr_fg": 31.0, "shipped": "direct"}


def test_the_best_filter_ships_when_it_beats_the_learned_result():
    result, row = _scored("direct", 29.5)
    result.uvs = np.zeros((3, 2), np.float32)
    filters = dict([("bicubic", _scored("bicubic", 29.0)), ("lanczos", _scored("lanczos", 30.0))])
    shipped, shipped_row = no_worse_than_filters("direct", result, row, filters)
    assert shipped.textures[0][0, 0, 0] == 30 and shipped.uvs is None  # the filter's, its UVs
    assert shipped.details == {"optimised_psnr_fg": 29.5, "shipped": "lanczos"}
    assert shipped.seconds == 1.0
    assert shipped_row == {
        "method": "direct",
        "psnr_fg": 30.0,
        "seconds": 1.0,
        "shipped": "lanczos",
    }


def test_without_filters_the_learned_result_ships():
    result, row = _scored("direct", 10.0)
    shipped, _ = no_worse_than_filters("direct", result, row, {})
    assert shipped is result and shipped.details["shipped"] == "direct"


def test_the_report_says_what_shipped(tmp_path, capsys):
    mesh_path, out, report = tmp_path / "mesh.glb", tmp_path / "out.glb", tmp_path / "r.json"
    save_mesh(demo_mesh(subdivisions=8, texture_size=128), mesh_path)
    argv = ["downsample", str(mesh_path), "-o", str(out), "--steps", "2", "--report", str(report)]
    quick = Evaluation.quick((0, 31), image_size=128)
    assert main(argv, evaluation=quick, optimize=ONE_VIEW_POOL) == 0
    printed = capsys.readouterr().out
    assert "shipped lanczos: it scored higher on Q than direct's own result" in printed
    document = json.loads(report.read_text())
    assert document["details"]["shipped"] == document["results"][0]["shipped"] == "lanczos"


@pytest.fixture
def budget_spy():
    """A learned method (bicubic's texture) that records the budget the job hands it."""
    budgets: list[float | None] = []

    def learned(mesh, scale, options, context):
        budgets.append(context.time_budget)
        return get_method("bicubic").run(mesh, scale, options, context)

    registry.register("budget-spy", learned, learned=True)
    yield budgets
    registry.unregister("budget-spy")


@pytest.mark.parametrize("already_spent", [25.0, 40.0])
def test_a_whole_job_budget_leaves_the_method_only_what_is_left(budget_spy, already_spent):
    """With ``started_at`` the budget is the job's wall clock: the method gets the budget less
    everything spent since the job began (here 25 s or 40 s before the comparison, as a slow
    load would), less the reserve for what comes after it."""
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    options = MethodOptions(device="cpu", time_budget=30.0)
    renderer = Renderer(mesh, "cpu", Evaluation.quick((0,), image_size=64))
    before = time.perf_counter()
    began = before - already_spent
    compare_mesh(
        mesh, [4], ["budget-spy", "lanczos"], options=options, renderer=renderer,
        started_at=began, reserve=2.0,
    )  # fmt: skip
    took = time.perf_counter() - before
    (budget,) = budget_spy
    upper = 30.0 - already_spent - 2.0  # the job's own work before the method only lowers it
    lower = upper - 2.5 * took  # that work, and 1.5 times the scoring of one filter
    assert max(lower, 1e-3) <= budget <= max(upper, 1e-3)
