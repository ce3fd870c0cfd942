"""geoscaler bench: finding meshes, skipping bad ones, tables, and the files it writes."""

from __future__ import annotations

import csv
import json
import math
import shlex

import pytest
from conftest import ONE_VIEW
from PIL import Image

from geoscaler.cli import build_parser, main
from geoscaler.errors import GeoscalerError
from geoscaler.io import save_mesh
from geoscaler.procedural import demo_mesh
from geoscaler.report.bench import (
    CSV_COLUMNS,
    METRIC_TITLES,
    command_line,
    find_meshes,
    paper_table,
    summarize,
)


@pytest.fixture(scope="module")
def good_glb(tmp_path_factory):
    path = tmp_path_factory.mktemp("good") / "good.glb"
    save_mesh(demo_mesh(subdivisions=8, texture_size=128), path)
    return path


@pytest.fixture
def data_dir(tmp_path, good_glb):
    """A folder with one good mesh and one corrupt one."""
    folder = tmp_path / "data"
    folder.mkdir()
    (folder / "good.glb").write_bytes(good_glb.read_bytes())
    (folder / "broken.glb").write_bytes(b"glTF this is not a real binary glTF file")
    return folder


def test_find_meshes_prefers_meta_entry(tmp_path):
    asset = tmp_path / "asset"
    (asset / "lods").mkdir(parents=True)
    for name in ("main.obj", "other.obj", "lods/low.glb"):
        (asset / name).write_text("")
    (asset / "meta.json").write_text(json.dumps({"entry": "main.obj"}))
    loose = tmp_path / "loose"
    (loose / "deep").mkdir(parents=True)
    (loose / "a.GLB").write_text("")
    (loose / "deep" / "b.gltf").write_text("")
    (loose / "notes.txt").write_text("")
    (loose / "meta.json").write_text("{not json")  # unreadable: the folder is searched instead
    found = find_meshes([tmp_path])
    assert [(m.name, m.path.relative_to(tmp_path).as_posix()) for m in found] == [
        ("asset", "asset/main.obj"),
        ("loose/a.GLB", "loose/a.GLB"),
        ("loose/deep/b.gltf", "loose/deep/b.gltf"),
    ]
    assert len(find_meshes([tmp_path / "asset", tmp_path / "asset" / "main.obj"])) == 1


def test_find_meshes_errors(tmp_path):
    with pytest.raises(GeoscalerError, match="no mesh files"):
        find_meshes([tmp_path])
    with pytest.raises(GeoscalerError, match="no such file or folder"):
        find_meshes([tmp_path / "missing"])


def test_bench_skips_a_corrupt_mesh_and_writes_results(data_dir, tmp_path, capsys):
    out = tmp_path / "results"
    argv = ["bench", str(data_dir), "--scale", "4", "8", "--methods", "box,bicubic"]
    assert main([*argv, "--out", str(out), "--device", "cpu"], evaluation=ONE_VIEW) == 0
    captured = capsys.readouterr()
    assert "skipped" in captured.err and "broken.glb" in captured.err
    assert "PSNR-fg (dB)" in captured.out and "good.glb" in captured.out
    written = sorted(p.name for p in out.iterdir())
    assert written == ["results.csv", "results.json", "results.md", "tradeoff.png"]

    with open(out / "results.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    assert list(rows[0]) == CSV_COLUMNS
    assert [(r["mesh"], r["scale"], r["method"]) for r in rows] == [
        ("good.glb", "4", "box"),
        ("good.glb", "4", "bicubic"),
        ("good.glb", "8", "box"),
        ("good.glb", "8", "bicubic"),
    ]
    assert float(rows[1]["gain_db"]) == 0.0 and rows[2]["texture_width"] == "16"

    document = json.loads((out / "results.json").read_text())
    assert document["protocol"] == 1
    assert [m["name"] for m in document["meshes"]] == ["good.glb"]
    assert document["failed"][0]["path"].endswith("broken.glb")
    assert len(document["results"]) == 4 and len(document["summary"]) == 4

    markdown = (out / "results.md").read_text()
    first, *rest = markdown.splitlines()
    assert first.startswith("`geoscaler bench ") and "--methods box,bicubic" in first
    assert "protocol: 1  " in rest and any(line.startswith("device: cpu") for line in rest)
    assert "| scale | metric | box | bicubic |" in markdown
    assert Image.open(out / "tradeoff.png").size == (960, 600)


def test_bench_json_to_stdout(good_glb, capsys):
    argv = ["bench", str(good_glb), "--scale", "4", "--methods", "bicubic", "--json"]
    assert main(argv, evaluation=ONE_VIEW) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["protocol"] == 1 and document["results"][0]["gain_db"] == 0.0


def test_bench_under_protocol_2_says_so_and_the_command_line_keeps_it(good_glb, capsys):
    argv = ["bench", str(good_glb), "--scale", "4", "--methods", "bicubic", "--protocol", "2"]
    assert main([*argv, "--json"], evaluation=ONE_VIEW) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["protocol"] == 2 and "--protocol 2" in document["command"]
    assert document["results"][0]["gain_db"] == 0.0


def test_bench_fails_when_no_mesh_can_be_read(tmp_path, capsys):
    (tmp_path / "broken.obj").write_bytes(b"\x00\x01 not a mesh")
    assert main(["bench", str(tmp_path), "--methods", "box"]) == 2
    err = capsys.readouterr().err
    assert "skipped" in err and "none of the 1 meshes" in err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--methods", "nope"], "'nope': unknown method"),
        (["--scale", "1"], "whole number >= 2"),
    ],
)
def test_bench_bad_arguments_exit_2(good_glb, extra, message, capsys):
    assert main(["bench", str(good_glb), *extra]) == 2
    assert message in capsys.readouterr().err


def test_bench_no_meshes_exits_2(tmp_path, capsys):
    assert main(["bench", str(tmp_path)]) == 2
    assert "no mesh files" in capsys.readouterr().err


def _row(mesh, method, scale, psnr, gain=0.0):
    return {
        "mesh": mesh,
        "method": method,
        "scale": scale,
        "distance": 2.4,
        "texture_bytes": 1024,
        "psnr_fg": psnr,
        "psnr_full": psnr + 10,
        "ssim_full": 0.9,
        "ssim_fg": 0.8,
        "gain_db": gain,
        "seconds": 1.0,
    }


def test_summary_and_paper_table_average_over_meshes():
    rows = [
        _row("a", "box", 4, 30.0, -1),
        _row("b", "box", 4, 32.0, 1),
        _row("a", "pbd", 4, math.inf),
    ]
    summary = summarize(rows)
    assert [(s["method"], s["meshes"], s["psnr_fg"]) for s in summary] == [
        ("box", 2, 31.0),
        ("pbd", 1, math.inf),
    ]
    grid = paper_table(summary, 2.4)
    assert grid[0] == ["scale", "metric", "box", "pbd"]
    assert grid[1] == ["x4", "PSNR-fg (dB)", "31.00", "inf"]
    assert [row[1] for row in grid[1:]] == list(METRIC_TITLES.values())


def test_command_line_reproduces_the_arguments():
    argv = ["bench", "my data", "--scale", "4", "8", "--methods", "box,pbd", "--out", "o"]
    line = command_line(build_parser().parse_args(argv))
    assert line == "geoscaler bench 'my data' --scale 4 8 --methods box,pbd --out o"
    assert shlex.split(line)[1:] == argv


def test_command_line_keeps_the_network_flags():
    argv = ["bench", "d", "--scale", "4", "--methods", "geoscaler", "--variant", "base,full"]
    argv += ["--preset", "cpu"]
    assert shlex.split(command_line(build_parser().parse_args(argv)))[1:] == argv
