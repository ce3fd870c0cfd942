"""The app's parts that need no window: camera, bookmarks, UV inspector geometry, the training
worker, and the UV pictures drawn headless."""

from __future__ import annotations

import json
import math
import os
import sys
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
from app_support import gl_context, import_app_module
from mesh_support import pbr_demo

from geoscaler.errors import GeoscalerError
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import VALIDATION_DISTANCE, Evaluation

ONE_SMALL_VIEW = Evaluation(image_size=64, views=(0,))
"""The worker's torch renders in these tests: view 0 at 64 pixels (the app's: protocol 1)."""


@pytest.fixture(scope="module")
def app_modules():
    return {name: import_app_module(name) for name in ("orbit", "bookmarks", "uv_inspect")}


@pytest.fixture(scope="module")
def small_demo():
    return demo_mesh(subdivisions=8, texture_size=128)


def test_the_orbit_is_a_protocol_camera(app_modules):
    orbit = app_modules["orbit"].Orbit(yaw=0.0, pitch=0.0)
    camera = orbit.camera()
    assert camera.direction == pytest.approx((0.0, 0.0, 1.0))
    assert camera.distance == VALIDATION_DISTANCE
    orbit.rotate(dx=-225.0, dy=0.0)  # 0.4 degrees a pixel: a quarter turn
    assert orbit.camera().direction == pytest.approx((1.0, 0.0, 0.0), abs=1e-12)
    orbit.rotate(dx=0.0, dy=1000.0)  # pitch stops short of the pole
    assert orbit.pitch == 89.0
    orbit.zoom(100)
    assert orbit.distance == app_modules["orbit"].MIN_DISTANCE
    orbit.shift(50.0, 25.0, view_pixels=100.0)
    assert orbit.pan == (1.0, -0.5)
    orbit.reset()
    assert orbit == app_modules["orbit"].Orbit()


def test_bookmarks_are_saved_and_read_back(app_modules, tmp_path):
    Bookmarks = app_modules["bookmarks"].Bookmarks
    Orbit = app_modules["orbit"].Orbit
    path = tmp_path / "mesh.bookmarks.json"
    marks = Bookmarks(path, "mesh")
    marks.add(Orbit(10.0, 20.0, 3.0, (0.1, -0.2)))
    marks.add(Orbit(), name="front")
    marks.rename(0, "handle close-up")
    assert json.loads(path.read_text())["mesh"] == "mesh"
    again = Bookmarks(path, "mesh")
    assert [b.name for b in again.items] == ["handle close-up", "front"]
    assert again.items[0].orbit == Orbit(10.0, 20.0, 3.0, (0.1, -0.2))
    again.remove(1)
    assert [b.name for b in Bookmarks(path, "mesh").items] == ["handle close-up"]


def test_a_broken_bookmarks_file_is_a_clear_error(app_modules, tmp_path):
    path = tmp_path / "mesh.bookmarks.json"
    path.write_text('{"bookmarks": [{"name": "x"}]}')
    with pytest.raises(GeoscalerError, match="not a bookmarks file"):
        app_modules["bookmarks"].Bookmarks(path, "mesh")


def test_chart_outlines_of_the_demo_asset(app_modules, small_demo):
    """The demo asset has 6 square charts of 8 x 8 quads: 6 x 4 x 8 boundary edges."""
    outlines = app_modules["uv_inspect"].chart_outlines(small_demo)
    assert outlines.shape == (6 * 4 * 8, 2, 2)
    lengths = np.linalg.norm(outlines[:, 1] - outlines[:, 0], axis=1)
    assert np.allclose(lengths, lengths[0], rtol=1e-4)  # chart edges are split evenly


def test_warp_field_and_grid_follow_a_synthetic_warp(app_modules, small_demo):
    """UVs moved by a known smooth field: the field is recovered where faces cover the
    texture, and the grid points are moved by it."""
    inspect = app_modules["uv_inspect"]
    uv = small_demo.uvs.astype(np.float64)
    shift = np.stack([0.01 * np.sin(2 * np.pi * uv[:, 1]), np.full(len(uv), -0.005)], axis=1)
    displacement, covered = inspect.warp_field(small_demo, (uv + shift).astype(np.float32), 64)
    assert covered.mean() > 0.3
    rows, cols = np.nonzero(covered)
    v = 1.0 - (rows + 0.5) / 64
    expected = np.stack([0.01 * np.sin(2 * np.pi * v), np.full(len(v), -0.005)], axis=1)
    assert np.abs(displacement[rows, cols] - expected).max() < 2e-3  # linear across faces

    grid = inspect.warp_grid(displacement, covered, lines=16)
    still = inspect.warp_grid(np.zeros_like(displacement), covered, lines=16)
    assert grid.shape == still.shape and len(grid) > 100
    assert np.allclose(grid[..., 1] - still[..., 1], -0.005, atol=1e-4)

    picture = inspect.heatmap(np.linalg.norm(displacement, axis=-1), covered)
    assert picture.shape == (64, 64, 4) and picture.dtype == np.uint8
    assert (picture[~covered][:, :3] == 64).all()  # grey outside the charts


def test_uv_pictures_draw_texture_outlines_and_warp(app_modules, small_demo):
    ctx = gl_context()
    gl_renderer = import_app_module("gl_renderer")
    inspect = app_modules["uv_inspect"]
    renderer = gl_renderer.GLRenderer(ctx, small_demo, image_size=64)
    surface = renderer.reference_surface()
    picture = inspect.UVPicture(ctx, size=128)

    def pixels():
        data = np.frombuffer(picture.fbo.read(components=3), np.uint8)
        return data.reshape(128, 128, 3)[::-1].astype(int)

    picture.draw(surface.textures[0], [])
    plain = pixels()
    level0 = small_demo.materials[0].base_color_texture[..., :3].astype(int)  # 128 x 128
    assert np.abs(plain - level0).mean() < 2.0  # the texture as stored, right way up
    picture.draw(surface.textures[0], [(inspect.chart_outlines(small_demo), (1, 0, 0, 1))])
    outlined = pixels()
    red = (outlined == [255, 0, 0]).all(axis=2)
    assert 0.02 < red.mean() < 0.3
    segments = np.array([[[0.0, 0.5], [1.0, 0.5]]], np.float32)  # a warp grid line at v = 0.5
    picture.draw(None, [(segments, (0, 1, 1, 1))])
    assert (pixels()[63:65] == [0, 255, 255]).all(axis=2).any(axis=0).mean() > 0.95
    picture.release()
    surface.release()


def finished_run(
    mesh, method: str, steps: int, validate_every: int, renderer: str = "exact", uv: str = "auto"
):
    """The state of a small run of ``method`` on ``mesh`` (4x, 64-pixel views, ``uv`` layout),
    run to its end, validated every ``validate_every`` steps exactly (no backtracking, which
    adds validations; ``uv="keep"``: no layout race, whose trials validate at their ends)."""
    training = import_app_module("training")
    settings = training.TrainingSettings(
        method=method,
        scale=4,
        steps=steps,
        time_budget=60.0,
        evaluation=ONE_SMALL_VIEW,
        optimize={"pool_views": 2, "validate_every": validate_every, "backtrack": None},
        renderer=renderer,
        uv=uv,
    )
    run = training.Training(mesh, settings)
    run.start()
    assert run.wait(timeout=120), "the worker did not finish"
    state = run.read()
    assert state.error is None, state.error
    return state


def test_training_runs_off_thread_and_reports(small_demo):
    state = finished_run(small_demo, "direct", steps=12, validate_every=4, uv="keep")
    assert state.phase == "done" and state.step == 12
    assert state.steps == list(range(1, 13)) and all(math.isfinite(x) for x in state.losses)
    assert state.validation_steps == [4, 8, 12]
    assert len(state.validation_ssim) == 3 and all(0 < x <= 1 for x in state.validation_ssim)
    assert math.isfinite(state.bicubic_psnr) and math.isfinite(state.gain)
    assert state.textures[0].shape == (32, 32, 3)
    assert [level.shape[:2] for level in state.chains[0]][:3] == [(32, 32), (16, 16), (8, 8)]
    assert {row["method"] for row in state.result.rows} == {"direct", "bicubic", "lanczos"}


def test_the_app_trains_through_the_soft_renderer_when_chosen(small_demo):
    state = finished_run(small_demo, "direct", steps=2, validate_every=2, renderer="soft")
    assert state.phase == "done" and state.step == 2
    assert state.result.result.training_renderer == "soft"


def test_training_pauses_resumes_and_stops(small_demo):
    training = import_app_module("training")
    settings = training.TrainingSettings(
        steps=10_000,
        time_budget=120.0,
        evaluation=ONE_SMALL_VIEW,
        optimize={"pool_views": 2},
    )
    run = training.Training(small_demo, settings)
    run.start()
    deadline = time.perf_counter() + 60
    while run.read().step < 3 and time.perf_counter() < deadline:
        time.sleep(0.05)
    run.pause()
    time.sleep(0.3)
    paused_at = run.read().step
    if sys.platform == "linux":  # the app's priority: a busy neighbour slows it, not stops it
        own = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        assert os.getpriority(os.PRIO_PROCESS, run.thread.native_id) == own
    time.sleep(0.5)
    assert run.read().step <= paused_at + 1 and run.read().phase == "paused"
    run.resume()
    run.stop()
    assert run.wait(timeout=60)
    state = run.read()
    assert state.phase == "done" and state.step < 10_000
    assert state.result.result.loop.stopped_by == "stopped"


def test_the_worker_holds_back_after_each_step_while_the_user_moves_the_camera(small_demo):
    training = import_app_module("training")
    run = training.Training(small_demo, training.TrainingSettings(evaluation=ONE_SMALL_VIEW))
    run._last_step_at = 10.0
    assert run.hold_back(10.4) == 0.0  # nobody moved the camera
    run._user_moved_at = 10.5
    assert run.hold_back(10.7) == pytest.approx(0.3)  # a 0.3 s step, 0.2 s after a move
    run._user_moved_at = 11.1
    assert run.hold_back(11.2) == pytest.approx(0.2)  # timed from the end of the pause (11.0)
    assert run.hold_back(11.6) == 0.0  # 0.5 s after the last move: the user let go
    run._user_moved_at = 20.0
    assert run.hold_back(20.1) == training.MAX_HOLD  # a long gap holds back at most 1 s


def test_bad_settings_are_refused_before_the_worker_starts(small_demo):
    training = import_app_module("training")
    with pytest.raises(GeoscalerError, match="larger than the 128 x 128 texture"):
        training.Training(small_demo, training.TrainingSettings(method="bicubic", scale=512))


def test_a_failing_method_reports_its_error(small_demo, request):
    from geoscaler.methods import registry

    def broken(mesh, scale, options, context):
        raise RuntimeError("out of texels")

    registry.register("broken", broken, learned=True)
    request.addfinalizer(lambda: registry.unregister("broken"))
    training = import_app_module("training")
    settings = training.TrainingSettings(method="broken", evaluation=ONE_SMALL_VIEW)
    run = training.Training(small_demo, settings)
    run.start()
    assert run.wait(timeout=60)
    assert run.read().phase == "failed"
    assert run.read().error == "RuntimeError: out of texels"


def test_the_uv_inspector_shows_the_warp_of_new_uvs(small_demo, tmp_path):
    """A method that returns new UVs (here a synthetic shift of 2 texels of the 32-texel result):
    the inspector adds the deformed grid and a warp heatmap that reads 2 texels."""
    ctx = gl_context()
    session_module = import_app_module("session")
    panels = import_app_module("panels")
    session = session_module.Session(ctx, small_demo, None, tmp_path, scale=4, image_size=64)

    class App:  # what UVPanel reads of the app
        pass

    app = App()
    app.session = session
    panel = panels.UVPanel()
    panel._update(app)
    assert panel.warp_texture is None  # bicubic keeps the mesh's UVs
    texture = session.candidate_textures[0]
    warped = (small_demo.uvs + np.float32(2.0 / 32)).astype(np.float32)
    session.set_candidate([texture], warped, "warped")
    panel._update(app)
    assert panel.warp_texture is not None
    assert panel.warp_max_texels == pytest.approx(2.0 * math.sqrt(2.0), rel=1e-3)
    session.release()


def test_every_shader_is_shipped_with_the_package():
    """setup.py installs shaders/*.vert and *.frag as package data of geoscaler.shaders: besides
    the package's own ``__init__.py``, nothing else is there, and the app reads them from it."""
    gl_renderer = import_app_module("gl_renderer")
    package = {"__init__.py", "__pycache__"}
    names = sorted(p.name for p in gl_renderer.shader_files().iterdir() if p.name not in package)
    assert names and all(name.endswith((".vert", ".frag")) for name in names), names
    for name in names:
        assert gl_renderer.shader_source(name).startswith("#version"), name
    with pytest.raises(GeoscalerError, match="not found"):
        gl_renderer.shader_source("missing.frag")


def test_the_live_candidate_carries_the_uvs_of_a_warping_method(small_demo):
    state = finished_run(small_demo, "geoscaler-uvw", steps=3, validate_every=3)
    assert state.uvs is not None and state.uvs.shape == small_demo.uvs.shape
    assert state.result.result.uvs is not None
    assert len(state.validation_ssim) == 1


def test_the_run_settings_default_to_the_clis(small_demo):
    """Steps: the method's own default; time budget: the CLI's 60 s; None is no limit."""
    training = import_app_module("training")
    from geoscaler.methods import default_steps
    from geoscaler.methods.direct import DEFAULT_CONFIG
    from geoscaler.methods.network import DEFAULT_PRESET, PRESETS
    from geoscaler.pipeline.arguments import DEFAULT_TIME_BUDGET

    settings = training.TrainingSettings(evaluation=ONE_SMALL_VIEW)
    assert settings.time_budget == DEFAULT_TIME_BUDGET == 60.0
    assert settings.step_limit() == DEFAULT_CONFIG["steps"]
    network_steps = PRESETS[DEFAULT_PRESET].optimize["steps"]
    assert default_steps("geoscaler") == network_steps
    assert default_steps("geoscaler-uvw") == network_steps
    assert default_steps("geoscaler", {"preset": "paper"}) == 15_000
    assert default_steps("direct", {"optimize": {"steps": 7, "lr": 0.1}}) == 7  # loop overrides
    assert default_steps("bicubic") is None

    run = training.Training(small_demo, settings)
    assert run.options.time_budget == 60.0 and run.options.steps is None
    assert run.read().total_steps == DEFAULT_CONFIG["steps"]
    unlimited = training.Training(small_demo, replace(settings, steps=9, time_budget=None))
    assert unlimited.options.time_budget is None and unlimited.options.steps == 9
    assert unlimited.read().total_steps == 9
    bicubic = training.Training(small_demo, replace(settings, method="bicubic"))
    assert bicubic.options.time_budget is None  # as the CLI: no budget for a filter


def test_the_optimise_fields_read_and_show_the_settings():
    training = import_app_module("training")
    panels = import_app_module("panels")
    settings = training.TrainingSettings()
    assert (panels.steps_text(settings), panels.budget_text(settings)) == ("300", "60")
    assert "300 steps (direct's default) or 60 s" in panels.run_summary(settings)
    panels.read_steps("250", settings)
    panels.read_budget("12.5", settings)
    assert (settings.steps, settings.time_budget) == (250, 12.5)
    for half_typed in ("0", "-3", "2.5", "."):  # not a limit: the settings stay as they were
        panels.read_steps(half_typed, settings)
    for half_typed in ("0", "-3", ".", "1e999"):
        panels.read_budget(half_typed, settings)
    assert (settings.steps, settings.time_budget) == (250, 12.5)
    panels.read_steps("", settings)
    panels.read_budget("", settings)
    assert (settings.steps, settings.time_budget) == (None, None)
    assert (panels.steps_text(settings), panels.budget_text(settings)) == ("300", "no limit")
    assert panels.run_summary(settings).endswith("no time limit")
    panels.read_budget("no limit", settings)
    assert settings.time_budget is None


def test_plot_axes_hold_the_reference_and_their_ticks_fit():
    panels = import_app_module("panels")
    low, high = panels.padded([37.6, 38.4, 38.1, 37.06])  # bicubic's level below the curve
    assert low < 37.06 and high > 38.4
    assert panels.padded([float("nan")]) is None
    low, high = panels.padded([36.0])  # one validation: a small span around it
    assert low < 36.0 < high
    for lo, hi, count in [(98.0, 202.0, 3), (98.0, 202.0, 8), (0.4, 30.6, 4), (35.0, 36.1, 6)]:
        ticks = panels.nice_ticks(lo, hi, count)
        assert 2 <= len(ticks) <= count and lo <= ticks[0] and ticks[-1] <= hi
        steps = np.diff(ticks)
        assert np.allclose(steps, steps[0])
        mantissa = steps[0] / 10 ** math.floor(math.log10(steps[0]))
        assert min(abs(mantissa - m) for m in (1, 2, 5)) < 1e-9
    assert panels.nice_ticks(100.0, 200.0, 3) == [100.0, 150.0, 200.0]


def stretched(mesh, factors):
    """``mesh`` with its positions scaled per axis (a wide or tall version of it)."""
    return replace(mesh, positions=(mesh.positions * np.float32(factors)).astype(np.float32))


def project(orbit, points: np.ndarray, aspect: float) -> np.ndarray:
    """Normalised device coordinates ``(N, 2)`` of ``points`` in a view ``aspect`` wide, as the
    app's renderer projects them."""
    gl_renderer = import_app_module("gl_renderer")
    scale = np.diag([*gl_renderer.view_scale(aspect, 1.0), 1.0, 1.0])
    clip = gl_renderer.pan_matrix(orbit.pan) @ scale @ orbit.camera().clip_matrix()
    homogeneous = np.c_[points, np.ones(len(points))] @ clip.T
    return homogeneous[:, :2] / homogeneous[:, 3:]


@pytest.mark.parametrize(
    ("factors", "aspect"), [((3, 1, 1), 4.0), ((1, 3, 1), 0.5), ((1, 1, 1), 1.0)]
)
def test_framing_fills_the_view_with_the_mesh(app_modules, small_demo, factors, aspect):
    """Wide, tall and square meshes in views of their shape: the mesh's outline is centred and
    spans FILL of the view's width or height, so nothing of it is cut off."""
    orbit_module = app_modules["orbit"]
    points = stretched(small_demo, factors).normalized_positions()
    orbit = orbit_module.Orbit()
    orbit.frame(points, aspect)
    ndc = project(orbit, points, aspect)
    low, high = ndc.min(axis=0), ndc.max(axis=0)
    assert np.abs(low + high).max() < 1e-6  # centred
    assert (high - low).max() == pytest.approx(2 * orbit_module.FILL, abs=1e-3)
    assert orbit_module.MIN_DISTANCE <= orbit.distance <= orbit_module.MAX_DISTANCE


def test_two_views_stack_for_a_wide_mesh():
    views = import_app_module("views")
    stacked, width, height = views.split_views(1000.0, 600.0, outline=(4.0, 1.0), label=20.0)
    assert stacked and width == 1000.0 and height == (600.0 - views.GAP) / 2 - 20.0
    stacked, width, height = views.split_views(1000.0, 600.0, outline=(1.0, 2.0), label=20.0)
    assert not stacked and width == (1000.0 - views.GAP) / 2 and height == 600.0 - 20.0
    assert not views.split_views(1000.0, 600.0, outline=(1.2, 1.0))[0]  # about square
    # Whole screen units: two views 386.5 wide would cover 386 and 387 pixels on screen.
    assert views.split_views(781.0, 600.5, outline=(1.0, 1.0), label=17.25) == (False, 386.0, 583.0)
    assert views.split_views(781.5, 40.0, outline=(1.0, 1.0)) == (False, 386.0, views.MIN_VIEW)
    assert views.pixel_shape(500.0, 300.0, 2.0) == (1000, 600)  # one texel a pixel
    width, height = views.pixel_shape(4000.0, 2000.0, 1.0)  # capped, the shape kept
    assert width * height <= views.MAX_VIEW_PIXELS and width == pytest.approx(2 * height, abs=1)


def test_a_wide_view_of_a_wide_mesh_is_filled(app_modules, small_demo):
    """The GL views render at any shape: a wide mesh framed in a 4:1 target reaches across it,
    none of it cut off."""
    ctx = gl_context()
    gl_renderer = import_app_module("gl_renderer")
    wide = stretched(small_demo, (3, 1, 1))
    renderer = gl_renderer.GLRenderer(ctx, wide, image_size=64)
    surface = renderer.reference_surface()
    orbit = app_modules["orbit"].Orbit()
    orbit.frame(wide.normalized_positions(), 4.0)
    target = renderer.target((256, 64))
    _, covered = renderer.render(orbit.camera(), surface, target, orbit.pan).read()
    assert covered.shape == (64, 256)
    rows, cols = np.nonzero(covered)
    spans = ((np.ptp(cols) + 1) / 256, (np.ptp(rows) + 1) / 64)
    assert max(spans) > 0.85  # filled across (FILL: 0.92)
    assert not (covered[0].any() or covered[-1].any())  # nothing cut off
    assert not (covered[:, 0].any() or covered[:, -1].any())
    target.release()
    surface.release()


def test_the_lit_toggle_draws_both_views_lit_and_the_candidate_ships_smaller_maps(tmp_path):
    ctx = gl_context()
    session_module, views_module = import_app_module("session"), import_app_module("views")
    session = session_module.Session(ctx, pbr_demo(), None, tmp_path, scale=4, image_size=64)
    views = views_module.ViewsPanel()
    views.render(session, views_module.SIDE_BY_SIDE)
    unlit = [target.read()[0] for target in session.targets]
    views.dirty = True
    views.render(session, views_module.SIDE_BY_SIDE, lit=True)
    lit = [target.read()[0] for target in session.targets]
    for before, after in zip(unlit, lit, strict=True):
        assert np.abs(before.astype(int) - after.astype(int)).mean() > 5
    asset = session.candidate_asset()
    assert asset.materials[0].maps["normalTexture"].shape == (32, 32, 3)
    assert asset.materials[0].base_color_texture is session.candidate_textures[0]
    warped = (session.mesh.uvs + np.float32(0.01)).astype(np.float32)
    session.set_candidate(session.candidate_textures, warped, "warped")
    assert session.lit_surfaces()[1] is None  # a new layout's maps are not re-baked live
    session.release()
