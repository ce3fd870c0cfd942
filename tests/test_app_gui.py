"""The desktop app, driven through its UI by the imgui test engine (``immapp`` runner, Xvfb).

One session, as an artist would use it: the app opens on the demo asset, the views show two
different non-empty pictures, Start trains (the step counter advances and the downsampled view
changes), a view is bookmarked and A/B-compared, the result is exported and loads again, and a
bad file shows an error while the app keeps running.

Set ``GEOSCALER_UPDATE_SCREENSHOT=1`` to also write the mid-training capture to docs/app.png.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from app_support import import_app_module, unavailable
from PIL import Image

from geoscaler.io import load_mesh
from geoscaler.procedural import demo_mesh

DOCS_SCREENSHOT = Path(__file__).resolve().parents[1] / "docs" / "app.png"


def crop(path: Path, rect: tuple[float, float, float, float]) -> np.ndarray:
    """``(h, w, 3)`` float pixels of a screenshot inside a view's screen rectangle."""
    x0, y0, x1, y1 = (int(round(v)) for v in rect)
    return np.asarray(Image.open(path).convert("RGB"), np.float32)[y0 + 2 : y1 - 2, x0 + 2 : x1 - 2]


def is_picture(pixels: np.ndarray) -> bool:
    """A rendered mesh: a good share of non-black pixels with varied colour."""
    covered = pixels.max(axis=2) > 20
    return covered.mean() > 0.2 and pixels[covered].std() > 10


def wait_until(ctx, condition, seconds: float) -> bool:
    """Let frames run (and the optimiser work) until ``condition()`` or ``seconds`` pass."""
    end = time.perf_counter() + seconds
    while not condition():
        if time.perf_counter() > end:
            return False
        time.sleep(0.05)  # the GIL to the worker between frames
        ctx.yield_()
    return True


@pytest.fixture
def gui_runner():
    if not os.environ.get("DISPLAY"):
        unavailable("no X display (run the tests under xvfb-run)")
    main = import_app_module("main")
    from imgui_bundle.immapp import testing

    return main, testing


def test_a_session_in_the_app(gui_runner, tmp_path):
    main, testing = gui_runner
    from geoscaler.app.training import TrainingSettings
    from geoscaler.protocol import Evaluation

    settings = TrainingSettings(
        method="direct",
        scale=4,
        steps=400,
        time_budget=120.0,
        evaluation=Evaluation(image_size=128, views=(0, 1)),
        optimize={"pool_views": 4, "validate_every": 5},
    )
    app = main.App(None, tmp_path / "out", settings, demo=lambda: demo_mesh(16, 512))
    names = ("start", "training", "difference", "wipe", "done")
    shots = {name: tmp_path / f"{name}.png" for name in names}
    seen: dict = {}

    def session(ctx) -> None:
        ctx.yield_(3)
        testing.capture(ctx, str(shots["start"]))
        seen["rects"] = dict(app.views.rects)
        seen["first label"] = app.session.candidate_label

        ctx.item_click("//Optimise/Start")
        assert wait_until(ctx, lambda: app.progress is not None and app.progress.step >= 6, 90)
        seen["steps"] = [app.progress.step]
        wait_until(ctx, lambda: app.progress.step >= seen["steps"][0] + 2, 30)
        seen["steps"].append(app.progress.step)
        ctx.yield_(2)
        testing.capture(ctx, str(shots["training"]))
        seen["training label"] = app.session.candidate_label

        ctx.item_click("//Bookmarks/Bookmark this view")
        ctx.item_click("//Optimise/Stop")
        assert wait_until(ctx, lambda: app.progress.result is not None, 60)
        ctx.yield_(2)
        ctx.item_click("//Bookmarks/view 1##0")
        ctx.item_click("//Bookmarks/A\\/B here")
        seen["metrics"] = app.bookmarks.metrics
        for mode in ("difference", "wipe"):
            ctx.item_click(f"//Views/{mode}")
            ctx.yield_(2)
            testing.capture(ctx, str(shots[mode]))
            seen[mode] = app.views.rects["##composed"]
        ctx.item_click("//Views/side by side")
        ctx.item_click("//Export/Export mesh + report")
        ctx.item_click("//Export/Save screenshot")
        ctx.yield_(2)
        testing.capture(ctx, str(shots["done"]))

        app.open(tmp_path / "broken.obj")
        wait_until(ctx, lambda: app.loading is None, 10)
        frames = app.frames
        ctx.yield_(3)
        seen["error"] = app.state.error
        seen["frames after error"] = app.frames - frames

    (tmp_path / "broken.obj").write_text("this is not a mesh\nf 1 2 3\n")
    testing.run(
        test_function=session, runner_params=app.runner_params(), add_ons_params=main.add_ons()
    )

    # Before training: two different, non-empty views (original | bicubic).
    original = crop(shots["start"], seen["rects"]["##original"])
    bicubic = crop(shots["start"], seen["rects"]["##downsampled"])
    assert is_picture(original) and is_picture(bicubic)
    assert np.abs(original - bicubic).mean() > 1.0
    assert seen["first label"] == "bicubic x4"

    # Training: the step counter advances and the downsampled view changes live.
    assert seen["steps"][1] > seen["steps"][0] >= 6
    assert seen["training label"].startswith("direct x4, step")
    live = crop(shots["training"], seen["rects"]["##downsampled"])
    assert is_picture(live)
    assert np.abs(live - bicubic).mean() > 0.2
    assert np.abs(crop(shots["training"], seen["rects"]["##original"]) - original).max() == 0

    # Bookmarks are saved beside the output, and A/B at one shows that view's metrics.
    saved = json.loads((tmp_path / "out" / "geoscaler_demo.bookmarks.json").read_text())
    assert [b["name"] for b in saved["bookmarks"]] == ["view 1"]
    assert 15.0 < seen["metrics"]["psnr_fg"] < 60.0
    assert 0.0 < seen["metrics"]["ssim_fg"] <= 1.0

    # Difference heatmap: black background, bright where the views differ; wipe: a picture.
    difference = crop(shots["difference"], seen["difference"])
    assert (difference.max(axis=2) < 5).mean() > 0.1 and difference.max() > 100
    wipe = crop(shots["wipe"], seen["wipe"])
    assert is_picture(wipe) and np.abs(difference - wipe).mean() > 10

    # Export: the mesh loads back with the 4x smaller texture, the report names the method.
    exported = load_mesh(tmp_path / "out" / "geoscaler_demo_x4.glb")
    assert exported.materials[0].base_color_texture.shape[:2] == (128, 128)
    assert len(exported.faces) == len(demo_mesh(16, 512).faces)
    report = json.loads((tmp_path / "out" / "geoscaler_demo_x4.json").read_text())
    assert report["method"] == "direct" and report["results"][0]["method"] == "direct"
    assert (tmp_path / "out" / "geoscaler_demo_view_1.png").is_file()

    # A bad file: an error in the UI, the demo stays open, frames keep coming.
    assert seen["error"] is not None and "broken.obj" in seen["error"]
    assert app.session is not None and app.session.mesh_path is None
    assert seen["frames after error"] >= 3

    if os.environ.get("GEOSCALER_UPDATE_SCREENSHOT") == "1":
        DOCS_SCREENSHOT.parent.mkdir(exist_ok=True)
        picture = Image.open(shots["training"]).convert("RGB")
        picture.quantize(colors=256, dither=Image.Dither.NONE).save(DOCS_SCREENSHOT, optimize=True)
