"""The downsampling job: what ``geoscaler downsample``, the demo and the app's export run.

:func:`prepare` checks everything that can be checked before long work (arguments, outputs
that must not overwrite inputs, the mesh) and returns a :class:`Job`; :func:`run_job` runs it
through :func:`geoscaler.pipeline.job.downsample` (the method beside bicubic and Lanczos on Q) and
:func:`export` writes the asset as it ships (:mod:`geoscaler.pipeline.shipping`: every map at its
class's size).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from geoscaler.clock import WALL_CLOCK, Clock
from geoscaler.errors import GeoscalerError
from geoscaler.io import (
    check_output,
    check_outputs,
    load_mesh,
    output_files,
    save_mesh,
    written_image,
)
from geoscaler.mesh import TexturedMesh
from geoscaler.methods import MethodOptions, MethodResult
from geoscaler.optim.events import Controller
from geoscaler.pipeline.arguments import check_method, check_protocol
from geoscaler.pipeline.job import (
    Downsampled,
    JobBudget,
    JobObserver,
    checked_output_sizes,
    downsample,
)
from geoscaler.pipeline.shipping import (
    ShippedMap,
    asset_of,
    export_seconds,
    relayout_seconds,
    with_lossless_formats,
)
from geoscaler.protocol import Evaluation
from geoscaler.render.lit import default_protocol
from geoscaler.render.renderer import Renderer
from geoscaler.resize.sizes import SizePlan, check_scale, size_plan

OUTPUT_SUFFIXES = (".glb", ".gltf", ".obj")
EXPORT_MARGIN = 2.0
"""How many times its priced seconds (:func:`~geoscaler.pipeline.shipping.export_seconds`,
:func:`~geoscaler.pipeline.shipping.relayout_seconds`) a job keeps for its export: the rates
are the 2-core AMD dev machine's, and the 2-core Intel one rendered and encoded at about
half its speed."""
EXPORT_LEAST = 0.3
"""Seconds a job keeps for its export whatever it writes: the files' writes and renames,
the report (the export of a 256 x 256 base colour alone took 0.02 s)."""


def export_reserve(job: Job) -> JobBudget:
    """The job's budget with the seconds its export is priced at kept back after the method
    (:data:`EXPORT_LEAST`, then :data:`EXPORT_MARGIN` times the price), and those a new UV
    layout's re-bake of the other maps would add, kept back only by a method that ships one."""
    writing = export_seconds(job.mesh, job.plan, job.image_format)
    relayout = EXPORT_MARGIN * relayout_seconds(job.mesh, job.plan)
    return JobBudget(job.started_at, EXPORT_LEAST + EXPORT_MARGIN * writing, relayout)


@dataclass
class Job:
    """A checked downsampling job, its mesh loaded.

    Attributes:
        mesh_path: the input file (never written).
        mesh: the loaded mesh.
        output: the mesh file to write; ``output_files`` are all the files that go with it.
        plan: the size rule of each texture class (the method makes the base colours at
            ``plan.color``'s sizes, from the full-resolution originals).
        method, options: what to run.
        force: replace existing outputs.
        report: the JSON report to write, or None.
        sizes: per material the base colour's output size ``(h, w)`` (None: untextured).
        started_at: the instant on ``clock`` its time budget counts from (the command's
            start: loading the mesh included).
        clock: where the job reads the time.
        image_format: "png", "jpeg" or "webp" for every image written (None: as the input).
        protocol: 1, the base colour optimised unlit; 2, ``direct`` then trains the normal
            and data maps lit (:mod:`geoscaler.pipeline.lit`).
    """

    mesh_path: Path
    mesh: TexturedMesh
    output: Path
    plan: SizePlan
    method: str
    options: MethodOptions
    force: bool = False
    report: Path | None = None
    output_files: list[Path] = field(default_factory=list)
    sizes: list[tuple[int, int] | None] = field(default_factory=list)
    started_at: float = field(default_factory=WALL_CLOCK.now)
    image_format: str | None = None
    clock: Clock = WALL_CLOCK
    protocol: int = 1


def product_evaluation(evaluation: Evaluation) -> Evaluation:
    """``evaluation`` as a downsampling job renders: the originals at full resolution (the
    protocol's 2048 cap is an evaluation convention, not a product limit)."""
    return replace(evaluation, reference_max_size=None)


def check_output_name(output: str | Path, mesh_path: Path, force: bool) -> Path:
    """OUT's suffix, folder and existence, before the mesh is even read."""
    output = Path(output)
    if output.suffix.lower() not in OUTPUT_SUFFIXES:
        raise GeoscalerError(
            f"-o {output}: the output format comes from the suffix; use one of "
            f"{', '.join(OUTPUT_SUFFIXES)}"
        )
    return check_output(output, force=force, inputs=[mesh_path])


def _check_distinct(report: Path, others: Sequence[Path], what: str) -> None:
    for other in others:
        if report.resolve() == Path(other).resolve():
            raise GeoscalerError(f"--report {report}: is {what}; choose another name")


def prepare(
    mesh_path: str | Path,
    output: str | Path,
    sizes: int | SizePlan,
    method: str,
    options: MethodOptions,
    force: bool = False,
    report: str | Path | None = None,
    started_at: float | None = None,
    image_format: str | None = None,
    clock: Clock = WALL_CLOCK,
    protocol: int | None = None,
) -> Job:
    """Check everything that can be checked, load the mesh, and return the :class:`Job`.

    ``sizes``: a scale for every texture, or a rule per texture class. ``started_at``: the
    instant on ``clock`` the job's time budget counts from (default: now; the CLI passes its
    process's start). ``image_format``: "png", "jpeg" or "webp" for every image written
    (None: each in its input's format). ``protocol``: 1 or 2 (:class:`Job`); None: the
    mesh's default (:func:`geoscaler.render.lit.default_protocol`).

    Raises:
        GeoscalerError: a bad scale or method, an output name, folder or suffix; an output
            that is an input file (even with ``force``) or exists without ``force``; an
            unreadable mesh; a scale larger than a texture.
    """
    started_at = clock.now() if started_at is None else started_at
    mesh_path = Path(mesh_path)
    plan = sizes if isinstance(sizes, SizePlan) else size_plan({"all": check_scale(sizes)}, {})
    method = check_method(method)
    output = check_output_name(output, mesh_path, force)
    report_path = None
    if report is not None:
        report_path = check_output(report, force=force, inputs=[mesh_path])
        _check_distinct(report_path, [output], "the output mesh")
    mesh = load_mesh(mesh_path)
    protocol = default_protocol(mesh) if protocol is None else check_protocol(protocol)
    base_sizes = checked_output_sizes(mesh, plan.color, None)
    originals = [m.base_color_texture for m in mesh.materials]
    if all(t is None or t.shape[:2] == size for t, size in zip(originals, base_sizes, strict=True)):
        raise GeoscalerError(
            f"sizes {plan.color.label} for colour textures: no base-colour texture would get "
            "smaller, so there is nothing for the method to do; give --scale or --max-size "
            "for every class (e.g. --scale 4) or for color (--scale color=2)"
        )
    files = output_files(with_lossless_formats(mesh, plan), output, image_format=image_format)
    if report_path is not None:
        _check_distinct(report_path, files, "a file of the output mesh")
    reports = [] if report_path is None else [report_path]
    # The last check before long work: the only one that tries a file in the folders.
    check_outputs([*files, *reports], force=force, inputs=mesh.source_files, probe=True)
    return Job(
        mesh_path,
        mesh,
        output,
        plan,
        method,
        options,
        force,
        report_path,
        files,
        base_sizes,
        started_at,
        image_format,
        clock,
        protocol,
    )


def export(
    mesh: TexturedMesh,
    result: MethodResult,
    output: Path,
    plan: SizePlan,
    method: str,
    force: bool = False,
    image_format: str | None = None,
) -> tuple[list[Path], list[ShippedMap]]:
    """Write the asset as it ships (:func:`geoscaler.pipeline.shipping.ship_asset`: the
    result's base colours and UVs, every other map at its class's size) in the format
    ``output`` names.

    Returns the files written, the main file last, and every texture before and after, with
    the bytes of its image as written.
    """
    out_mesh, maps = asset_of(mesh, result, plan, method)
    written = save_mesh(out_mesh, output, overwrite=force, image_format=image_format)
    for shipped in maps:
        shipped.bytes_after, shipped.format_after = written_image(
            out_mesh, shipped.pixels, output, image_format
        )
    return written, maps


def run_job(
    job: Job,
    renderer: Renderer | None = None,
    observer: JobObserver | None = None,
    controller: Controller | None = None,
) -> tuple[Downsampled, list[Path]]:
    """Run a prepared job end to end: downsample, score, write the mesh; returns what was done
    and the files written (the report is written by the caller, which knows the seconds).

    The time budget is the wall clock of the whole job, from :func:`prepare` to the export
    (the seconds the export is priced at are kept for it, :func:`export_reserve`).
    """
    renderer = renderer or Renderer(job.mesh, job.options.device, product_evaluation(Evaluation()))
    done = downsample(
        job.mesh,
        job.plan.color,
        job.method,
        job.options,
        renderer,
        observer,
        controller,
        export_reserve(job),
        job.clock,
        job.protocol,
        job.plan,
    )
    (observer or JobObserver()).stage("writing", 0, 1)
    shipped = done.result.shipped(job.method)
    written, done.maps = export(
        job.mesh, done.result, job.output, job.plan, shipped, job.force, job.image_format
    )
    return done, written
