"""Running a prepared downsampling job as a command does: a progress bar, Ctrl-C that keeps
the best result, the report written atomically beside the mesh, nothing left behind on failure.
``geoscaler downsample``, the demo (:func:`demo`) and ``geoscaler batch`` (one asset at a time)
run it."""

from __future__ import annotations

from pathlib import Path

from geoscaler.io import check_output, prepare_folder, save_mesh, save_png, write_atomically
from geoscaler.methods import is_learned
from geoscaler.optim.events import Controller
from geoscaler.pipeline.arguments import method_options
from geoscaler.pipeline.downsampling import Job, prepare, product_evaluation, run_job
from geoscaler.pipeline.job import Downsampled
from geoscaler.protocol import GAIN_REFERENCE, PROTOCOL_EVALUATION, Evaluation
from geoscaler.render.renderer import Renderer
from geoscaler.report.console import DownsampleProgress, stop_on_interrupt
from geoscaler.report.documents import comparison_picture, dumps, format_report, report_document


def downsample_and_report(
    job: Job, evaluation: Evaluation = PROTOCOL_EVALUATION, progress: bool = True, say=print
) -> tuple[Downsampled, dict]:
    """Run a prepared job with a progress bar, write its report, print what was done.

    A first Ctrl-C stops the optimisation and the best result so far is still written; a
    second raises KeyboardInterrupt. Returns ``(Downsampled, report document)``.
    """
    controller = Controller()
    renderer = Renderer(job.mesh, job.options.device, product_evaluation(evaluation))
    bar = DownsampleProgress(progress, is_learned(job.method), job.clock)
    try:
        with stop_on_interrupt(controller, bar.write):
            done, written = run_job(job, renderer, bar, controller)
            bar.close()
            try:
                seconds = job.clock.now() - job.started_at
                document = report_document(job, done, seconds, written)
                if job.report is not None:
                    text = dumps(document) + "\n"
                    write_atomically(job.report, lambda tmp: tmp.write_text(text))
                    written.append(job.report)
            except BaseException:  # a failed run leaves no output behind
                for path in written:
                    Path(path).unlink(missing_ok=True)
                raise
    finally:
        bar.close()
    say(format_report(document))
    for path in written:
        say(f"wrote {path}")
    return done, document


DEMO_MESH_NAME = "geoscaler_pebble.glb"
"""The demo asset's file: named after what it is, so that an older demo asset left in the folder
(the cube-sphere of earlier versions, ``geoscaler_demo.glb``) is not reused for it."""
DEMO_SCALE = 4
DEMO_TIME_BUDGET = 75.0
DEMO_STEPS = 120
"""Budget and step limit of ``direct`` in ``geoscaler demo``, caches included: the step limit
lets the cosine schedule end where the machine is fast enough; the budget bounds the demo's time
where it is not (see docs/decisions/demo-budget.md)."""
DEMO_UV = "repack"
"""``--uv`` of the demo's ``direct``: the pebble's atlas is a scan's, mostly empty, and the demo
shows what repacking it gains. ``auto``'s race would spend most of the demo's budget on its
fixed costs here, the new layout's validation taps and the loser's trial (see
docs/decisions/demo-budget.md)."""


def demo(
    out_dir: str | Path,
    device: str = "auto",
    time_budget: float | None = None,
    steps: int | None = None,
    progress: bool = True,
    say=print,
    evaluation: Evaluation = PROTOCOL_EVALUATION,
    optimize: dict | None = None,
    started_at: float | None = None,
) -> dict:
    """``geoscaler demo``: build (or reuse) the demo asset in ``out_dir`` and downsample it.

    The asset is :func:`geoscaler.procedural.scan_mesh` (a pebble with a scan's atlas), run
    with ``direct`` and ``--uv`` :data:`DEMO_UV`. Writes ``geoscaler_pebble_x4.glb``, its report
    ``geoscaler_pebble_x4.json`` and the picture ``demo_comparison.png`` (original | bicubic |
    direct on three views) into ``out_dir``, replacing earlier demo outputs. ``time_budget``
    of ``direct``: :data:`DEMO_TIME_BUDGET` by default, counted from ``started_at`` (an
    instant on the wall clock; None: now). Returns the report.
    """
    out_dir = prepare_folder(out_dir)
    mesh_path = out_dir / DEMO_MESH_NAME
    if mesh_path.exists():
        say(f"using the demo asset {mesh_path}")
    else:
        from geoscaler.procedural import scan_mesh  # scipy.ndimage and .spatial: the demo's alone

        say(f"building the demo asset into {mesh_path}")
        save_mesh(scan_mesh(), mesh_path)
    stem = f"{mesh_path.stem}_x{DEMO_SCALE}"
    picture = check_output(out_dir / "demo_comparison.png", force=True, inputs=[mesh_path])
    budget = DEMO_TIME_BUDGET if time_budget is None else time_budget
    steps = DEMO_STEPS if steps is None else steps
    settings: dict = {"uv": DEMO_UV}
    if optimize:
        settings["optimize"] = dict(optimize)
    options = method_options(["direct"], device, 0, steps, budget, settings)
    job = prepare(
        mesh_path,
        out_dir / f"{stem}.glb",
        DEMO_SCALE,
        "direct",
        options,
        force=True,
        report=out_dir / f"{stem}.json",
        started_at=started_at,
    )
    done, document = downsample_and_report(job, evaluation, progress=progress, say=say)
    sheet = comparison_picture(
        job.mesh,
        done.comparison,
        DEMO_SCALE,
        [GAIN_REFERENCE, "direct"],
        renderer=Renderer(job.mesh, device, evaluation),
    )
    save_png(picture, sheet)
    say(f"wrote {picture}: original | bicubic | direct on three views, zoom and error heatmap")
    return document
