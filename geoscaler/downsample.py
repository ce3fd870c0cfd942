"""``geoscaler downsample`` and ``geoscaler demo``: the product's main job.

One mesh in, the same mesh with base-colour textures ``scale`` times smaller out, plus a report
of protocol-1 metrics on the validation set Q for the result and for bicubic and Lanczos at the
same scale. Everything that can be checked is checked before any heavy work (arguments, the
mesh, every file that will be written); Q is rasterised once and shared by the method (its
validation) and the report; a first Ctrl-C stops the optimisation cleanly and the best result so
far is still written, a second one aborts.

:func:`prepare` validates and loads, :func:`downsample` runs the method and scores it,
:func:`export` writes the mesh, :func:`report_document` / :func:`format_report` describe the
run; :func:`run_job` chains them for the CLI and :func:`demo`.
"""

from __future__ import annotations

import contextlib
import math
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from geoscaler import PROTOCOL
from geoscaler.baselines import BASELINES, lanczos, target_size
from geoscaler.cameras import VALIDATION_DISTANCE
from geoscaler.compare import (
    GAIN_REFERENCE,
    Comparison,
    comparison_picture,
    describe_device,
    dumps,
    format_table,
    json_safe,
    network_extra,
    protocol_cameras,
    score_outputs,
    texture_facts,
)
from geoscaler.errors import GeoscalerError
from geoscaler.evaluate import ViewSet
from geoscaler.files import check_output, prepare_folder, save_png, write_atomically
from geoscaler.mesh import TexturedMesh, load_mesh, save_mesh
from geoscaler.methods import (
    MethodOptions,
    MethodResult,
    known_method,
    known_methods,
    reference_textures,
    remaining_budget,
    run_method,
)
from geoscaler.metrics import evaluate
from geoscaler.optimize import Controller, ProgressEvent, ViewCache
from geoscaler.render import Renderer, resolve_device
from geoscaler.texture import texture_to_linear

DEFAULT_METHOD = "direct"
DEFAULT_SCALE = 4
DEFAULT_TIME_BUDGET = 60.0
"""Seconds a learned method may spend when ``--time-budget`` is not given, caching of the
validation views included (the issue's target: at most 60 s wall per mesh)."""

OUTPUT_SUFFIXES = (".glb", ".gltf", ".obj")
REPORT_BASELINES = ("bicubic", "lanczos")
"""Methods always scored beside the result, at the same scale (bicubic is the gain's zero)."""

DEMO_MESH_NAME = "geoscaler_demo.glb"
DEMO_SCALE = 4
DEMO_TIME_BUDGET = 75.0
DEMO_STEPS = 120
"""Budget and step limit of ``direct`` in ``geoscaler demo``, caches included. Measured on the
idle 2-core machine (CPU, 2 torch threads): Q 11-12 s, training views and taps 27-35 s, about
0.25 s a step, report and picture 20 s; ``geoscaler demo`` took 95-105 s in all (100-120
steps, +0.55 to +0.61 dB PSNR-fg over bicubic). The step limit lets the cosine schedule end
where the machine is fast enough; the budget bounds the demo's time where it is not. On a
machine shared with other CPU work the demo takes longer and may run few or no steps."""

# Test hooks (the command line leaves them alone): the protocol views that stand for Q (None:
# all 60, the protocol), a renderer factory for Q, and OptimizeConfig overrides of learned
# methods. Fewer views or smaller images only make quick checks; their figures are not
# protocol-1 means.
VALIDATION_VIEWS: Sequence[int] | None = None
RENDERER = Renderer
OPTIMIZE_OVERRIDES: dict[str, Any] = {}


def is_learned(method: str) -> bool:
    """Whether ``method`` optimises (steps, time budget, progress events) or is a baseline."""
    return method not in BASELINES


# ----------------------------------------------------------------------------- checks


def check_method(method: str) -> str:
    """The name of a registered method, else a GeoscalerError listing the known ones."""
    if not known_method(method):
        raise GeoscalerError(
            f"--method {method!r}: unknown method; choose one of: {known_methods()}"
        )
    return method


def check_scale(scale: Any) -> int:
    """A whole scale factor >= 2 (the texture-size check comes once the mesh is loaded)."""
    if isinstance(scale, bool) or not isinstance(scale, int | np.integer) or scale < 2:
        raise GeoscalerError(
            f"--scale {scale}: a scale must be a whole number >= 2, e.g. 4 (2048 -> 512) or 8"
        )
    return int(scale)


def check_options(
    method: str,
    device: str = "auto",
    seed: int = 0,
    steps: int | None = None,
    time_budget: float | None = None,
    extra: dict[str, Any] | None = None,
) -> MethodOptions:
    """:class:`MethodOptions` for ``method``, checked; learned methods get the default budget.

    ``extra``: method settings such as the network's variant, preset and VGG-19 weights.
    """
    if steps is not None and steps < 1:
        raise GeoscalerError(f"--steps {steps}: must be at least 1")
    if time_budget is not None and not (math.isfinite(time_budget) and time_budget > 0):
        raise GeoscalerError(f"--time-budget {time_budget}: must be a positive number of seconds")
    resolve_device(device)  # no CUDA -> a clear error now, not after loading
    if time_budget is None and is_learned(method):
        time_budget = DEFAULT_TIME_BUDGET
    return MethodOptions(
        device=device, seed=seed, steps=steps, time_budget=time_budget, extra=dict(extra or {})
    )


def check_output_name(output: str | Path, mesh_path: Path, force: bool) -> Path:
    """OUT's suffix, folder and existence, before the mesh is even read."""
    output = Path(output)
    if output.suffix.lower() not in OUTPUT_SUFFIXES:
        raise GeoscalerError(
            f"-o {output}: the output format comes from the suffix; use one of "
            f"{', '.join(OUTPUT_SUFFIXES)}"
        )
    return check_output(output, force=force, inputs=[mesh_path])


def planned_files(mesh: TexturedMesh, output: Path, force: bool) -> list[Path]:
    """Every file :func:`save_mesh` will write for ``mesh`` at ``output``, checked now.

    OBJ and glTF outputs come with side files (MTL, .bin, PNG maps); each must be writable, not
    an input of the mesh, and new unless ``force``. Raises GeoscalerError otherwise.
    """
    from geoscaler.mesh import _check_suffix, _check_targets, _plan_images

    suffix = _check_suffix(output)
    used = [m for m in range(len(mesh.materials)) if (mesh.face_material == m).any()]
    with warnings.catch_warnings():  # save_mesh warns about maps OBJ cannot hold; once is enough
        warnings.simplefilter("ignore")
        images, _ = _plan_images(mesh, used, output.stem, suffix)
    names = [] if suffix == ".glb" else [image.name for image in images]
    names += [output.stem + ".mtl"] if suffix == ".obj" else []
    names += [output.stem + ".bin"] if suffix == ".gltf" else []
    targets = [output.parent / name for name in [*names, output.name]]
    _check_targets(mesh, targets, force)
    return targets


def check_scale_fits(mesh: TexturedMesh, scale: int) -> list[tuple[int, int] | None]:
    """Output size ``(h, w)`` of each material's texture (None: untextured), or an error.

    Sizes follow the protocol's reference maps (originals above 2048 texels reduced first).
    """
    sizes: list[tuple[int, int] | None] = []
    for material, reference in zip(mesh.materials, reference_textures(mesh), strict=True):
        if reference is None:
            sizes.append(None)
            continue
        try:
            sizes.append(target_size(*reference.shape[:2], scale))
        except GeoscalerError as error:
            raise GeoscalerError(f"--scale {scale}: material {material.name!r}: {error}") from None
    if all(size is None for size in sizes):
        raise GeoscalerError("the mesh has no base-colour texture; there is nothing to downsample")
    return sizes


def _check_distinct(report: Path, others: Sequence[Path], what: str) -> None:
    for other in others:
        if report.resolve() == Path(other).resolve():
            raise GeoscalerError(f"--report {report}: is {what}; choose another name")


@dataclass
class Job:
    """A checked downsampling job, its mesh loaded.

    Attributes:
        mesh_path: the input file (never written).
        mesh: the loaded mesh.
        output: the mesh file to write; ``output_files`` are all the files that go with it.
        scale, method, options: what to run.
        force: replace existing outputs.
        report: the JSON report to write, or None.
        sizes: per material the output texture size ``(h, w)`` (None: untextured).
    """

    mesh_path: Path
    mesh: TexturedMesh
    output: Path
    scale: int
    method: str
    options: MethodOptions
    force: bool = False
    report: Path | None = None
    output_files: list[Path] = field(default_factory=list)
    sizes: list[tuple[int, int] | None] = field(default_factory=list)


def prepare(
    mesh_path: str | Path,
    output: str | Path,
    scale: Any = DEFAULT_SCALE,
    method: str = DEFAULT_METHOD,
    options: MethodOptions | None = None,
    force: bool = False,
    report: str | Path | None = None,
) -> Job:
    """Check everything that can be checked, load the mesh, and return the :class:`Job`.

    Raises:
        GeoscalerError: a bad scale or method, options, output name, folder or suffix; an
            output that is an input file (even with ``force``) or exists without ``force``; an
            unreadable mesh; a scale larger than a texture.
    """
    mesh_path = Path(mesh_path)
    scale = check_scale(scale)
    method = check_method(method)
    options = options or check_options(method)
    output = check_output_name(output, mesh_path, force)
    report_path = None
    if report is not None:
        report_path = check_output(report, force=force, inputs=[mesh_path])
        _check_distinct(report_path, [output], "the output mesh")
    mesh = load_mesh(mesh_path)
    sizes = check_scale_fits(mesh, scale)
    files = planned_files(mesh, output, force)
    if report_path is not None:
        check_output(report_path, force=force, inputs=mesh.source_files)
        _check_distinct(report_path, files, "a file of the output mesh")
    return Job(mesh_path, mesh, output, scale, method, options, force, report_path, files, sizes)


# ----------------------------------------------------------------------------- progress


class Progress:
    """One tqdm bar for the whole job: view caching, then optimisation steps.

    Caching counts the views of Q, then the method's training views. Steps show the loss, the
    best validation PSNR-fg and the time left: the step rate's estimate, or the time budget's
    end when that comes first.
    """

    FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"

    def __init__(self, enabled: bool = True, views: int = 0):
        from tqdm import tqdm

        self.bar = tqdm(
            total=views,
            desc="caching views",
            unit="view",
            bar_format=self.FORMAT,
            disable=not enabled,
            leave=False,
            dynamic_ncols=True,
        )
        self.views = views
        self.deadline: float | None = None
        self.phase = "caching"
        self.first_step: tuple[float, int] | None = None

    def write(self, text: str) -> None:
        """Print a line to stderr without breaking the bar."""
        self.bar.write(text, file=sys.stderr)

    def caching_q(self, done: int, total: int) -> None:
        """Progress callback of the Q view set."""
        self.bar.n = done
        self.bar.refresh()

    def method_started(self, time_budget: float | None) -> None:
        """The method starts now; a budget, if any, ends it ``time_budget`` seconds later."""
        self.deadline = None if time_budget is None else time.perf_counter() + time_budget
        self.bar.set_postfix_str("method set-up", refresh=True)

    def on_event(self, event: ProgressEvent) -> None:
        """Receives the method's :class:`ProgressEvent` reports."""
        bar = self.bar
        if event.phase == "caching":
            bar.total = self.views + event.total
            bar.n = self.views + event.done
            if event.done == event.total:
                bar.set_postfix_str("texture taps and first validation", refresh=False)
            bar.refresh()
            return
        if self.phase == "caching":
            self.phase = "steps"
            bar.set_description_str("optimising", refresh=False)
            bar.set_postfix_str("", refresh=False)
            bar.unit = "step"
            bar.reset(total=event.total_steps)
            self.first_step = (time.perf_counter(), event.step)
        bar.n = event.step
        postfix = []
        if math.isfinite(event.loss):
            postfix.append(f"loss {event.loss:.3g}")
        if math.isfinite(event.best_psnr):
            postfix.append(f"best PSNR-fg {event.best_psnr:.2f} dB")
        left = self.time_left(event)
        if left is not None:
            postfix.append(f"left {_clock(left)}")
        bar.set_postfix_str(", ".join(postfix), refresh=False)
        bar.refresh()

    def time_left(self, event: ProgressEvent) -> float | None:
        """Seconds to the step limit at the current rate, or to the budget's end if sooner."""
        estimates = []
        if self.first_step is not None and event.step > self.first_step[1]:
            began, first = self.first_step
            rate = (time.perf_counter() - began) / (event.step - first)
            estimates.append(rate * (event.total_steps - event.step))
        if self.deadline is not None:
            estimates.append(max(self.deadline - time.perf_counter(), 0.0))
        return min(estimates) if estimates else None

    def close(self) -> None:
        self.bar.close()


def _clock(seconds: float) -> str:
    minutes, seconds = divmod(int(round(seconds)), 60)
    return f"{minutes}:{seconds:02d}"


@contextlib.contextmanager
def stop_on_interrupt(controller: Controller, say) -> Iterator[None]:
    """While active, a first SIGINT asks ``controller`` to stop; a second one aborts.

    Only the main thread can take signals; elsewhere (e.g. a GUI worker) this does nothing and
    the caller stops the controller itself.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    presses = 0

    def handler(signum, frame):
        nonlocal presses
        presses += 1
        if presses > 1:
            raise KeyboardInterrupt
        controller.stop()
        say(
            "stopping: the best result so far will be written once the current phase ends "
            "(view caching cannot be cut short); Ctrl-C again to abort"
        )

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# ----------------------------------------------------------------------------- the job


@dataclass
class Downsampled:
    """What :func:`downsample` produced and measured.

    Attributes:
        result: the method's textures (8-bit, as they ship; alpha re-attached) and UVs, its
            seconds (including the caching of Q for learned methods) and details.
        rows: protocol rows (see :data:`geoscaler.compare.ROW_KEYS`): the method first, then
            bicubic and Lanczos, each with its ``gain_db`` over bicubic.
        comparison: the same as a :class:`~geoscaler.compare.Comparison` (for pictures).
        views: the view set Q, kept for pictures.
        details: the method's details plus how Q was used.
    """

    result: MethodResult
    rows: list[dict[str, Any]]
    comparison: Comparison
    views: ViewSet
    details: dict[str, Any]


def downsample(
    mesh: TexturedMesh,
    scale: int,
    method: str = DEFAULT_METHOD,
    options: MethodOptions | None = None,
    progress: Progress | None = None,
    controller: Controller | None = None,
    views: Sequence[int] | None = None,
    q: ViewSet | None = None,
) -> Downsampled:
    """Run ``method`` on ``mesh`` at ``scale`` and score it, bicubic and Lanczos on Q.

    Q is rasterised once: the method validates on it (``extra["validation_views"]``) and the
    report scores on it. For learned methods the time budget covers the caching of Q too.

    Args:
        mesh, scale, method: the job (checked by :func:`prepare`).
        options: the method's settings (device, seed, steps, time budget).
        progress: the bar to drive (None: silent).
        controller: stops the method early (the best state so far is returned).
        views: protocol view indices standing for Q (None: all 60, the protocol).
        q: Q already rasterised for ``views`` (e.g. by the app, which scores bicubic on it
            before the method starts); its caching is then not counted in the method's time.
    """
    options = options or check_options(method)
    controller = controller or Controller()
    start = time.perf_counter()
    cameras = protocol_cameras(VALIDATION_DISTANCE, views)
    if q is None:
        report = progress.caching_q if progress else None
        q = ViewSet(RENDERER(mesh, options.device), cameras, report)
    renderer = q.renderer
    q_seconds = time.perf_counter() - start

    learned = is_learned(method)
    budget = options.time_budget
    if learned:
        budget = remaining_budget(budget, q_seconds)  # the budget covers the caching of Q
    extra = {**options.extra, "validation_views": q, "controller": controller}
    if learned and OPTIMIZE_OVERRIDES:
        extra["optimize"] = {**OPTIMIZE_OVERRIDES, **extra.get("optimize", {})}
    method_options = MethodOptions(
        device=options.device,
        seed=options.seed,
        steps=options.steps,
        time_budget=budget,
        on_event=progress.on_event if progress else options.on_event,
        extra=extra,
    )
    if progress:
        progress.method_started(budget if learned else None)
    result = run_method(method, mesh, scale, method_options)
    if learned:
        result.seconds += q_seconds
    result.textures = ship_textures(mesh, result.textures, scale)

    outputs = {(method, scale): result}
    for name in REPORT_BASELINES:
        if name != method:
            outputs[name, scale] = run_method(name, mesh, scale)
    if progress:
        progress.bar.set_description_str("scoring on Q", refresh=False)
        progress.bar.set_postfix_str("", refresh=False)
        progress.bar.unit = "method"
        progress.bar.reset(total=len(outputs))
    scorer = CachedScorer(q, result.textures)
    scored = {}
    for key, output in outputs.items():
        scored.update(score_outputs(scorer, {key: output}, VALIDATION_DISTANCE))
        if progress:
            progress.bar.update()
    del scorer
    bicubic_psnr = scored[GAIN_REFERENCE, scale]["psnr_fg"]
    for (name, _), row in scored.items():
        row["gain_db"] = 0.0 if name == GAIN_REFERENCE else row["psnr_fg"] - bicubic_psnr
    rows = list(scored.values())

    comparison = Comparison(rows, outputs, device=str(renderer.device))
    comparison.foreground[VALIDATION_DISTANCE] = q.foreground.sum(dim=(1, 2)).cpu().numpy()
    comparison.view_indices = list(range(len(cameras)) if views is None else views)
    details = {
        **result.details,
        "validation_views": len(q),
        "validation_cache_seconds": round(q_seconds, 3),
    }
    if learned:
        details["time_budget"] = options.time_budget
        details["steps_limit"] = options.steps
    return Downsampled(result, rows, comparison, q, details)


class CachedScorer:
    """Scores 8-bit candidates on a :class:`ViewSet` like :meth:`ViewSet.score`, cheaper.

    Candidates of one scale share their texture sizes, so each view's texture taps for those
    sizes are computed once (:class:`~geoscaler.optimize.ViewCache`) and every candidate is
    then one gather per view instead of a full shading pass: the same renders up to float
    rounding (about 1e-7), about 3x cheaper for the three candidates of a report on the CPU.
    Candidates with other sizes or their own UVs go through :meth:`ViewSet.score`.
    """

    def __init__(self, views: ViewSet, like: Sequence[np.ndarray | None]):
        self.views = views
        self.sizes = [None if t is None else tuple(t.shape[:2]) for t in like]
        self.cache = ViewCache(views, self.sizes, with_taps=True)

    def __len__(self) -> int:
        return len(self.views)

    def score(
        self, textures: Sequence[np.ndarray | None], uvs: np.ndarray | None = None
    ) -> dict[str, torch.Tensor]:
        """Per-view protocol metrics, as :meth:`ViewSet.score`."""
        sizes = [None if t is None else tuple(t.shape[:2]) for t in textures]
        if uvs is not None or sizes != self.sizes:
            return self.views.score(textures, uvs)
        device = self.views.renderer.device
        linear = [None if t is None else texture_to_linear(t, device) for t in textures]
        with torch.no_grad():
            images = torch.stack(
                [self.cache.render(i, linear, None) for i in range(len(self.views))]
            )
            return evaluate(images, self.views.references, self.views.foreground)


def ship_textures(
    mesh: TexturedMesh, textures: Sequence[np.ndarray | None], scale: int
) -> list[np.ndarray | None]:
    """The method's textures as they will be written: where the reference has alpha and the
    method returned RGB only (learned methods optimise colour), the reference's alpha is
    downsampled with Lanczos and appended, so cut-outs survive."""
    shipped: list[np.ndarray | None] = []
    for texture, reference in zip(textures, reference_textures(mesh), strict=True):
        if texture is None or reference is None:
            shipped.append(texture)
            continue
        if texture.shape[2] == 3 and reference.shape[2] in (2, 4):
            alpha = lanczos(np.ascontiguousarray(reference[..., -1:]), scale)
            texture = np.concatenate([texture, alpha.reshape(*texture.shape[:2], 1)], axis=2)
        shipped.append(texture)
    return shipped


def export(
    mesh: TexturedMesh, result: MethodResult, output: Path, force: bool = False
) -> list[Path]:
    """Write ``mesh`` with the result's textures (and UVs) in the format ``output`` names.

    Other maps, factors and material properties are carried over untouched.
    """
    out_mesh, uvs = mesh, result.uvs
    for index, texture in enumerate(result.textures):
        if texture is not None:
            out_mesh = out_mesh.with_texture(index, texture, uvs=uvs)
            uvs = None  # the UVs are the mesh's, set once
    return save_mesh(out_mesh, output, overwrite=force)


def report_document(job: Job, done: Downsampled, seconds: float) -> dict[str, Any]:
    """The JSON report: protocol, files, settings, result rows and the method's details."""
    size, _ = texture_facts(done.result.textures)
    return json_safe(
        {
            "protocol": PROTOCOL,
            "mesh": str(job.mesh_path),
            "output": str(job.output),
            "method": job.method,
            "scale": job.scale,
            "texture_size": size,
            "device": describe_device(done.comparison.device),
            "seconds": round(seconds, 3),
            "results": done.rows,
            "details": done.details,
        }
    )


def format_report(document: dict[str, Any]) -> str:
    """The printed report: a header, the protocol table and one line on how the method ran."""
    lines = [
        f"mesh {document['mesh']} -> {document['output']}   protocol {document['protocol']}   "
        f"device {document['device']}",
        format_table(document["results"]),
    ]
    details = document["details"]
    if "steps" in details:
        lines.append(
            f"{document['method']}: {details['steps']} steps (best at step "
            f"{details.get('best_step')}), stopped by {details.get('stopped_by')}; "
            f"{document['seconds']:.1f} s for the whole job"
        )
        if details["steps"] == 0 and details.get("stopped_by") == "time budget":
            lines.append(
                f"note: the time budget ({details.get('time_budget')} s) ran out while the "
                "views were being cached, so no optimisation step ran and the result is the "
                "method's Lanczos start; give a larger --time-budget"
            )
    else:
        lines.append(f"{document['seconds']:.1f} s for the whole job")
    return "\n".join(lines)


def run_job(job: Job, progress: bool = True, say=print) -> tuple[Downsampled, dict[str, Any]]:
    """Run a prepared job end to end: downsample, score, write OUT (and the report), print.

    A first Ctrl-C stops the optimisation and the best result so far is still written; a
    second raises KeyboardInterrupt.
    """
    start = time.perf_counter()
    controller = Controller()
    bar = Progress(
        enabled=progress, views=len(protocol_cameras(VALIDATION_DISTANCE, VALIDATION_VIEWS))
    )
    try:
        with stop_on_interrupt(controller, bar.write):
            done = downsample(
                job.mesh,
                job.scale,
                job.method,
                job.options,
                progress=bar,
                controller=controller,
                views=VALIDATION_VIEWS,
            )
            bar.close()
            written = export(job.mesh, done.result, job.output, job.force)
            document = report_document(job, done, time.perf_counter() - start)
            if job.report is not None:
                text = dumps(document) + "\n"
                write_atomically(job.report, lambda tmp: tmp.write_text(text))
                written.append(job.report)
    finally:
        bar.close()
    say(format_report(document))
    for path in written:
        say(f"wrote {path}")
    return done, document


def command(args: Any) -> None:
    """``geoscaler downsample``: check, run, write, report."""
    extra = network_extra(args)
    if args.variant is not None:
        from geoscaler.nn.network import check_variant

        if args.method != "geoscaler":
            raise GeoscalerError("--variant: only --method geoscaler has variants")
        extra["variant"] = check_variant(args.variant)
    options = check_options(
        args.method, args.device, args.seed, args.steps, args.time_budget, extra
    )
    job = prepare(args.mesh, args.output, args.scale, args.method, options, args.force, args.report)
    run_job(job)


# ----------------------------------------------------------------------------- demo


def demo(
    out_dir: str | Path,
    device: str = "auto",
    time_budget: float | None = None,
    steps: int | None = None,
    progress: bool = True,
    say=print,
) -> dict[str, Any]:
    """``geoscaler demo``: build (or reuse) the demo asset in ``out_dir`` and downsample it.

    Writes ``geoscaler_demo_x4.glb``, its report ``geoscaler_demo_x4.json`` and the picture
    ``demo_comparison.png`` (original | bicubic | direct on three views) into ``out_dir``,
    replacing earlier demo outputs. ``time_budget`` of ``direct``: :data:`DEMO_TIME_BUDGET`
    by default. Returns the report.
    """
    from geoscaler.procedural import demo_mesh

    out_dir = prepare_folder(out_dir)
    mesh_path = out_dir / DEMO_MESH_NAME
    if mesh_path.exists():
        say(f"using the demo asset {mesh_path}")
    else:
        say(f"building the demo asset into {mesh_path}")
        save_mesh(demo_mesh(), mesh_path)
    stem = f"{mesh_path.stem}_x{DEMO_SCALE}"
    picture = check_output(out_dir / "demo_comparison.png", force=True, inputs=[mesh_path])
    budget = DEMO_TIME_BUDGET if time_budget is None else time_budget
    steps = DEMO_STEPS if steps is None else steps
    options = check_options(DEFAULT_METHOD, device, 0, steps, budget)
    job = prepare(
        mesh_path,
        out_dir / f"{stem}.glb",
        DEMO_SCALE,
        DEFAULT_METHOD,
        options,
        force=True,
        report=out_dir / f"{stem}.json",
    )
    done, document = run_job(job, progress=progress, say=say)
    sheet = comparison_picture(
        job.mesh,
        done.comparison,
        DEMO_SCALE,
        [GAIN_REFERENCE, DEFAULT_METHOD],
        renderer=done.views.renderer,
    )
    save_png(picture, sheet)
    say(f"wrote {picture}: original | bicubic | direct on three views, zoom and error heatmap")
    return document
