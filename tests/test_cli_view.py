"""``geoscaler view``: the app's command; the library never needs the app's dependencies."""

from __future__ import annotations

import subprocess
import sys

from geoscaler.cli import build_parser, main


def test_view_takes_an_optional_mesh_and_an_output_folder():
    args = build_parser().parse_args(["view"])
    assert args.mesh is None and args.out == "." and args.scale == 4
    args = build_parser().parse_args(["view", "scan.glb", "--out", "exports", "--scale", "8"])
    assert (args.mesh, args.out, args.scale) == ("scan.glb", "exports", 8)


def test_view_of_a_missing_file_is_a_clear_error(tmp_path, capsys):
    assert main(["view", str(tmp_path / "nothing.glb")]) == 2
    assert "nothing.glb: no such file" in capsys.readouterr().err


def test_the_library_imports_without_the_app_or_a_display():
    code = (
        "import sys; sys.modules['moderngl'] = None; sys.modules['imgui_bundle'] = None\n"
        "import geoscaler.cli, geoscaler.report.console, geoscaler.pipeline.job\n"
        "import geoscaler.render.renderer\n"
        "import geoscaler.report.documents\n"
        "assert geoscaler.cli.main(['view']) == 2\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={"PATH": ""}
    )
    assert result.returncode == 0, result.stderr
    assert "pip install 'geoscaler[app]'" in result.stderr
