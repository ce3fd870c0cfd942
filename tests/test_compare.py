"""geoscaler compare: the comparison core, its JSON, its picture and the command line."""

from __future__ import annotations

import contextlib
import json
import math

import numpy as np
import pytest
import torch
from conftest import ONE_VIEW, small_renderer
from mesh_support import pbr_demo
from PIL import Image

from geoscaler.cli import main
from geoscaler.errors import GeoscalerError
from geoscaler.io import save_mesh
from geoscaler.methods import MethodOptions, MethodResult, get_method, registry
from geoscaler.pipeline.job import JobObserver, compare_mesh
from geoscaler.pipeline.rows import ROW_KEYS
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import BYTES_PER_TEXEL, Evaluation
from geoscaler.render.metrics import evaluate, ssim_fg, ssim_full
from geoscaler.render.renderer import Renderer
from geoscaler.report.documents import (
    comparison_json,
    comparison_picture,
    dumps,
    format_table,
    pick_views,
)
from geoscaler.report.figures import colormap
from geoscaler.resize.filters import reference_textures

VIEWS = (0, 31)  # two protocol views keep the tests fast; the CLI always scores all 60


def reference_method(mesh, scale, options, context):
    """A fake method that ships the reference map itself: renders identical to the original."""
    return MethodResult(reference_textures(mesh))


@contextlib.contextmanager
def registered(name, run, learned=False):
    """Register the fake method ``name`` while the block runs."""
    registry.register(name, run, learned=learned)
    try:
        yield
    finally:
        registry.unregister(name)


@pytest.fixture(scope="module")
def mesh():
    return demo_mesh(subdivisions=8, texture_size=128)


@pytest.fixture(scope="module")
def comparison(mesh):
    with registered("reference", reference_method):
        return compare_mesh(
            mesh, [4], ["bicubic", "box", "reference"], renderer=small_renderer(mesh, VIEWS)
        )


def by_method(rows):
    return {row["method"]: row for row in rows}


def test_rows_have_the_documented_keys(comparison):
    assert [row["method"] for row in comparison.rows] == ["bicubic", "box", "reference"]
    box = by_method(comparison.rows)["box"]
    assert set(ROW_KEYS) <= set(box)
    assert box["scale"] == 4 and box["distance"] == 2.4 and box["views"] == len(VIEWS)
    assert box["texture_size"] == [32, 32]
    assert box["texture_bytes"] == 32 * 32 * BYTES_PER_TEXEL
    assert 10 < box["psnr_fg"] < box["psnr_full"] < 60  # background pixels inflate PSNR-full
    assert 0 < box["ssim_fg"] < box["ssim_full"] < 1
    assert box["seconds"] >= 0


def test_gain_is_psnr_fg_over_bicubic(comparison):
    rows = by_method(comparison.rows)
    assert rows["bicubic"]["gain_db"] == 0.0
    assert rows["box"]["gain_db"] == rows["box"]["psnr_fg"] - rows["bicubic"]["psnr_fg"]


def test_reference_texture_scores_perfectly(comparison):
    row = by_method(comparison.rows)["reference"]
    assert row["psnr_fg"] == math.inf and row["psnr_full"] == math.inf
    assert row["ssim_full"] == 1.0 and row["ssim_fg"] == 1.0
    assert row["gain_db"] == math.inf
    assert row["texture_size"] == [128, 128]


def test_json_is_strict_with_protocol_key(comparison):
    document = json.loads(dumps(comparison_json("mesh.glb", comparison)))
    assert document["protocol"] == 1 and document["mesh"] == "mesh.glb"
    reference = by_method(document["results"])["reference"]
    assert reference["psnr_fg"] is None and reference["ssim_fg"] == 1.0  # inf -> null
    assert isinstance(by_method(document["results"])["box"]["psnr_fg"], float)
    assert document["runs"] == []  # filters only: no learned run to describe


def test_table_lists_each_row(comparison):
    text = format_table(comparison.rows)
    assert "distance 2.4 (2 views)" in text
    assert "box" in text and "32x32" in text and "+0.00" in text


def test_bicubic_runs_for_the_gain_but_is_only_shown_if_listed(mesh):
    comparison = compare_mesh(mesh, [4], ["box"], renderer=small_renderer(mesh))
    assert [row["method"] for row in comparison.rows] == ["box"]
    assert ("bicubic", 4) in comparison.outputs
    assert comparison.rows[0]["gain_db"] != 0.0


def test_each_method_runs_once_per_scale_whatever_the_distances(mesh):
    calls = []

    def counting(mesh, rule, options, context):
        calls.append(rule.scale)
        return get_method("box").run(mesh, rule, options, context)

    with registered("counting", counting):
        comparison = compare_mesh(
            mesh, [4, 8], ["counting"], [1.5, 4.0], renderer=small_renderer(mesh, (5,))
        )
    assert calls == [4, 8]
    order = [(row["distance"], row["scale"]) for row in comparison.rows]
    assert order == [(1.5, 4), (1.5, 8), (4.0, 4), (4.0, 8)]
    assert [row["texture_size"] for row in comparison.rows[:2]] == [[32, 32], [16, 16]]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"methods": ["nope"]}, "'nope': unknown method"),
        ({"scales": [1]}, "whole number >= 2"),
        ({"scales": [256]}, "larger than the 128 x 128 texture"),
        ({"distances": [0.5]}, "must be over 1"),
    ],
)
def test_bad_arguments_raise_before_work(mesh, kwargs, message):
    arguments = {"scales": [4], "methods": ["box"], **kwargs}
    arguments["renderer"] = small_renderer(mesh)
    with pytest.raises(GeoscalerError, match=message):
        compare_mesh(mesh, **arguments)


@pytest.mark.parametrize("views", [(60,), (-1,), ()])
def test_an_evaluation_refuses_views_outside_the_protocol(views):
    """The views scored are the renderer's evaluation's: a bad index is refused when the
    settings are made, before any renderer exists."""
    with pytest.raises(ValueError, match="views must be a non-empty subset of 0..59"):
        Evaluation.quick(views)


def test_picture_shows_original_and_each_method(mesh, comparison):
    renderer = small_renderer(mesh)
    picture = comparison_picture(
        mesh, comparison, 4, ["box", "bicubic"], count=2, renderer=renderer
    )
    assert picture.dtype == np.uint8 and picture.shape[2] == 3
    assert picture.shape[1] == 3 * 256 + 2 * 4  # original | box | bicubic
    assert picture.shape[0] > 2 * 3 * 256  # two views of three rows each
    assert len(np.unique(picture.reshape(-1, 3), axis=0)) > 1000  # renders, not blank tiles


def test_pick_views_prefers_large_and_distinct_views():
    counts = np.zeros(60)
    counts[[3, 4, 40]] = [900, 1000, 800]
    counts[50] = 100  # too small to be picked
    picked = pick_views(counts, count=3)
    assert picked[0] == 4 and set(picked) == {3, 4, 40}
    assert pick_views(counts, count=2) == [4, 40]  # 40 is farther from 4 than 3 is


def test_colormap_runs_dark_to_bright():
    ramp = colormap(np.linspace(0, 1, 50)).astype(float)
    luminance = ramp @ [0.2126, 0.7152, 0.0722]
    assert ramp.shape == (50, 3)
    assert np.all(np.diff(luminance) > 0)
    assert tuple(colormap(np.array([-1.0, 2.0]))[0]) == (0, 0, 4)


@pytest.mark.parametrize(
    ("rows", "cols"), [((20, 40), (30, 45)), ((0, 64), (50, 64)), ((3, 9), (0, 7))]
)
def test_scoring_shortcut_on_black_background_is_exact(rows, cols):
    """evaluate() computes SSIM only near non-black pixels (renders of a mesh on black): its
    means must equal the plain full-map SSIM of geoscaler.render.metrics."""
    generator = torch.Generator().manual_seed(0)
    shape = (3, 64, 72, 3)
    reference = torch.rand(shape, generator=generator, dtype=torch.float64)
    image = (reference + 0.1 * torch.randn(shape, generator=generator, dtype=torch.float64)).clamp(
        0, 1
    )
    content = torch.zeros(shape[:3], dtype=torch.bool)
    content[0, slice(*rows), slice(*cols)] = True
    content[2, 30:34, 10:12] = True  # view 1 stays all black
    image, reference = image * content[..., None], reference * content[..., None]
    fg = content & (torch.rand(shape[:3], generator=generator) > 0.3)
    scores = evaluate(image, reference, fg, batch_size=2)
    torch.testing.assert_close(scores["ssim_full"], ssim_full(image, reference), rtol=0, atol=1e-12)
    torch.testing.assert_close(
        scores["ssim_fg"], ssim_fg(image, reference, fg), rtol=0, atol=1e-12, equal_nan=True
    )


# --- the command line -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def glb(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "small.glb"
    save_mesh(demo_mesh(subdivisions=8, texture_size=128), path)
    return path


def test_cli_json_and_out_folder(glb, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["compare", str(glb), "--scale", "4", "--methods", "box,bicubic", "--json"]
    assert main([*argv, "--out", str(out), "--device", "cpu"], evaluation=ONE_VIEW) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["protocol"] == 1 and document["mesh"] == str(glb)
    assert document["device"].startswith("cpu")
    assert [r["method"] for r in document["results"]] == ["box", "bicubic"]
    assert set(ROW_KEYS) <= set(document["results"][0])
    assert sorted(p.name for p in out.iterdir()) == ["small_compare.json", "small_compare_x4.png"]
    assert json.loads((out / "small_compare.json").read_text()) == document
    assert Image.open(out / "small_compare_x4.png").size[0] == 3 * 256 + 2 * 4


def test_cli_scores_a_pbr_asset_lit_and_says_so(tmp_path, capsys):
    path = tmp_path / "pbr.glb"
    save_mesh(pbr_demo(texture_size=64), path)
    argv = ["compare", str(path), "--methods", "bicubic", "--device", "cpu"]
    assert main(argv, evaluation=ONE_VIEW) == 0
    assert "protocol 2" in capsys.readouterr().out
    assert main([*argv, "--protocol", "1", "--json"], evaluation=ONE_VIEW) == 0
    assert json.loads(capsys.readouterr().out)["protocol"] == 1


def test_cli_text_table(glb, capsys):
    argv = ["compare", str(glb), "--methods", "bicubic", "--device", "cpu"]
    assert main(argv, evaluation=ONE_VIEW) == 0
    out = capsys.readouterr().out
    assert "protocol 1" in out and "PSNR-fg" in out and "bicubic" in out and "+0.00" in out


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--methods", "box,nope"], "'nope': unknown method"),
        (["--scale", "1"], "whole number >= 2"),
        (["--distance", "0.5"], "must be over 1"),
        (["--methods", "box,box"], "listed twice"),
        (["--steps", "0"], "--steps 0"),
        (["--time-budget", "inf"], "--time-budget inf"),
        (["--protocol", "3"], "--protocol 3: must be 1"),
    ],
)
def test_cli_bad_arguments_exit_2(glb, extra, message, capsys):
    assert main(["compare", str(glb), *extra]) == 2
    captured = capsys.readouterr()
    assert message in captured.err and "Traceback" not in captured.err


def test_cli_missing_mesh_exits_2(tmp_path, capsys):
    assert main(["compare", str(tmp_path / "missing.glb")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_a_refused_compare_leaves_no_out_folder_behind(tmp_path, capsys):
    """The --out folder is made by the last check before work, once the mesh has loaded."""
    out = tmp_path / "new"
    assert main(["compare", str(tmp_path / "missing.glb"), "--out", str(out)]) == 2
    assert "no such file" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_refuses_existing_outputs_without_force(glb, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "small_compare.json").write_text("keep")
    assert main(["compare", str(glb), "--methods", "box", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (out / "small_compare.json").read_text() == "keep"


def test_learned_methods_validate_on_the_views_compare_scores_on(monkeypatch):
    import geoscaler.methods.learned

    def refuse(*args, **kwargs):
        raise AssertionError("the method made its own validation")

    monkeypatch.setattr(geoscaler.methods.learned, "Validation", refuse)
    mesh = demo_mesh(subdivisions=4, texture_size=64)
    handed = []

    class Watch(JobObserver):
        def views_cached(self, distance, views):
            handed.append((distance, views))

    options = MethodOptions(device="cpu", steps=1, settings={"optimize": {"pool_views": 1}})
    comparison = compare_mesh(
        mesh,
        [4],
        ["bicubic", "direct"],
        options=options,
        renderer=small_renderer(mesh),
        observer=Watch(),
    )
    assert [row["method"] for row in comparison.rows] == ["bicubic", "direct"]
    assert comparison.outputs["direct", 4].loop.steps == 1
    ((distance, q),) = handed  # Q, once: validated on, then scored on
    assert distance == 2.4 and len(q) == len(q.cameras) == 1  # the renderer's one view


def test_a_learned_method_gets_the_validation_uncached_and_the_whole_budget():
    contexts = []

    def learned(mesh, scale, options, context):
        contexts.append((context, context.validation.num_views))
        return get_method("bicubic").run(mesh, scale, options, context)

    mesh = demo_mesh(subdivisions=4, texture_size=64)
    options = MethodOptions(device="cpu", time_budget=30.0)
    renderer = small_renderer(mesh)
    with registered("learned", learned, learned=True):
        compare_mesh(mesh, [4], ["learned", "lanczos"], options=options, renderer=renderer)
    ((context, cached),) = contexts
    assert context.time_budget == 30.0  # compare: the budget counts from the method's start
    assert cached == 0  # its views are cached while it trains
    assert set(context.validation.baselines) == {"lanczos", "bicubic"}


# ----------------------------------------------------------------------------- protocol 2


def test_a_mesh_with_pbr_maps_is_compared_lit_each_filter_resizing_every_map():
    from geoscaler.pipeline.shipping import every_map_by
    from geoscaler.render.cameras import validation_cameras
    from geoscaler.render.lit import lit_scores
    from geoscaler.resize.sizes import SizePlan, SizeRule

    mesh = pbr_demo(texture_size=64)
    evaluation = Evaluation.quick(VIEWS, image_size=64)
    renderer = Renderer(mesh, "cpu", evaluation)
    comparison = compare_mesh(mesh, [4], ["bicubic", "lanczos"], renderer=renderer)
    assert comparison.protocol == 2
    rows = {row["method"]: row for row in comparison.rows}
    rule = SizeRule(scale=4)
    lanczos = every_map_by(mesh, SizePlan(rule, rule, rule), "lanczos")
    assert lanczos.materials[0].maps["normalTexture"].shape == (16, 16, 3)
    cameras = validation_cameras()
    (scores,), _ = lit_scores(mesh, [lanczos], [cameras[i] for i in (0, 31)], "cpu", evaluation)
    mean = float(scores["psnr_fg"].double().mean())  # the row averages in float64
    assert rows["lanczos"]["psnr_fg"] == pytest.approx(mean, abs=1e-9)
    assert rows["lanczos"]["views"] == 2
    assert comparison_json("m.glb", comparison)["protocol"] == 2


def test_the_protocol_can_be_asked_and_a_base_colour_mesh_defaults_to_protocol_1(mesh):
    from geoscaler.render.lit import default_protocol

    assert default_protocol(mesh) == 1 and default_protocol(pbr_demo(texture_size=64)) == 2
    renderer = Renderer(pbr_demo(texture_size=64), "cpu", Evaluation.quick((0,), image_size=32))
    unlit = compare_mesh(renderer.mesh, [4], ["bicubic"], renderer=renderer, protocol=1)
    assert unlit.protocol == 1
    with pytest.raises(GeoscalerError, match="--protocol 3: must be 1"):
        compare_mesh(renderer.mesh, [4], ["bicubic"], renderer=renderer, protocol=3)
