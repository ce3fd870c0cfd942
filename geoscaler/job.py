"""One job pipeline: what ``downsample``, ``compare``, ``bench``, ``demo`` and the app all run.

``load -> plan outputs -> cache Q once -> run each method under its budget -> score -> gains
-> export -> report``:

- :func:`compare_mesh` is the core: it caches the validation set Q once (with the texture taps
  of the output sizes), runs the filters and then the learned methods (which validate on that
  same cache, under the budget left once Q is cached), scores every output on each view set
  as it will ship (8-bit, alpha re-attached), and sets each row's gain over bicubic.
- :func:`prepare` checks a downsampling job and loads its mesh, :func:`run_job` runs it
  through :func:`compare_mesh` (the method beside bicubic and Lanczos on Q), :func:`export`
  writes the mesh, :func:`write_report` the JSON report.

A :class:`JobObserver` watches a job (the CLI's progress bars, the app's live state).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from geoscaler.arguments import check_distances, check_method, check_scale, check_scales
from geoscaler.cameras import spread_order, view_set_cameras
from geoscaler.errors import GeoscalerError
from geoscaler.filters import lanczos, output_sizes, reference_texture
from geoscaler.io import (
    check_output,
    check_outputs,
    load_mesh,
    output_files,
    prepare_folder,
    save_mesh,
)
from geoscaler.mesh import TexturedMesh, check_geometry
from geoscaler.methods import MethodOptions, MethodResult, RunContext, is_learned, run_method
from geoscaler.optimize import Controller, ProgressEvent
from geoscaler.protocol import GAIN_REFERENCE, VALIDATION_DISTANCE
from geoscaler.render import Renderer
from geoscaler.rows import protocol_row, validation_row
from geoscaler.validation import Validation, validation_view_sets
from geoscaler.views import ViewCache, ViewSet

OUTPUT_SUFFIXES = (".glb", ".gltf", ".obj")
EXPORT_RESERVE = 2.0
"""Seconds a downsampling job keeps for writing its files and report after scoring (on the
2-core machine a 2048 x 2048 scan texture encodes to PNG in 0.4 s, a 4096 x 4096 one in 1.3 s)."""
REPORT_BASELINES = ("bicubic", "lanczos")
"""Methods a downsampling job always scores beside its result (bicubic is the gain's zero)."""


class JobObserver:
    """Watches a job; each hook does nothing unless a subclass says otherwise."""

    def stage(self, what: str, done: int, total: int) -> None:
        """Coarse progress: ``what`` is running, ``done`` of ``total`` units of it are done."""

    def views_cached(self, distance: float, views: ViewSet) -> None:
        """The view set at ``distance``: Q as the job starts (its views are cached while the
        methods run), the protocol's other sets once cached."""

    def method_started(self, name: str, scale: int, time_budget: float | None) -> None:
        """Method ``name`` starts at ``scale``; a learned one has ``time_budget`` seconds."""

    def on_event(self, event: ProgressEvent) -> None:
        """A learned method's optimisation loop reports."""

    def scored(self, row: dict[str, Any]) -> None:
        """A row was scored (without its gain, which comes once bicubic is scored too)."""


@dataclass
class Comparison:
    """What :func:`compare_mesh` measured.

    Attributes:
        rows: one dict per (distance, scale, listed method), keys :data:`ROW_KEYS`.
        outputs: ``(method, scale)`` -> the method's result as it ships (bicubic included).
        foreground: distance -> ``(N,)`` int64 foreground pixels of each view's reference.
        view_indices: the protocol view indices scored (0..59), the same at every distance.
        device: the torch device the views were rendered on.
    """

    rows: list[dict[str, Any]]
    outputs: dict[tuple[str, int], MethodResult]
    foreground: dict[float, np.ndarray] = field(default_factory=dict)
    view_indices: list[int] = field(default_factory=list)
    device: str = "cpu"


def checked_output_sizes(mesh: TexturedMesh, scale: int) -> list[tuple[int, int] | None]:
    """:func:`geoscaler.filters.output_sizes`, refusing a mesh with nothing to downsample."""
    try:
        sizes = output_sizes(mesh, scale)
    except GeoscalerError as error:
        raise GeoscalerError(f"--scale {scale}: {error}") from None
    if all(size is None for size in sizes):
        raise GeoscalerError("the mesh has no base-colour texture; there is nothing to downsample")
    return sizes


def ship_textures(
    mesh: TexturedMesh, textures: Sequence[np.ndarray | None], scale: int
) -> list[np.ndarray | None]:
    """The method's textures as they will be written: where the original has alpha and the
    method returned RGB only (learned methods optimise colour), the reference map's alpha is
    downsampled with Lanczos and appended, so cut-outs survive. (The reference map, a resize of
    the original when it is over 2048 texels, is made only where alpha is needed.)"""
    shipped: list[np.ndarray | None] = []
    for texture, material in zip(textures, mesh.materials, strict=True):
        original = material.base_color_texture
        if texture is not None and original is not None:
            if texture.shape[2] == 3 and original.shape[2] in (2, 4):
                alpha = reference_texture(original)[..., -1:]
                alpha = lanczos(np.ascontiguousarray(alpha), scale)
                texture = np.concatenate([texture, alpha.reshape(*texture.shape[:2], 1)], axis=2)
        shipped.append(texture)
    return shipped


def remaining_budget(budget: float | None, spent: float) -> float | None:
    """What is left of a time budget (None: no budget) after ``spent`` seconds of the job's
    work for the method, such as caching the validation views; kept positive."""
    return None if budget is None else max(budget - spent, 1e-3)


def compare_mesh(
    mesh: TexturedMesh,
    scales: Sequence[int],
    methods: Sequence[str],
    distances: Sequence[float] = (VALIDATION_DISTANCE,),
    options: MethodOptions | None = None,
    renderer: Renderer | None = None,
    observer: JobObserver | None = None,
    controller: Controller | None = None,
    started_at: float | None = None,
    reserve: float = 0.0,
    rows_on: str = "protocol",
) -> Comparison:
    """Run ``methods`` at every scale and score them.

    The filters run first; they are the *baselines* of the learned methods, which validate on a
    :class:`~geoscaler.validation.Validation` (Q and near/far guards, cached while they train)
    and ship their result only where it clears the best baseline on every validation set
    (:func:`no_worse_than_filters`).

    Args:
        mesh: the mesh; its textures are the originals.
        scales: whole reduction factors >= 2 (e.g. ``[4, 8]``).
        methods: registered method names, in the order rows are wanted; bicubic runs for the
            gains whether listed or not.
        distances: camera distances of the protocol view sets scored (2.4 is Q; 1.5 near,
            4.0 far); ``rows_on="validation"`` scores Q only.
        options: settings of every method; ``options.device`` also renders the views.
        renderer: the mesh's renderer; its ``evaluation`` says the image size and the views
            standing for each set (default: protocol 1 on ``options.device``).
        observer: watches the job.
        controller: pauses or stops the learned methods (their best state so far is kept).
        started_at: the ``time.perf_counter()`` from which ``options.time_budget`` is the wall
            clock of the whole job (``downsample``: the command's start); a learned method then
            gets what is left, and keeps ``reserve`` seconds and the time of the rows' scoring
            for after it. None (``compare``, ``bench``): each learned method's budget counts
            from its own start.
        reserve: seconds the caller needs after this returns (``downsample``: the export).
        rows_on: ``"protocol"``: rows on the protocol's view sets at ``distances`` (all their
            views, after the methods); ``"validation"``: rows on the validation's Q views, the
            ones the shipped result was chosen on (a downsampling job's report, inside its
            budget).

    Returns:
        A :class:`Comparison`; its rows are ordered by distance, scale, then ``methods``.

    Raises:
        GeoscalerError: an unknown method, a bad scale or distance, a scale too large for a
            texture, or a method's own error.
    """
    check_geometry(mesh, mesh.source_path or "the mesh")
    scales = check_scales(scales)
    distances = [VALIDATION_DISTANCE] if rows_on == "validation" else check_distances(distances)
    listed = [check_method(name) for name in methods]
    options = options or MethodOptions()
    observer = observer or JobObserver()
    sizes = {scale: checked_output_sizes(mesh, scale) for scale in scales}
    to_run = listed if GAIN_REFERENCE in listed else [*listed, GAIN_REFERENCE]
    filters = [name for name in to_run if not is_learned(name)]
    learned = [name for name in to_run if is_learned(name)]
    renderer = renderer or Renderer(mesh, options.device)
    comparison = Comparison([], {}, device=str(renderer.device))
    view_sets = validation_view_sets(renderer)
    observer.views_cached(VALIDATION_DISTANCE, view_sets["Q"])
    q_order = spread_order(len(renderer.evaluation.view_indices))
    comparison.view_indices = [renderer.evaluation.view_indices[i] for i in q_order]
    steps = len(scales) * len(to_run) * (1 + len(distances))
    progress = _Stages(observer, steps + len(distances))
    scores: dict[tuple[float, str, int], dict[str, Any]] = {}
    for scale in scales:
        outputs: dict[str, MethodResult] = {}
        for name in filters:
            progress.step(f"{name} x{scale}")
            outputs[name] = _run(mesh, scale, name, options, renderer, None, None, observer)
        scorings_after = len(to_run) if rows_on == "validation" else 0
        baselines = {name: outputs[name].textures for name in filters}
        validation = Validation(view_sets, sizes[scale], baselines, scorings_after)
        for name in learned:
            progress.step(f"{name} x{scale}")
            budget = options.time_budget
            if started_at is not None:
                budget = remaining_budget(budget, time.perf_counter() - started_at)
            context = RunContext(
                renderer, validation, controller, observer.on_event, budget, reserve
            )
            method_start = time.perf_counter()
            result = _run(mesh, scale, name, options, renderer, context, budget, observer)
            if started_at is not None and "first_step_seconds" in result.details:
                first = method_start - started_at + result.details["first_step_seconds"]
                result.details["first_step_after_start"] = round(first, 3)
            outputs[name] = no_worse_than_filters(name, result, validation, outputs)
        if rows_on == "validation":
            _cache_for_rows(validation, options.time_budget, started_at, reserve)
            for name in to_run:
                progress.step(f"scoring {name} x{scale}")
                row = validation_row(outputs[name], name, scale, validation)
                scores[VALIDATION_DISTANCE, name, scale] = row
                observer.scored(row)
        comparison.outputs.update({(name, scale): outputs[name] for name in to_run})
    if rows_on == "protocol":
        _score_protocol_sets(
            comparison,
            mesh,
            scales,
            to_run,
            distances,
            view_sets["Q"],
            progress,
            observer,
            scores,
            sizes,
        )
    for (distance, name, scale), row in scores.items():
        reference = scores[distance, GAIN_REFERENCE, scale]["psnr_fg"]
        row["gain_db"] = 0.0 if name == GAIN_REFERENCE else row["psnr_fg"] - reference
    comparison.rows = [
        scores[distance, name, scale]
        for distance in distances
        for scale in scales
        for name in listed
    ]
    q = view_sets["Q"]
    if len(q):
        counts = q.foreground[: len(q)].sum(dim=(1, 2)).cpu().numpy()
        comparison.foreground.setdefault(VALIDATION_DISTANCE, counts)
    progress.done()
    return comparison


class _Stages:
    """Counts the job's stages for :meth:`JobObserver.stage`."""

    def __init__(self, observer: JobObserver, total: int):
        self.observer, self.total, self.count = observer, total, 0

    def step(self, what: str) -> None:
        self.observer.stage(what, self.count, self.total)
        self.count = min(self.count + 1, self.total)

    def done(self) -> None:
        self.observer.stage("done", self.total, self.total)


def _cache_for_rows(
    validation: Validation, budget: float | None, started_at: float | None, reserve: float
) -> None:
    """Before the rows of a job without a learned method: cache the validation views (all of
    them, or under a budget those that leave time for the scoring and ``reserve``)."""
    if validation.frozen:
        return
    if budget is None or started_at is None:
        validation.cache_all()
    else:
        end = started_at + budget - reserve
        while time.perf_counter() + 2 * validation.seconds_needed(0, caching=True) < end:
            if not validation.cache_next():
                break
    validation.freeze()


def _score_protocol_sets(
    comparison: Comparison,
    mesh: TexturedMesh,
    scales: Sequence[int],
    names: Sequence[str],
    distances: Sequence[float],
    q: ViewSet,
    progress: _Stages,
    observer: JobObserver,
    scores: dict[tuple[float, str, int], dict[str, Any]],
    sizes: dict[int, list[tuple[int, int] | None]],
) -> None:
    """Score every output on all views of the protocol's sets at ``distances`` (Q's views are
    the validation's, completed here)."""
    for distance in distances:
        progress.step(f"rendering the views at {distance:g}")
        if distance == VALIDATION_DISTANCE:
            while q.cache_next():
                observer.stage("caching Q", len(q), len(q.cameras))
            views = q
        else:  # the same directions, in the same order as Q's
            cameras = view_set_cameras(distance, q.renderer.evaluation)
            views = ViewSet(q.renderer, [cameras[i] for i in spread_order(len(cameras))])
        comparison.foreground[distance] = views.foreground.sum(dim=(1, 2)).cpu().numpy()
        if views is not q:  # Q was handed over as the job started
            observer.views_cached(distance, views)
        for scale in scales:
            cache = ViewCache(views, sizes[scale], with_taps=True)
            for name in names:
                progress.step(f"scoring {name} x{scale} at {distance:g}")
                row = protocol_row(comparison.outputs[name, scale], name, scale, distance, cache)
                scores[distance, name, scale] = row
                observer.scored(row)


def no_worse_than_filters(
    name: str,
    result: MethodResult,
    validation: Validation,
    filters: dict[str, MethodResult],
) -> MethodResult:
    """What a learned method ships: of its result and the filters, the one
    :meth:`Validation.rank` puts first: the learned result wherever it is no worse than the
    best filter on every validation set (Q, near, far), else whichever falls least below that
    floor on its worst set (a learned method starts from Lanczos; a pool cut short or a bad
    run must not ship below the filters the job has).

    Args:
        name: the learned method.
        result: its result; ``details["validation_scores"]`` from the loop (a method without
            them ships as it is).
        validation: the validation sets, frozen, with the filters as baselines.
        filters: filter name -> its result, at the same scale.

    Returns:
        The result to ship; ``details["shipped"]`` names what ships, ``["shortfall_db"]`` is
        how far the method's own result fell below the floor.
    """
    scores = {name: result.details.get("validation_scores"), **validation.baseline_scores()}
    if scores[name] is None:
        result.details["shipped"] = name
        return result
    best = max(scores, key=lambda candidate: validation.rank(scores[candidate]))
    result.details["shipped"] = best
    result.details["shortfall_db"] = validation.shortfall(scores[name])
    if best == name:
        return result
    return MethodResult(list(filters[best].textures), None, result.seconds, result.details)


def _run(
    mesh: TexturedMesh,
    scale: int,
    name: str,
    options: MethodOptions,
    renderer: Renderer,
    context: RunContext | None,
    budget: float | None,
    observer: JobObserver,
) -> MethodResult:
    """Run one method as the job does: a learned one with the job's ``context`` (renderer,
    validation, ``budget`` seconds); every output with its alpha re-attached as it will ship."""
    observer.method_started(name, scale, budget if is_learned(name) else None)
    result = run_method(name, mesh, scale, options, context if is_learned(name) else None)
    result.textures = ship_textures(mesh, result.textures, scale)
    return result


# ----------------------------------------------------------------------------- downsampling


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
        started_at: the ``time.perf_counter()`` its time budget counts from (the command's
            start: loading the mesh included).
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
    started_at: float = field(default_factory=time.perf_counter)


def check_output_name(output: str | Path, mesh_path: Path, force: bool) -> Path:
    """OUT's suffix, folder and existence, before the mesh is even read."""
    output = Path(output)
    if output.suffix.lower() not in OUTPUT_SUFFIXES:
        raise GeoscalerError(
            f"-o {output}: the output format comes from the suffix; use one of "
            f"{', '.join(OUTPUT_SUFFIXES)}"
        )
    return check_output(output, force=force, inputs=[mesh_path])


def prepare_out_dir(
    out: str | Path, names: Sequence[str], force: bool, inputs: Sequence[Path]
) -> list[Path]:
    """Create the folder ``out`` if needed and check every output file in it before work."""
    folder = prepare_folder(out)
    return [check_output(folder / name, force=force, inputs=inputs) for name in names]


def _check_distinct(report: Path, others: Sequence[Path], what: str) -> None:
    for other in others:
        if report.resolve() == Path(other).resolve():
            raise GeoscalerError(f"--report {report}: is {what}; choose another name")


def prepare(
    mesh_path: str | Path,
    output: str | Path,
    scale: Any,
    method: str,
    options: MethodOptions,
    force: bool = False,
    report: str | Path | None = None,
    started_at: float | None = None,
) -> Job:
    """Check everything that can be checked, load the mesh, and return the :class:`Job`.

    ``started_at``: the ``time.perf_counter()`` the job's time budget counts from (default:
    now; the CLI passes its process's start).

    Raises:
        GeoscalerError: a bad scale or method, an output name, folder or suffix; an output
            that is an input file (even with ``force``) or exists without ``force``; an
            unreadable mesh; a scale larger than a texture.
    """
    started_at = time.perf_counter() if started_at is None else started_at
    mesh_path = Path(mesh_path)
    scale = check_scale(scale)
    method = check_method(method)
    output = check_output_name(output, mesh_path, force)
    report_path = None
    if report is not None:
        report_path = check_output(report, force=force, inputs=[mesh_path])
        _check_distinct(report_path, [output], "the output mesh")
    mesh = load_mesh(mesh_path)
    sizes = checked_output_sizes(mesh, scale)
    files = check_outputs(output_files(mesh, output), force=force, inputs=mesh.source_files)
    if report_path is not None:
        check_output(report_path, force=force, inputs=mesh.source_files)
        _check_distinct(report_path, files, "a file of the output mesh")
    return Job(
        mesh_path,
        mesh,
        output,
        scale,
        method,
        options,
        force,
        report_path,
        files,
        sizes,
        started_at,
    )


@dataclass
class Downsampled:
    """What :func:`run_job` produced and measured.

    Attributes:
        result: the method's textures as they ship (8-bit, alpha re-attached), UVs, seconds
            (caching of Q included for learned methods) and details.
        comparison: the rows on Q: the method first, then bicubic and Lanczos, each with its
            ``gain_db`` over bicubic; the outputs (for pictures).
        details: the method's details plus how Q was used.
    """

    result: MethodResult
    comparison: Comparison
    details: dict[str, Any]

    @property
    def rows(self) -> list[dict[str, Any]]:
        return self.comparison.rows


def downsample(
    mesh: TexturedMesh,
    scale: int,
    method: str,
    options: MethodOptions,
    renderer: Renderer | None = None,
    observer: JobObserver | None = None,
    controller: Controller | None = None,
    started_at: float | None = None,
    reserve: float = 0.0,
) -> Downsampled:
    """Run ``method`` on ``mesh`` at ``scale`` and score it, bicubic and Lanczos on Q.

    ``started_at``, ``reserve``: as :func:`compare_mesh` (None: the budget counts from the
    caching of Q).
    """
    methods = [method, *(name for name in REPORT_BASELINES if name != method)]
    comparison = compare_mesh(
        mesh,
        [scale],
        methods,
        [VALIDATION_DISTANCE],
        options,
        renderer,
        observer,
        controller,
        started_at,
        reserve,
        rows_on="validation",
    )
    result = comparison.outputs[method, scale]
    details = dict(result.details)
    if is_learned(method):
        details["time_budget"] = options.time_budget
        details["steps_limit"] = options.steps
    return Downsampled(result, comparison, details)


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


def run_job(
    job: Job,
    renderer: Renderer | None = None,
    observer: JobObserver | None = None,
    controller: Controller | None = None,
) -> tuple[Downsampled, list[Path]]:
    """Run a prepared job end to end: downsample, score, write the mesh; returns what was done
    and the files written (the report is written by the caller, which knows the seconds).

    The time budget is the wall clock of the whole job, from :func:`prepare` to the export
    (:data:`EXPORT_RESERVE` seconds are kept for writing the files).
    """
    done = downsample(
        job.mesh,
        job.scale,
        job.method,
        job.options,
        renderer,
        observer,
        controller,
        job.started_at,
        EXPORT_RESERVE,
    )
    (observer or JobObserver()).stage("writing", 0, 1)
    written = export(job.mesh, done.result, job.output, job.force)
    return done, written
