"""The printed report says, per texture and in total, what was made and what it costs."""

from __future__ import annotations

from geoscaler.report.documents import format_report

ROW = {
    "method": "direct", "scale": 4, "texture_size": "16x16", "views": 2, "distance": 2.4,
    "psnr_fg": 30.0, "psnr_full": 31.0, "ssim_full": 0.9, "ssim_fg": 0.8, "gain_db": 1.0,
    "seconds": 3.0,
}  # fmt: skip


def document(bytes_after: int, scores: dict) -> dict:
    maps = [
        {
            "slots": ["sofa/baseColorTexture", "fringe/baseColorTexture"],
            "class": "color",
            "method": "direct",
            "size_before": [1024, 1024],
            "size_after": [256, 256],
            "memory_before": 4194304,
            "memory_after": 262144,
            "bytes_before": 500_000,
            "bytes_after": 40_000,
            "format_before": "image/jpeg",
            "format_after": "image/png",
        }
    ]
    return {
        "mesh": "sofa.gltf",
        "output": "small.glb",
        "protocol": 1,
        "device": "cpu",
        "method": "direct",
        "seconds": 12.0,
        "results": [ROW],
        "details": {"validation_views": {"Q": 2, "near": 1, "far": 1}, "validation_scores": scores},
        "maps": maps,
        "totals": {
            "memory_before": 4194304,
            "memory_after": 262144,
            "bytes_before": 600_000,
            "bytes_after": bytes_after,
        },
    }


def test_each_texture_and_the_totals_are_listed():
    text = format_report(document(90_000, {"Q": 30.0, "near": 29.0, "far": 28.0}))
    lines = text.splitlines()
    assert lines[-3:] == [
        "textures:",
        "  sofa/baseColorTexture, fringe/baseColorTexture: color, direct; 1024 x 1024 -> "
        "256 x 256; memory 4.19 MB -> 0.26 MB; file 0.50 MB JPEG -> 40.0 kB PNG",
        "  total: texture memory 4.19 MB -> 0.26 MB (6.2%); on disk 0.60 MB -> 90.0 kB (15.0%)",
    ]


def test_an_output_larger_than_its_input_is_said():
    text = format_report(document(700_000, {"Q": 30.0, "near": 29.0, "far": 28.0}))
    assert "note: the output is larger on disk than the input" in text


def test_a_validation_set_that_saw_nothing_reads_n_a():
    text = format_report(document(90_000, {"Q": 30.0, "near": None, "far": None}))
    assert "PSNR-fg (Q / near / far): direct 30.00 / n/a / n/a" in text


def test_backtracks_are_said_with_the_steps():
    report = document(90_000, {"Q": 30.0, "near": 29.0, "far": 28.0})
    report["details"].update(steps=98, best_step=98, stopped_by="time budget", backtracks=1)
    lines = format_report(report).splitlines()
    at = lines.index(
        "direct: 98 steps (best at step 98), stopped by time budget; 12.0 s for the whole job"
    )
    assert lines[at + 1] == (
        "1 validation(s) ranked the candidate below the best so far: each sent the texels back "
        "to the best and lowered the learning rate"
    )
    report["details"]["backtracks"] = 0
    assert "validation(s) ranked" not in format_report(report)


def test_a_method_the_budget_had_no_time_for_is_said_with_what_shipped():
    report = document(90_000, {})
    report["details"] = {"shipped": "lanczos", "not_run": "the time budget (0.5 s left) ..."}
    lines = format_report(report).splitlines()
    at = lines.index("12.0 s for the whole job")
    assert lines[at + 1] == (
        "direct not run: the time budget (0.5 s left) ...; shipped lanczos, unvalidated; give a "
        "larger --time-budget"
    )


def test_a_run_the_budget_stopped_before_its_first_step_says_it_shipped_its_start():
    report = document(90_000, {"Q": 30.0, "near": 29.0, "far": 28.0})
    report["details"].update(steps=0, best_step=0, stopped_by="time budget", time_budget=15.0)
    text = format_report(report)
    assert "note: the time budget (15.0 s) left no time for a first step" in text
    report["details"]["stopped_by"] = "stopped"  # Ctrl-C before the first step: no such note
    assert "left no time for a first step" not in format_report(report)


def test_the_lit_stage_says_which_start_it_trained_from():
    report = document(90_000, {"Q": 30.0, "near": 29.0, "far": 28.0})
    scores = {"Q": 24.83, "near": 23.6, "far": 25.68}
    lit = {
        "steps": 10, "best_step": 0, "stopped_by": "time budget", "shipped": "start",
        "validation_scores": scores, "validation_views": 8, "start_maps": "lanczos",
        "baseline_scores": {"start": scores, "lanczos": {"Q": 24.62, "near": 23.41, "far": 25.42}},
    }  # fmt: skip
    report["details"]["lit"] = lit
    lines = format_report(report).splitlines()
    assert (
        "lit (protocol 2): normal and data maps trained through lit views, from every other map "
        "by lanczos (it validated above its class's filter), 10 steps (best at step 0), stopped "
        "by time budget; shipped start"
    ) in lines
    assert (
        "  lit PSNR-fg on 8 views a set (Q / near / far): shipped 24.83 / 23.60 / 25.68; start "
        "24.83 / 23.60 / 25.68; lanczos 24.62 / 23.41 / 25.42"
    ) in lines
    lit["start_maps"] = None  # the start's own maps, by their class: nothing more said
    assert "from every other map" not in format_report(report)
    assert "from its class's maps" not in format_report(report)
    lit["other_starts_left_out"] = True  # the time held the stage, not the other starts' scoring
    assert (
        "lit (protocol 2): normal and data maps trained through lit views, from its class's maps "
        "(the time left held no scoring of other starts), 10 steps (best at step 0), stopped by "
        "time budget; shipped start"
    ) in format_report(report).splitlines()
