"""Writing into a folder that fills up: `geoscaler downsample` and `geoscaler batch` on a small
tmpfs mounted for the test (as root; skipped where mounting is not allowed).

Expected of every failed write: one line that names the file, says that the device is full
and what to do; a non-zero exit status; nothing of the failed output left in the folder (no
temporary file, no staging folder, no mesh without its report). A batch goes on with the next
asset and its summary says why the asset failed.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import ONE_VIEW
from mesh_support import quad_mesh

from geoscaler.cli import main
from geoscaler.io import save_mesh
from geoscaler.procedural import demo_mesh

PAGE = 4096
FULL = "no space left on the device; free space or choose another output folder"
JOB = ["--method", "lanczos", "--device", "cpu"]


def run(argv: list[str]) -> int:
    return main(argv, evaluation=ONE_VIEW)


def _mount_error(folder: Path, size: int) -> str | None:
    """Mount a tmpfs of ``size`` bytes on ``folder``; why not, or None."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return "mounting a tmpfs needs root and mount(8)"
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "geoscaler-test", str(folder)],
        capture_output=True,
        text=True,
    )
    return None if done.returncode == 0 else f"cannot mount a tmpfs: {done.stderr.strip()}"


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Callable[[int], Path]]:
    """``small_disk(size)``: a new folder on a tmpfs of ``size`` bytes (whole pages)."""
    mounted: list[Path] = []

    def make(size: int) -> Path:
        folder = tmp_path / f"disk{len(mounted)}"
        folder.mkdir()
        why = _mount_error(folder, size)
        if why is not None:
            pytest.skip(why)
        mounted.append(folder)
        return folder

    yield make
    for folder in mounted:
        subprocess.run(["umount", str(folder)], check=True)


def noise_mesh(size: int, seed: int = 0):
    """A quad with a ``size`` x ``size`` noise texture: its PNG hardly compresses."""
    texture = np.random.default_rng(seed).integers(0, 256, (size, size, 3), dtype=np.uint8)
    return quad_mesh(texture)


def pages(nbytes: int) -> int:
    return -(-nbytes // PAGE) * PAGE


def error_lines(err: str) -> list[str]:
    """What stderr says besides progress bars: lines that are not a bar's redraw."""
    return [line for line in err.splitlines() if line.startswith("geoscaler:")]


# ----------------------------------------------------------------------------- downsample


@pytest.fixture(scope="module")
def noise_glb(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("noise") / "noise.glb"
    save_mesh(noise_mesh(512), path)  # at --scale 2 a 256 x 256 PNG of about 190 kB
    return path


def test_a_mesh_that_does_not_fit_fails_with_one_line_and_leaves_nothing(
    noise_glb, small_disk, capsys
):
    disk = small_disk(16 * PAGE)
    out, report = disk / "small.glb", disk / "small.json"
    argv = ["downsample", str(noise_glb), "--scale", "2", "-o", str(out), "--report", str(report)]
    assert run([*argv, *JOB]) == 2
    err = capsys.readouterr().err
    assert error_lines(err) == [f"geoscaler: error: {out}: {FULL}"]
    assert "Traceback" not in err
    assert list(disk.iterdir()) == []


def test_a_report_that_does_not_fit_takes_the_written_mesh_with_it(
    noise_glb, small_disk, tmp_path, capsys
):
    spacious = tmp_path / "spacious"
    spacious.mkdir()
    argv = ["downsample", str(noise_glb), "--scale", "2", *JOB]
    assert run([*argv, "-o", str(spacious / "small.glb")]) == 0
    disk = small_disk(pages((spacious / "small.glb").stat().st_size))  # the mesh, no more
    out, report = disk / "small.glb", disk / "small.json"
    capsys.readouterr()
    assert run([*argv, "-o", str(out), "--report", str(report)]) == 2
    captured = capsys.readouterr()
    assert error_lines(captured.err) == [f"geoscaler: error: {report}: {FULL}"]
    assert "wrote" not in captured.out
    assert list(disk.iterdir()) == []


# ----------------------------------------------------------------------------- batch


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> Path:
    """Two small assets around a big one: a.glb, b_big.glb, c.glb."""
    root = tmp_path_factory.mktemp("library")
    save_mesh(demo_mesh(subdivisions=3, texture_size=64), root / "a.glb")
    save_mesh(noise_mesh(1024, seed=1), root / "b_big.glb")  # x4: a 256 x 256 noise PNG
    save_mesh(demo_mesh(subdivisions=3, texture_size=64), root / "c.glb")
    return root


def test_a_batch_whose_disk_fills_fails_that_asset_and_goes_on(library, small_disk, capsys):
    out = small_disk(24 * PAGE)  # the small assets and the summary fit, the big one does not
    status = run(["batch", str(library), "-o", str(out), "--scale", "4", *JOB])
    err = capsys.readouterr().err
    assert status == 1
    failed = f"{library / 'b_big.glb'}: {out / 'b_big.glb'}: {FULL}"  # the asset, the file
    assert error_lines(err) == [f"geoscaler: failed: {failed}"]
    summary = json.loads((out / "summary.json").read_text())
    rows = {row["asset"]: row for row in summary["assets"]}
    assert {name: row["status"] for name, row in rows.items()} == {
        "a.glb": "done",
        "b_big.glb": "failed",
        "c.glb": "done",
    }
    assert rows["b_big.glb"]["error"] == failed
    assert f"- b_big.glb: {failed}" in (out / "summary.md").read_text()
    assert sorted(p.name for p in out.iterdir()) == [
        "a.glb", "a.report.json", "c.glb", "c.report.json",
        "summary.csv", "summary.json", "summary.md",
    ]  # fmt: skip


def test_a_batch_that_cannot_write_its_summary_says_so_and_leaves_no_summary(
    library, small_disk, capsys
):
    disk = small_disk(PAGE)
    (disk / "full").write_bytes(bytes(PAGE))  # not a byte more fits
    out = disk / "out"
    status = run(["batch", str(library), "-o", str(out), "--scale", "4", *JOB])
    err = capsys.readouterr().err
    assert status == 2
    lines = error_lines(err)
    assert lines[:-1] == [
        f"geoscaler: failed: {library / name}: {out / name}: {FULL}"
        for name in ("a.glb", "b_big.glb", "c.glb")
    ]
    assert lines[-1] == f"geoscaler: error: {out / 'summary.csv'}: {FULL}"
    assert "Traceback" not in err
    assert list(out.iterdir()) == []


def test_an_asset_whose_report_cannot_be_moved_into_place_is_removed_whole(
    library, tmp_path, monkeypatch
):
    """Another failure than a full disk, at the last step (the report renamed into place,
    after the mesh): the asset fails with the file named at its place, nothing of it stays."""
    import errno

    import geoscaler.batch.worker as worker
    from geoscaler.batch import FAILED, Asset, AssetTask, run_asset
    from geoscaler.cli import build_parser, job_settings

    args = build_parser().parse_args(["batch", "x", "-o", "y", "--scale", "4", *JOB])
    args.optimize = None  # as main() sets it
    asset = Asset("a.glb", library / "a.glb", tmp_path / "a.glb")
    real_replace = os.replace

    def failing(source, target):
        if Path(target) == asset.report:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        real_replace(source, target)

    monkeypatch.setattr(worker.os, "replace", failing)
    result = run_asset(AssetTask(asset, job_settings(args), {}, ONE_VIEW))
    assert result.status == FAILED
    assert result.error == (
        f"{asset.path}: {asset.report}: writing it failed (Input/output error); check the "
        "device or choose another output folder"
    )
    assert list(tmp_path.iterdir()) == []
