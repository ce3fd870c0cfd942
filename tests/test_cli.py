"""The command line: info, render and their errors (exit status 2, no traceback)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from geoscaler.cli import main
from geoscaler.errors import GeoscalerError
from geoscaler.io import check_output, save_mesh, save_png, write_atomically
from geoscaler.procedural import demo_mesh


@pytest.fixture(scope="module")
def small_glb(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "small.glb"
    save_mesh(demo_mesh(subdivisions=6, texture_size=64), path)
    return path


def test_info_json_describes_the_mesh(small_glb, capsys):
    assert main(["info", str(small_glb), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["protocol"] == 1
    assert info["faces"] == 6 * 6 * 6 * 2
    assert info["uv_charts"] == 6
    (material,) = info["materials"]
    assert material["texture_size"] == [64, 64]
    assert material["base_color_factor"] == [1.0, 1.0, 1.0, 1.0]
    assert 0.3 < material["uv_coverage"] < 0.8


def test_info_text_mentions_charts_and_texture(small_glb, capsys):
    assert main(["info", str(small_glb)]) == 0
    out = capsys.readouterr().out
    assert "UV charts  6" in out and "64 x 64 x 3" in out


def test_render_writes_a_protocol_view(small_glb, tmp_path, capsys):
    out = tmp_path / "view.png"
    assert main(["render", str(small_glb), "--view", "3", "-o", str(out), "--device", "cpu"]) == 0
    image = np.asarray(Image.open(out))
    assert image.shape == (512, 512, 3)
    assert (image.sum(-1) > 0).mean() > 0.2  # the mesh covers a good part of the frame
    assert image[0, 0].sum() == 0  # black background in the corner


def test_render_refuses_to_overwrite_without_force(small_glb, tmp_path, capsys):
    out = tmp_path / "view.png"
    out.write_bytes(b"keep me")
    assert main(["render", str(small_glb), "-o", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "MESH", "--view", "60", "-o", "OUT"], "--view 60"),
        (["render", "MESH", "--distance", "0.5", "-o", "OUT"], "--distance 0.5"),
        (["render", "MESH", "-o", "OUT.jpg"], "PNG"),
        (["render", "MESH", "-o", "MESH"], "input file"),
        (["info", "missing.obj"], "missing.obj"),
    ],
)
def test_bad_arguments_give_one_line_errors(small_glb, tmp_path, capsys, args, message):
    args = [
        str(small_glb) if a == "MESH" else str(tmp_path / "out.png") if a == "OUT" else a
        for a in args
    ]
    args = [str(tmp_path / "out.jpg") if a == "OUT.jpg" else a for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("geoscaler: error:") and message in err
    assert "Traceback" not in err


def test_write_atomically_leaves_nothing_behind_on_failure(tmp_path):
    target = tmp_path / "out.png"
    target.write_bytes(b"old")

    def broken(tmp):
        tmp.write_bytes(b"half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_atomically(target, broken)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.png"]


def test_saved_png_has_usual_permissions(tmp_path):
    path = save_png(tmp_path / "a.png", np.zeros((2, 2, 3), dtype=np.uint8))
    assert path.stat().st_mode & 0o044 == 0o044  # readable by group and others


def test_check_output_needs_an_existing_folder(tmp_path):
    with pytest.raises(GeoscalerError, match="does not exist"):
        check_output(tmp_path / "nope" / "a.png", force=False)


def test_control_characters_in_names_are_escaped_in_errors(tmp_path, capsys):
    """A file name cannot drive the terminal: escape sequences are printed escaped."""
    name = tmp_path / "evil\x1b[2J\x07.obj"
    assert main(["info", str(name)]) == 2
    err = capsys.readouterr().err
    assert "\x1b" not in err and "\x07" not in err
    assert "evil\\x1b[2J\\x07.obj" in err and err.count("\n") == 1


def test_the_command_line_stops_numpy_asking_for_huge_pages(tmp_path, capsys):
    advice = pytest.importorskip("numpy._core.multiarray")
    advice._set_madvise_hugepage(True)
    try:
        assert main(["info", str(tmp_path / "missing.glb")]) == 2  # any command
        assert advice._get_madvise_hugepage() is False
    finally:
        advice._set_madvise_hugepage(True)  # numpy's default, for the tests after this one
    assert "missing.glb" in capsys.readouterr().err


LATE_CTRL_C = """
import os, signal, sys
from geoscaler.process import exit_status_kept

def command():
    {body}

status = exit_status_kept(command)
os.kill(os.getpid(), signal.SIGINT)  # a Ctrl-C after the command ended, as the process exits
sys.exit(status)
"""


@pytest.mark.parametrize(
    "body, status",
    [
        ("return 130", 130),  # the command was interrupted and said so
        ("return 0", 0),  # it had finished: the late Ctrl-C interrupts nothing
        ("raise KeyboardInterrupt", 130),  # a Ctrl-C after its own handling
    ],
)
def test_a_late_ctrl_c_does_not_change_the_exit_status(body, status):
    """As the command line (``main()`` without argv), the process exits with the command's
    status, not by SIGINT (-2), when a Ctrl-C comes after the command has ended."""
    import subprocess
    import sys

    code = LATE_CTRL_C.format(body=body)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert (done.returncode, done.stderr) == (status, "")


@pytest.mark.parametrize(
    "argv, uv",
    [
        (["downsample", "m.glb", "-o", "o.glb"], "auto"),
        (["downsample", "m.glb", "-o", "o.glb", "--uv", "keep"], None),
        (["downsample", "m.glb", "-o", "o.glb", "--uv", "repack"], "repack"),
        (["downsample", "m.glb", "-o", "o.glb", "--renderer", "soft"], None),
        (["downsample", "m.glb", "-o", "o.glb", "--method", "geoscaler"], None),
        (["batch", "in", "-o", "out"], "auto"),
    ],
)
def test_jobs_race_the_layouts_unless_told_otherwise(argv, uv):
    """``direct`` through the exact renderer races the layouts by default where assets are made;
    ``--uv keep``, the soft renderer and the network keep the mesh's own (no ``uv`` setting)."""
    from geoscaler.cli import build_parser, job_settings

    args = build_parser().parse_args(argv)
    args.optimize = None  # as main() sets it
    assert job_settings(args)["options"].settings.get("uv") == uv


@pytest.mark.parametrize(
    "argv, uv",
    [
        (["compare", "m.glb", "--methods", "bicubic,direct"], None),
        (["compare", "m.glb", "--methods", "bicubic,direct", "--uv", "auto"], "auto"),
    ],
)
def test_comparisons_measure_the_own_layout_unless_asked(argv, uv):
    from geoscaler.cli import build_parser
    from geoscaler.pipeline.arguments import comparison_settings

    args = build_parser().parse_args(argv)
    args.optimize = None
    assert comparison_settings(args)[3].settings.get("uv") == uv


def test_a_job_in_its_own_layout_imports_no_layout_planning(small_glb, tmp_path):
    """scipy.ndimage (0.2 s of imports) serves the packing's guards, the bake and the demo's
    asset: a job that keeps its layout never imports it, nor the demo's scipy.spatial."""
    probe = (
        "import sys\n"
        "from geoscaler.cli import main\n"
        "status = main(sys.argv[1:])\n"
        "print(status, 'scipy.ndimage' in sys.modules, 'scipy.spatial' in sys.modules)\n"
    )
    out = tmp_path / "out.glb"
    job = [small_glb, "--scale", "4", "--uv", "keep", "--time-budget", "5", "-o", out]
    command = [sys.executable, "-c", probe, "downsample", *map(str, job)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.stdout.splitlines()[-1] == "0 False False", done.stderr
