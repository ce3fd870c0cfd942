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
from geoscaler.cameras import view_set_cameras
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
from geoscaler.mesh import TexturedMesh
from geoscaler.methods import MethodOptions, MethodResult, RunContext, is_learned, run_method
from geoscaler.metrics import METRIC_NAMES, mean_metrics
from geoscaler.optimize import Controller, ProgressEvent
from geoscaler.protocol import BYTES_PER_TEXEL, GAIN_REFERENCE, VALIDATION_DISTANCE
from geoscaler.render import Renderer
from geoscaler.views import ViewCache, ViewSet

OUTPUT_SUFFIXES = (".glb", ".gltf", ".obj")
EXPORT_RESERVE = 2.0
"""Seconds a downsampling job keeps for writing its files and report after scoring (on the
2-core machine a 2048 x 2048 scan texture encodes to PNG in 0.4 s, a 4096 x 4096 one in 1.3 s)."""
REPORT_BASELINES = ("bicubic", "lanczos")
"""Methods a downsampling job always scores beside its result (bicubic is the gain's zero)."""

ROW_KEYS = (
    "method",
    "scale",
    "distance",
    "views",
    "texture_size",
    "texture_bytes",
    *METRIC_NAMES,
    "gain_db",
    "seconds",
    "shipped",
)
"""Keys of a result row: ``texture_size`` is ``[width, height]`` of the largest texture,
``texture_bytes`` the RGBA8 memory of all textures (``BYTES_PER_TEXEL``), PSNRs and gain in
dB (``+inf`` for a render identical to the reference), ``seconds`` the method's wall time,
``shipped`` the method whose textures the row scores: the row's own, or for a learned method
the filter that beat it on Q (:func:`no_worse_than_filters`)."""


class JobObserver:
    """Watches a job; each hook does nothing unless a subclass says otherwise."""

    def stage(self, what: str, done: int, total: int) -> None:
        """Coarse progress: ``what`` is running, ``done`` of ``total`` units of it are done."""

    def views_cached(self, distance: float, views: ViewSet) -> None:
        """The view set at ``distance`` is cached (Q before any method runs)."""

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
        q_seconds: seconds spent caching Q (and its taps) for the learned methods.
    """

    rows: list[dict[str, Any]]
    outputs: dict[tuple[str, int], MethodResult]
    foreground: dict[float, np.ndarray] = field(default_factory=dict)
    view_indices: list[int] = field(default_factory=list)
    device: str = "cpu"
    q_seconds: float = 0.0


def texture_facts(textures: Sequence[np.ndarray | None]) -> tuple[list[int], int]:
    """``([width, height]`` of the largest texture, RGBA8 bytes of them all)``."""
    present = [t for t in textures if t is not None]
    if not present:
        return [0, 0], 0
    largest = max(present, key=lambda t: t.shape[0] * t.shape[1])
    texels = sum(t.shape[0] * t.shape[1] for t in present)
    return [int(largest.shape[1]), int(largest.shape[0])], int(texels * BYTES_PER_TEXEL)


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


def _row(
    result: MethodResult, name: str, scale: int, distance: float, cache: ViewCache
) -> dict[str, Any]:
    """A result row without its gain: the output scored on one cached view set."""
    metrics = mean_metrics(cache.score(result.textures, result.uvs))
    size, nbytes = texture_facts(result.textures)
    return {
        "method": name,
        "scale": scale,
        "distance": distance,
        "views": len(cache),
        "texture_size": size,
        "texture_bytes": nbytes,
        **{key: metrics[key] for key in METRIC_NAMES},
        "seconds": result.seconds,
        "shipped": result.details.get("shipped", name),
    }


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
) -> Comparison:
    """Run ``methods`` at every scale and score them on the protocol views at each distance.

    Args:
        mesh: the mesh; its textures are the originals.
        scales: whole reduction factors >= 2 (e.g. ``[4, 8]``).
        methods: registered method names, in the order rows are wanted; bicubic runs for the
            gains whether listed or not.
        distances: camera distances of the view sets (2.4 is Q; 1.5 near, 4.0 far).
        options: settings of every method; ``options.device`` also renders the views.
        renderer: the mesh's renderer; its ``evaluation`` says the image size and the views
            standing for each set (default: protocol 1 on ``options.device``).
        observer: watches the job.
        controller: pauses or stops the learned methods (their best state so far is kept).
        started_at: the ``time.perf_counter()`` from which ``options.time_budget`` is the wall
            clock of the whole job (``downsample``: the command's start); a learned method then
            gets what is left once everything before it is done, less 1.5 times the time of
            scoring a filter on Q (its own scoring comes after it) and ``reserve``. None
            (``compare``, ``bench``): each learned method's budget counts from the caching of
            Q, per scale.
        reserve: seconds the caller needs after this returns (``downsample``: the export).

    Returns:
        A :class:`Comparison`; its rows are ordered by distance, scale, then ``methods``.

    Raises:
        GeoscalerError: an unknown method, a bad scale or distance, a scale too large for a
            texture, or a method's own error.
    """
    scales = check_scales(scales)
    distances = check_distances(distances)
    listed = [check_method(name) for name in methods]
    options = options or MethodOptions()
    observer = observer or JobObserver()
    sizes = {scale: checked_output_sizes(mesh, scale) for scale in scales}
    to_run = listed if GAIN_REFERENCE in listed else [*listed, GAIN_REFERENCE]
    to_run = sorted(to_run, key=is_learned)  # filters first: their scores come early
    renderer = renderer or Renderer(mesh, options.device)
    evaluation = renderer.evaluation
    comparison = Comparison([], {}, device=str(renderer.device))
    comparison.view_indices = evaluation.view_indices
    others = [distance for distance in distances if distance != VALIDATION_DISTANCE]
    total = len(scales) * len(to_run) * (1 + len(distances)) + len(others)
    done = 0

    def step(what: str) -> None:
        nonlocal done
        observer.stage(what, done, total)
        done += 1

    scores: dict[tuple[float, str, int], dict[str, Any]] = {}
    q = None
    if VALIDATION_DISTANCE in distances or any(is_learned(name) for name in to_run):
        start = time.perf_counter()
        cameras = view_set_cameras(VALIDATION_DISTANCE, evaluation)
        q = ViewSet(renderer, cameras, lambda d, n: observer.stage("caching Q", d, n))
        comparison.q_seconds = time.perf_counter() - start
        comparison.foreground[VALIDATION_DISTANCE] = q.foreground.sum(dim=(1, 2)).cpu().numpy()
        observer.views_cached(VALIDATION_DISTANCE, q)
    for scale in scales:
        q_cache, q_seconds = None, comparison.q_seconds
        if q is not None:
            start = time.perf_counter()
            q_cache = ViewCache(q, sizes[scale], with_taps=True)
            q_seconds += time.perf_counter() - start
        on_q: dict[str, tuple[MethodResult, dict[str, Any]]] = {}
        score_seconds = 0.0
        for name in to_run:
            step(f"{name} x{scale}")
            budget = None
            if is_learned(name):
                spent = q_seconds
                if started_at is not None:
                    after = 1.5 * score_seconds + reserve
                    spent = time.perf_counter() - started_at + after
                budget = remaining_budget(options.time_budget, spent)
            result = _run(
                mesh, scale, name, options, renderer, q_cache, budget, observer, controller
            )
            if is_learned(name):
                result.seconds += q_seconds  # the job's caching for it
            if q_cache is not None:
                step(f"scoring {name} x{scale} on Q")
                start = time.perf_counter()
                row = _row(result, name, scale, VALIDATION_DISTANCE, q_cache)
                score_seconds = max(score_seconds, time.perf_counter() - start)
                if is_learned(name):
                    result, row = no_worse_than_filters(name, result, row, on_q)
                else:
                    on_q[name] = result, row
                if VALIDATION_DISTANCE in distances:
                    scores[VALIDATION_DISTANCE, name, scale] = row
                    observer.scored(row)
            comparison.outputs[name, scale] = result
        del q_cache
    del q
    for distance in others:
        step(f"rendering the views at {distance:g}")
        views = ViewSet(renderer, view_set_cameras(distance, evaluation))
        comparison.foreground[distance] = views.foreground.sum(dim=(1, 2)).cpu().numpy()
        observer.views_cached(distance, views)
        for scale in scales:
            cache = ViewCache(views, sizes[scale], with_taps=True)
            for name in to_run:
                step(f"scoring {name} x{scale} at {distance:g}")
                row = _row(comparison.outputs[name, scale], name, scale, distance, cache)
                scores[distance, name, scale] = row
                observer.scored(row)
            del cache
        del views
    for (distance, name, scale), row in scores.items():
        reference = scores[distance, GAIN_REFERENCE, scale]["psnr_fg"]
        row["gain_db"] = 0.0 if name == GAIN_REFERENCE else row["psnr_fg"] - reference
    comparison.rows = [
        scores[distance, name, scale]
        for distance in distances
        for scale in scales
        for name in listed
    ]
    observer.stage("done", total, total)
    return comparison


def no_worse_than_filters(
    name: str,
    result: MethodResult,
    row: dict[str, Any],
    filters: dict[str, tuple[MethodResult, dict[str, Any]]],
) -> tuple[MethodResult, dict[str, Any]]:
    """What a learned method ships: its result, or the best filter scored on Q beside it
    where that filter scored higher there (a learned method starts from Lanczos; a pool cut
    short or a bad run must not ship below the filters the job already has).

    Args:
        name: the learned method.
        result, row: its result and Q row.
        filters: filter name -> its result and Q row, at the same scale.

    Returns:
        The result and row to ship; ``row["shipped"]`` and ``details["shipped"]`` name what
        ships, and ``details["optimised_psnr_fg"]`` is the method's own score on Q.
    """
    result.details["optimised_psnr_fg"] = row["psnr_fg"]
    best = max(filters, key=lambda f: filters[f][1]["psnr_fg"], default=None)
    if best is None or filters[best][1]["psnr_fg"] <= row["psnr_fg"]:
        result.details["shipped"] = name
        return result, row
    shipped, shipped_row = filters[best]
    details = {**result.details, "shipped": best}
    result = MethodResult(list(shipped.textures), None, result.seconds, details)
    return result, {**shipped_row, "method": name, "seconds": result.seconds, "shipped": best}


def _run(
    mesh: TexturedMesh,
    scale: int,
    name: str,
    options: MethodOptions,
    renderer: Renderer,
    q_cache: ViewCache | None,
    budget: float | None,
    observer: JobObserver,
    controller: Controller | None,
) -> MethodResult:
    """Run one method as the job does: a learned one on the job's renderer and cached Q, with
    ``budget`` seconds; every output with its alpha re-attached as it will ship."""
    if not is_learned(name):
        observer.method_started(name, scale, None)
        result = run_method(name, mesh, scale, options)
    else:
        context = RunContext(renderer, q_cache, controller, observer.on_event, budget)
        observer.method_started(name, scale, budget)
        result = run_method(name, mesh, scale, options, context)
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
        started_at: the ``time.perf_counter()`` when the job was prepared: its time budget
            counts from there (loading the mesh included).
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
) -> Job:
    """Check everything that can be checked, load the mesh, and return the :class:`Job`.

    Raises:
        GeoscalerError: a bad scale or method, an output name, folder or suffix; an output
            that is an input file (even with ``force``) or exists without ``force``; an
            unreadable mesh; a scale larger than a texture.
    """
    started_at = time.perf_counter()
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
    )
    result = comparison.outputs[method, scale]
    details = {
        **result.details,
        "validation_views": len(comparison.view_indices),
        "validation_cache_seconds": round(comparison.q_seconds, 3),
    }
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
    written = export(job.mesh, done.result, job.output, job.force)
    return done, written
