"""`geoscaler downsample` and `geoscaler demo` on a tiny procedural mesh.

The command runs as users run it, except for the settings a caller of ``main`` may pass:
3 validation views of 128 pixels stand for Q (the protocol: 60 of 512; with 2, no candidate
clears the floor's confidence on Q and the start ships) and the optimiser caches 4 training
views.
"""

import json
import os
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import geoscaler.cli
import geoscaler.pipeline.downsampling
import geoscaler.report.runner
from geoscaler.io import load_mesh, paths, save_mesh
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.report.console import DownsampleProgress
from geoscaler.report.runner import demo
from geoscaler.resize.filters import lanczos

QUICK_VIEWS = (0, 20, 40)
QUICK_EVALUATION = Evaluation.quick(QUICK_VIEWS)
# Two steps at the default learning rate (0.005 in sRGB units, after a 10-step warm-up) move no
# texel by a whole 8-bit code; these make two steps visible in the written texture, on enough
# views that they gain at every validation distance (from two views, the steps sharpen Q's views
# by 0.1 dB and lose 1 dB near and far: the floor ships the start).
QUICK_OPTIMIZE = {
    "pool_views": 4,
    "views_per_step": 4,
    "validate_every": 1,
    "lr": 0.02,
    "warmup_steps": 1,
}


def main(argv: list[str]) -> int:
    """``geoscaler.cli.main`` with the quick settings above."""
    return geoscaler.cli.main(argv, evaluation=QUICK_EVALUATION, optimize=QUICK_OPTIMIZE)


def tiny_mesh():
    return demo_mesh(subdivisions=4, texture_size=64)


@pytest.fixture(scope="module")
def glb(tmp_path_factory):
    path = tmp_path_factory.mktemp("input") / "tiny.glb"
    save_mesh(tiny_mesh(), path)
    return path


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def direct_run(glb, tmp_path_factory):
    """One `downsample --method direct --steps 20 --report` run; what it wrote and produced."""
    out_dir = tmp_path_factory.mktemp("out")
    before = folder_bytes(glb.parent)
    produced = {}
    real_export = geoscaler.pipeline.downsampling.export

    def spy(mesh, result, output, *args, **kwargs):
        produced["textures"] = [None if t is None else t.copy() for t in result.textures]
        produced["uvs"] = result.uvs
        return real_export(mesh, result, output, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:  # a spy: what the job hands the writer
        patch.setattr(geoscaler.pipeline.downsampling, "export", spy)
        argv = ["downsample", str(glb), "--scale", "4", "-o", str(out_dir / "small.glb")]
        argv += ["--steps", "20", "--device", "cpu", "--report", str(out_dir / "report.json")]
        status = main(argv)
    return {
        "status": status,
        "out": out_dir / "small.glb",
        "report": json.loads((out_dir / "report.json").read_text()),
        "produced": produced,
        "before": before,
        "after": folder_bytes(glb.parent),
    }


def test_direct_writes_the_mesh_with_the_new_texture(direct_run, glb):
    assert direct_run["status"] == 0
    written = load_mesh(direct_run["out"])
    (texture,) = direct_run["produced"]["textures"]
    assert texture.dtype == np.uint8 and texture.shape == (16, 16, 3)  # 64 / 4
    np.testing.assert_array_equal(written.materials[0].base_color_texture, texture)
    assert direct_run["produced"]["uvs"] is None  # direct keeps the mesh's UVs
    original = load_mesh(glb)
    np.testing.assert_array_equal(written.uvs[written.faces], original.uvs[original.faces])
    np.testing.assert_allclose(written.positions[written.faces], original.positions[original.faces])
    assert not np.array_equal(texture, lanczos(original.materials[0].base_color_texture, 4))


def test_report_json_has_protocol_results_and_gain(direct_run, glb):
    report = direct_run["report"]
    assert report["protocol"] == 1
    assert report["mesh"] == str(glb) and report["output"] == str(direct_run["out"])
    assert report["method"] == "direct" and report["scale"] == 4
    assert report["texture_size"] == [16, 16] and report["device"].startswith("cpu")
    rows = {row["method"]: row for row in report["results"]}
    assert list(rows) == ["direct", "bicubic", "lanczos"]
    assert rows["bicubic"]["gain_db"] == 0
    for row in rows.values():
        assert {"psnr_fg", "psnr_full", "ssim_full", "ssim_fg", "gain_db", "seconds"} <= set(row)
        assert row["views"] == len(QUICK_VIEWS)
    assert rows["direct"]["gain_db"] == pytest.approx(
        rows["direct"]["psnr_fg"] - rows["bicubic"]["psnr_fg"]
    )
    (texture,) = report["maps"]
    assert texture["format_after"] == "image/png" and texture["bytes_after"] > 0


def test_steps_stop_the_loop(direct_run):
    details = direct_run["report"]["details"]
    assert details["steps"] == 20 and details["stopped_by"] == "steps"
    assert details["validation_views"] == {"Q": 3, "near": 3, "far": 3}  # guards: no more than Q


def test_the_input_is_never_modified(direct_run):
    assert direct_run["after"] == direct_run["before"]


@pytest.mark.parametrize("suffix", [".obj", ".gltf"])
def test_obj_input_to_other_formats(tmp_path, suffix, capsys):
    source = tmp_path / "in"
    source.mkdir()
    save_mesh(tiny_mesh(), source / "tiny.obj")
    before = folder_bytes(source)
    out = tmp_path / f"small{suffix}"
    assert (
        main(["downsample", str(source / "tiny.obj"), "-o", str(out), "--method", "lanczos"]) == 0
    )
    assert folder_bytes(source) == before
    expected = lanczos(load_mesh(source / "tiny.obj").materials[0].base_color_texture, 4)
    np.testing.assert_array_equal(load_mesh(out).materials[0].base_color_texture, expected)
    printed = capsys.readouterr().out
    assert "lanczos" in printed and "bicubic" in printed and f"wrote {out}" in printed


def test_force_replaces_an_existing_output(glb, tmp_path):
    out = tmp_path / "small.glb"
    out.write_bytes(b"old")
    assert main(["downsample", str(glb), "-o", str(out), "--method", "box", "--force"]) == 0
    assert load_mesh(out).materials[0].base_color_texture.shape == (16, 16, 3)


@pytest.fixture
def no_work(monkeypatch):
    """Bad arguments must be refused before any heavy work starts."""

    def refuse(*args, **kwargs):
        raise AssertionError("heavy work started before the arguments were checked")

    monkeypatch.setattr(geoscaler.report.runner, "downsample_and_report", refuse)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--scale", "0"], "--scale 0: must be a whole number >= 2"),
        (["--scale", "1"], "whole number >= 2"),
        (["--scale", "128"], "larger than the 64 x 64 texture"),
        (["--method", "nope"], "unknown method; choose one of: box, bicubic, lanczos"),
        (["-o", "OUT.png"], "use one of .glb, .gltf, .obj"),
        (["-o", "MESH"], "refusing to overwrite the input file"),
        (["-o", "MESH", "--force"], "refusing to overwrite the input file"),
        (["-o", "EXISTING"], "already exists; pass --force"),
        (["-o", "MISSING/out.glb"], "does not exist"),
        (["--steps", "0"], "--steps 0: must be at least 1"),
        (["--time-budget", "0"], "--time-budget 0"),
        (["--time-budget", "inf"], "--time-budget inf: must be a positive number of seconds"),
        (["--seed", "-1"], "--seed -1: must be a whole number from 0 to 4294967295"),
        (["--report", "OUT"], "is the output mesh"),
        (["--report", "MESH"], "refusing to overwrite the input file"),
        (
            ["--method", "geoscaler", "--variant", "tiny"],
            "--variant 'tiny': unknown variant; choose one of",
        ),
        (["--variant", "base"], "only --method geoscaler has variants"),
        (["--method", "geoscaler", "--vgg19", "MISSING.pth"], "--vgg19 MISSING.pth: no such"),
    ],
)
def test_bad_arguments_exit_2_before_work(glb, tmp_path, no_work, capsys, extra, message):
    names = {
        "MESH": str(glb),
        "OUT": str(tmp_path / "out.glb"),
        "OUT.png": str(tmp_path / "out.png"),
        "EXISTING": str(tmp_path / "existing.glb"),
        "MISSING/out.glb": str(tmp_path / "missing" / "out.glb"),
    }
    (tmp_path / "existing.glb").write_bytes(b"keep")
    argv = ["downsample", str(glb), "-o", names["OUT"]] + [names.get(a, a) for a in extra]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("geoscaler: error:") and message in err, err
    assert "Traceback" not in err
    assert (tmp_path / "existing.glb").read_bytes() == b"keep"
    assert not (tmp_path / "out.glb").exists()


def test_a_fractional_scale_is_a_usage_error(glb, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["downsample", str(glb), "--scale", "1.5", "-o", str(tmp_path / "out.glb")])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--scale: '1.5' is not a whole number" in err and "Traceback" not in err


def test_an_unwritable_folder_is_refused(glb, tmp_path, no_work, monkeypatch, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        paths.os, "access", lambda p, mode: Path(p) != locked and real_access(p, mode)
    )
    assert main(["downsample", str(glb), "-o", str(locked / "out.glb")]) == 2
    err = capsys.readouterr().err
    assert "is not writable" in err and "Traceback" not in err


def test_a_folder_that_only_looks_writable_is_refused_before_work(
    glb, tmp_path, no_work, monkeypatch, capsys
):
    """Where ``os.access`` says yes but the file system makes no file (here an immutable
    folder, ``os.access`` overridden), the last check before work tries one and refuses."""
    locked = tmp_path / "locked"
    locked.mkdir()
    if subprocess.run(["chattr", "+i", str(locked)], capture_output=True).returncode:
        pytest.skip("chattr +i is not available here")
    monkeypatch.setattr(paths.os, "access", lambda p, mode: True)
    try:
        status = main(["downsample", str(glb), "-o", str(locked / "out.glb")])
    finally:
        subprocess.run(["chattr", "-i", str(locked)], check=True)
    assert status == 2
    err = capsys.readouterr().err
    assert f"folder {locked} is not writable (Operation not permitted)" in err
    assert list(locked.iterdir()) == []


def test_existing_side_files_of_an_obj_output_are_refused(glb, tmp_path, no_work, capsys):
    (tmp_path / "out.mtl").write_text("keep")
    assert main(["downsample", str(glb), "-o", str(tmp_path / "out.obj")]) == 2
    err = capsys.readouterr().err
    assert "out.mtl" in err and "--force" in err
    assert (tmp_path / "out.mtl").read_text() == "keep"


def test_the_step_bar_follows_the_runs_total_and_never_shows_negative_time_left():
    from geoscaler.clock import ManualClock
    from geoscaler.optim.events import ProgressEvent

    clock = ManualClock()
    progress = DownsampleProgress(enabled=False, clock=clock)
    progress.on_event(ProgressEvent("step", step=1, total_steps=10, elapsed=0.0))
    clock.set(4.0)
    assert progress.time_left(ProgressEvent("step", 5, 10, 4.0)) == pytest.approx(5.0)  # 1 s a step
    progress.method_started("direct", 4, time_budget=3.0)  # the budget ends first, at 7 s
    assert progress.time_left(ProgressEvent("step", 5, 10, 4.0)) == pytest.approx(3.0)
    # A race's continuation counts the losing trial's steps on top: the total grows with them.
    progress.on_event(ProgressEvent("step", step=12, total_steps=14, elapsed=6.0))
    assert (progress.bar.n, progress.bar.total) == (12, 14)
    assert progress.time_left(ProgressEvent("step", 15, 14, 7.0)) == 0.0
    progress.close()


def interrupt_at_step(monkeypatch, step: int, times: int) -> None:
    """Send SIGINT ``times`` times to this process when the loop reports ``step``."""
    real = DownsampleProgress.on_event

    def on_event(self, event):
        real(self, event)
        if event.phase == "step" and event.step == step:
            for _ in range(times):
                os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(DownsampleProgress, "on_event", on_event)


def test_ctrl_c_stops_cleanly_and_writes_the_best_result(glb, tmp_path, monkeypatch, capsys):
    interrupt_at_step(monkeypatch, 1, times=1)
    out, report = tmp_path / "out.glb", tmp_path / "report.json"
    argv = ["downsample", str(glb), "-o", str(out), "--steps", "50", "--report", str(report)]
    handler = signal.getsignal(signal.SIGINT)  # Python's default, or SIG_IGN in a background job
    assert main(argv) == 0
    details = json.loads(report.read_text())["details"]
    assert details["stopped_by"] == "stopped" and 1 <= details["steps"] < 50
    assert load_mesh(out).materials[0].base_color_texture.shape == (16, 16, 3)
    assert "Ctrl-C again to abort" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) is handler  # restored


def test_a_second_ctrl_c_aborts(glb, tmp_path, monkeypatch, capsys):
    interrupt_at_step(monkeypatch, 1, times=2)
    out = tmp_path / "out.glb"
    assert main(["downsample", str(glb), "-o", str(out), "--steps", "50"]) == 130
    assert not out.exists()
    assert "interrupted" in capsys.readouterr().err


def quick_demo(out_dir: Path, time_budget: float = 1e-3, steps: int | None = None) -> dict:
    """``geoscaler demo`` with the quick settings, by default under a budget too short for
    ``direct`` to run (the command's own: 75 s)."""
    return demo(
        out_dir, "cpu", time_budget, steps, evaluation=QUICK_EVALUATION, optimize=QUICK_OPTIMIZE
    )


def test_demo_builds_the_asset_and_writes_outputs(tmp_path, capsys):
    # one step, and a budget no busy machine runs out of before the layout is planned and
    # baked (its share of 300 s was not enough for a 2048 bake priced on a loaded machine)
    quick_demo(tmp_path / "demo", time_budget=3600.0, steps=1)
    written = sorted(p.name for p in (tmp_path / "demo").iterdir())
    assert written == [
        "demo_comparison.png",
        "geoscaler_pebble.glb",
        "geoscaler_pebble_x4.glb",
        "geoscaler_pebble_x4.json",
    ]
    report = json.loads((tmp_path / "demo" / "geoscaler_pebble_x4.json").read_text())
    assert report["protocol"] == 1 and report["method"] == "direct"
    assert report["details"]["steps"] == 1 and report["details"]["stopped_by"] == "steps"
    assert report["details"]["uv"] == "repack"  # the scan-like atlas: what the tool is for
    assert report["details"]["layout"]["charts"] == 31
    assert report["details"]["layout_used"] == "repack"
    picture = Image.open(tmp_path / "demo" / "demo_comparison.png")
    assert picture.size[0] == 3 * 256 + 2 * 4  # original | bicubic | direct
    asset = (tmp_path / "demo" / "geoscaler_pebble.glb").read_bytes()
    quick_demo(tmp_path / "demo")
    printed = capsys.readouterr().out
    assert "using the demo asset" in printed and "direct not run: the time budget" in printed
    assert (tmp_path / "demo" / "geoscaler_pebble.glb").read_bytes() == asset


def test_renderer_soft_trains_through_the_soft_rasteriser(glb, tmp_path):
    report = tmp_path / "r.json"
    argv = ["downsample", str(glb), "-o", str(tmp_path / "s.glb"), "--renderer", "soft"]
    argv += ["--steps", "1", "--device", "cpu", "--report", str(report)]
    assert main(argv) == 0
    details = json.loads(report.read_text())["details"]
    assert details["training_renderer"] == "soft" and details["steps"] == 1
