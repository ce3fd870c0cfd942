"""`geoscaler batch` over a small library: three tiny meshes (one in a subfolder, one named by
its folder's meta.json) and one corrupt file.

Jobs run as users run them, with Lanczos (deterministic, so outputs can be compared byte for
byte) and one validation view of 128 pixels; the process tests use `direct` under a short
budget so that there is a job to interrupt.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import geoscaler.batch
import geoscaler.batch.worker
import geoscaler.cli
from geoscaler.batch import DONE, FAILED, NOT_RUN, SKIPPED, SUMMARY_FILES
from geoscaler.batch.assets import STAGING_PREFIX, Asset, completed, plan_assets
from geoscaler.batch.worker import AssetTask, run_asset
from geoscaler.io import save_mesh
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation

QUICK = Evaluation.quick((0,))
JOB = ["--method", "lanczos", "--scale", "4", "--device", "cpu"]
ASSETS = ["a.glb", "broken.glb", "c/model.gltf", "sub/b.obj"]


def main(argv: list[str]) -> int:
    """``geoscaler.cli.main`` with the quick evaluation: the exit status."""
    return geoscaler.cli.main(argv, evaluation=QUICK)


def make_library(root: Path) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    save_mesh(demo_mesh(subdivisions=4, texture_size=64), root / "a.glb")
    (root / "sub").mkdir(parents=True)
    save_mesh(demo_mesh(subdivisions=3, texture_size=32), root / "sub" / "b.obj")
    (root / "c").mkdir()
    save_mesh(demo_mesh(subdivisions=4, texture_size=32), root / "c" / "model.gltf")
    save_mesh(demo_mesh(subdivisions=2, texture_size=32), root / "c" / "lod1.glb")  # not named
    (root / "c" / "meta.json").write_text(json.dumps({"entry": "model.gltf"}))
    (root / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00" + bytes(range(40)))
    (root / ".hidden").mkdir()
    save_mesh(demo_mesh(subdivisions=2, texture_size=32), root / ".hidden" / "x.glb")
    return root


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> Path:
    return make_library(tmp_path_factory.mktemp("library"))


def files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by relative path, reports and summaries left out."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not p.name.endswith(".report.json") and p.name not in SUMMARY_FILES
    }


def summary(folder: Path) -> dict:
    return json.loads((folder / "summary.json").read_text())


def rows_but_time(folder: Path) -> list[dict]:
    """The summary's rows without what depends on the run: seconds, threads, host."""
    drop = {"seconds", "device", "host"}
    return [{k: v for k, v in row.items() if k not in drop} for row in summary(folder)["assets"]]


def leftovers(folder: Path) -> list[str]:
    """Anything a run must not leave: staging folders, temporary files, the lock."""
    return [p.name for p in folder.rglob(".*")]


@pytest.fixture(scope="module")
def local_runs(library, tmp_path_factory):
    """The library with 1 and with 2 local jobs: exit status and output folder of each."""
    runs = {}
    for jobs in (1, 2):
        out = tmp_path_factory.mktemp(f"jobs{jobs}")
        runs[jobs] = (main(["batch", str(library), "-o", str(out), *JOB, "--jobs", str(jobs)]), out)
    return runs


# ----------------------------------------------------------------------------- finding assets


def test_assets_are_meta_entries_or_mesh_files_and_outputs_mirror_the_tree(library, tmp_path):
    inside = library / "out"  # OUT_DIR inside IN_DIR is not searched
    inside.mkdir()
    shutil.copy(library / "a.glb", inside / "written_before.glb")
    try:
        assets = plan_assets(library, inside, None)
    finally:
        shutil.rmtree(inside)
    assert [a.name for a in assets] == ASSETS  # no side file, no lod1, nothing hidden
    assert assets[3].output == inside / "sub" / "b.obj"
    assert assets[3].report == inside / "sub" / "b.report.json"
    assert [a.output.suffix for a in plan_assets(library, tmp_path, "glb")] == [".glb"] * 4


def test_two_assets_with_one_output_stem_are_not_both_written(tmp_path):
    (tmp_path / "in").mkdir()
    save_mesh(demo_mesh(subdivisions=2, texture_size=32), tmp_path / "in" / "a.obj")
    save_mesh(demo_mesh(subdivisions=2, texture_size=32), tmp_path / "in" / "a.glb")
    first, second = plan_assets(tmp_path / "in", tmp_path / "out", "gltf")
    assert first.problem is None
    assert "would overwrite those of a.glb" in second.problem


# ----------------------------------------------------------------------------- local engine


def test_a_bad_asset_fails_alone_and_the_status_counts_it(local_runs):
    status, out = local_runs[1]
    assert status == 1
    rows = {row["asset"]: row for row in summary(out)["assets"]}
    assert [rows[name]["status"] for name in ASSETS] == [DONE, FAILED, DONE, DONE]
    assert "broken.glb" in rows["broken.glb"]["error"]
    assert "\n" not in rows["broken.glb"]["error"]
    for name in ("a.glb", "c/model.gltf", "sub/b.obj"):
        assert rows[name]["gain_db"] is not None
        assert rows[name]["memory_after"] * 16 == rows[name]["memory_before"]  # 4x per side
        assert rows[name]["bytes_after"] > 0 and rows[name]["device"].startswith("cpu")
    listed = set()  # every file written belongs to an asset's report, which lists its files
    for name in ("a.glb", "c/model.gltf", "sub/b.obj"):
        output = out / rows[name]["output"]
        report = json.loads(output.with_name(output.stem + ".report.json").read_text())
        listed |= {
            (output.parent / f).relative_to(out).as_posix() for f in report["batch"]["outputs"]
        }
    assert set(files(out)) == listed
    assert (out / "sub" / "b.report.json").is_file() and not (out / "broken.glb").exists()
    assert leftovers(out) == []


def test_summary_has_csv_json_and_markdown_with_a_total(local_runs):
    _, out = local_runs[1]
    document = summary(out)
    total = document["total"]
    assert total["status"] == "3 done, 1 failed"
    done = [r for r in document["assets"] if r["status"] == DONE]
    assert total["bytes_after"] == sum(r["bytes_after"] for r in done)
    table = list(csv.DictReader((out / "summary.csv").open()))
    assert [row["asset"] for row in table] == [*ASSETS, "total"]
    markdown = (out / "summary.md").read_text()
    assert "| sub/b.obj | done |" in markdown and "| **total** |" in markdown
    assert "- broken.glb:" in markdown


def test_one_and_two_jobs_write_the_same_files_and_rows(local_runs):
    (status1, out1), (status2, out2) = local_runs[1], local_runs[2]
    assert status1 == status2 == 1
    assert files(out1) == files(out2)
    assert rows_but_time(out1) == rows_but_time(out2)
    assert summary(out2)["run"]["workers"].startswith("2 jobs x ")


def test_inputs_are_not_modified(library, local_runs):
    again = make_library(library.parent / "fresh")
    try:
        assert files(library) == files(again)
    finally:
        shutil.rmtree(again)


# ----------------------------------------------------------------------------- resume


def test_resume_does_no_work_on_a_finished_library(local_runs, library, tmp_path, monkeypatch):
    _, out = local_runs[2]
    copy = tmp_path / "library"  # the library without its bad asset, times kept
    shutil.copytree(library, copy)
    (copy / "broken.glb").unlink()
    runs = []
    monkeypatch.setattr(geoscaler.batch, "run_local", lambda tasks, *a: runs.append(tasks))
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.name not in SUMMARY_FILES}
    assert main(["batch", str(copy), "-o", str(out), *JOB]) == 2  # a batch ran there before
    assert main(["batch", str(copy), "-o", str(out), *JOB, "--resume"]) == 0
    assert runs == []
    assert {p: p.stat().st_mtime_ns for p in before} == before
    rows = summary(out)["assets"]
    assert [row["status"] for row in rows] == [SKIPPED] * 3
    assert [row["gain_db"] for row in rows] == [
        row["gain_db"] for row in summary(local_runs[1][1])["assets"] if row["status"] == DONE
    ]


def test_resume_redoes_an_asset_whose_input_or_options_changed(local_runs, library):
    _, out = local_runs[1]
    asset = next(a for a in plan_assets(library, out) if a.name == "sub/b.obj")
    record = json.loads(asset.report.read_text())["batch"]
    key = record["settings"]
    assert completed(asset, key) is not None
    assert completed(asset, {**key, "method": "bicubic"}) is None
    assert completed(asset, {**key, "protocol": 2}) is None
    texture = next(library / "sub" / f for f in record["inputs"] if f.endswith(".png"))
    stat = texture.stat()
    try:
        os.utime(texture, ns=(stat.st_atime_ns, time.time_ns() + 10**9))
        assert completed(asset, key) is None
    finally:
        os.utime(texture, ns=(stat.st_atime_ns, stat.st_mtime_ns))


# ----------------------------------------------------------------------------- interruptions


def test_an_interrupted_job_leaves_nothing(library, tmp_path, monkeypatch):
    args = geoscaler.cli.build_parser().parse_args(["batch", "x", "-o", "y", *JOB])
    args.optimize = None  # as main() sets it
    settings = geoscaler.cli.job_settings(args)
    asset = Asset("a.glb", library / "a.glb", tmp_path / "a.glb")

    def interrupted(job, *args, **kwargs):  # half the files written, then Ctrl-C Ctrl-C
        (job.output.parent / "a_basecolor.png").write_bytes(b"half")
        job.output.write_bytes(b"glTF")
        raise KeyboardInterrupt

    monkeypatch.setattr(geoscaler.batch.worker, "downsample_and_report", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_asset(AssetTask(asset, settings, {}, QUICK))
    assert list(tmp_path.iterdir()) == []


def test_a_ctrl_c_while_the_summary_is_written_waits_for_it(library, tmp_path, monkeypatch):
    # the second of two Ctrl-C can land just as the first has ended the run: the summary is
    # written whole, then the batch stops as interrupted
    monkeypatch.setattr(geoscaler.batch, "_run", lambda *args: False)  # no asset ran
    summarise = geoscaler.batch._summarise

    def interrupted(*args):
        os.kill(os.getpid(), signal.SIGINT)
        return summarise(*args)

    monkeypatch.setattr(geoscaler.batch, "_summarise", interrupted)
    assert geoscaler.cli.main(["batch", str(library), "-o", str(tmp_path), *JOB]) == 130
    assert {row["status"] for row in summary(tmp_path)["assets"]} == {NOT_RUN}
    assert all((tmp_path / name).exists() for name in SUMMARY_FILES)


WORKER = textwrap.dedent(
    """
    import sys
    import geoscaler.cli
    from geoscaler.protocol import Evaluation
    sys.exit(geoscaler.cli.main(evaluation=Evaluation.quick((0,))))
    """
)
"""The console script's ``sys.exit(main())`` with the quick evaluation: ``main`` reads
``sys.argv`` and runs as the process's command line, whose exit status a late Ctrl-C must not
change."""


def _wait_for_staging(out: Path, process: subprocess.Popen, timeout: float = 60) -> Path:
    end = time.monotonic() + timeout
    while time.monotonic() < end and process.poll() is None:
        found = list(out.rglob(STAGING_PREFIX + "*"))
        if found:
            return found[0]
        time.sleep(0.05)
    raise AssertionError(f"no job started in {out}: {process.communicate()}")


def _workers(pid: int) -> list[int]:
    """The pool's worker processes among ``pid``'s children (not the resource tracker)."""
    children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    return [
        int(child)
        for child in children
        if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes()
    ]


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc")
def test_a_killed_worker_and_ctrl_c_leave_only_complete_outputs(library, tmp_path):
    """The first asset's worker is killed mid-job; during the next, Ctrl-C twice."""
    argv = ["batch", str(library), "-o", str(tmp_path), "--method", "direct", "--scale", "4"]
    argv += ["--device", "cpu", "--time-budget", "20"]
    process = subprocess.Popen(
        [sys.executable, "-c", WORKER, *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's Ctrl-C reaches
    )
    try:
        first = _wait_for_staging(tmp_path, process)
        for worker in _workers(process.pid):
            os.kill(worker, signal.SIGKILL)
        while first.exists():
            time.sleep(0.05)
        _wait_for_staging(tmp_path, process)  # the next asset, in a new worker
        time.sleep(1.0)
        os.killpg(process.pid, signal.SIGINT)
        time.sleep(0.5)
        os.killpg(process.pid, signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, stderr
    rows = {row["asset"]: row for row in summary(tmp_path)["assets"]}
    assert rows["a.glb"]["status"] == FAILED and "worker process died" in rows["a.glb"]["error"]
    assert rows["broken.glb"]["status"] in (FAILED, NOT_RUN)
    assert rows["sub/b.obj"]["status"] == NOT_RUN  # nothing starts after the first Ctrl-C
    assert leftovers(tmp_path) == []
    written = files(tmp_path)
    for row in rows.values():  # an asset is there whole, with its report, or not at all
        stem = str(Path(row["asset"]).with_suffix(""))
        mine = [name for name in written if name.startswith(stem)]
        assert (row["status"] == DONE) == bool(mine), (row, mine)


# ----------------------------------------------------------------------------- Ray


def test_ray_engine_gives_the_same_files_and_rows(library, local_runs, tmp_path):
    ray = pytest.importorskip(
        "ray", reason="Ray is an optional extra: pip install 'geoscaler[ray]'"
    )
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR")
    try:
        status = main(["batch", str(library), "-o", str(tmp_path), *JOB, "--engine", "ray"])
    finally:
        ray.shutdown()
    _, out1 = local_runs[1]
    assert status == 1
    assert files(tmp_path) == files(out1)
    assert rows_but_time(tmp_path) == rows_but_time(out1)
    assert leftovers(tmp_path) == []


def test_ray_engine_without_ray_says_how_to_install_it(library, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    assert main(["batch", str(library), "-o", str(tmp_path), *JOB, "--engine", "ray"]) == 2
    assert "pip install 'geoscaler[ray]'" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_bad_folders_exit_2_before_work(library, tmp_path, capsys):
    assert main(["batch", str(tmp_path / "nope"), "-o", str(tmp_path / "o"), *JOB]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert main(["batch", str(library), "-o", str(library), *JOB]) == 2
    assert "is IN_DIR" in capsys.readouterr().err
