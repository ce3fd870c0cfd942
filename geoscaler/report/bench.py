"""Benchmark methods over many meshes: the paper-style table, CSV/JSON/Markdown and a plot.

``geoscaler bench PATH...`` finds mesh files (a folder whose ``meta.json`` names an ``"entry"``
contributes that one file; other folders every ``.obj``/``.gltf``/``.glb`` in them, searched
recursively), runs :func:`geoscaler.pipeline.job.compare_mesh` on each, skips (and reports) a mesh
that fails, and averages the protocol metrics over the meshes that succeeded.
"""

from __future__ import annotations

import csv
import io
import math
import shlex
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from geoscaler.clock import WALL_CLOCK, Clock
from geoscaler.errors import GeoscalerError
from geoscaler.io import SUPPORTED_SUFFIXES, find_assets, load_mesh
from geoscaler.methods import MethodOptions
from geoscaler.pipeline.arguments import (
    check_distances,
    check_method,
    check_protocol,
    check_scales,
    comparison_settings,
)
from geoscaler.pipeline.job import JobObserver, compare_mesh, prepare_out_dir
from geoscaler.pipeline.rows import ROW_KEYS
from geoscaler.protocol import (
    BYTES_PER_TEXEL,
    PROTOCOL_EVALUATION,
    VALIDATION_DISTANCE,
    Evaluation,
)
from geoscaler.render.metrics import METRIC_NAMES
from geoscaler.render.renderer import Renderer
from geoscaler.report.documents import describe_device, dumps, json_safe

METRIC_TITLES = {
    "psnr_fg": "PSNR-fg (dB)",
    "psnr_full": "PSNR-full (dB)",
    "ssim_full": "SSIM-full",
    "ssim_fg": "SSIM-fg",
    "gain_db": "gain over bicubic (dB)",
}
"""Row titles of the paper-style table, in order."""

MEMORY_NOTE = (
    f"texture memory = texels x {BYTES_PER_TEXEL} bytes (uncompressed RGBA8; RGB8 is padded to "
    "RGBA8 on GPUs), mip chain not counted"
)

OUTPUT_FILES = ("results.csv", "results.json", "results.md")


@dataclass
class MeshEntry:
    """A mesh file found by :func:`find_meshes` and the short name tables show for it."""

    path: Path
    name: str


@dataclass
class BenchResult:
    """What :func:`bench_meshes` measured.

    Attributes:
        rows: one dict per (mesh, distance, scale, method): ``"mesh"``, ``"path"`` and
            :data:`geoscaler.pipeline.job.ROW_KEYS`.
        meshes: the meshes that were evaluated.
        failed: ``(path, message)`` of each mesh that was skipped.
        device: the torch device of the renders (e.g. ``"cpu"``).
        seconds: wall time of the whole run.
        protocol: the protocol every row follows (PROTOCOL.md: 1 or 2).
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    meshes: list[MeshEntry] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)
    device: str = "cpu"
    seconds: float = 0.0
    protocol: int = 1


def _search_folder(root: Path) -> list[MeshEntry]:
    """Mesh files under ``root`` (:func:`geoscaler.io.find_assets`), named by their folder
    where a ``meta.json`` names them, else by their path under ``root``."""
    return [
        MeshEntry(found.path, found.path.parent.name if found.from_meta else found.relative)
        for found in find_assets(root)
    ]


def find_meshes(paths: Sequence[str | Path]) -> list[MeshEntry]:
    """Mesh files named by ``paths`` (files taken as given, folders searched), deduplicated.

    Raises:
        GeoscalerError: a path that does not exist, or no mesh file found at all.
    """
    found: list[MeshEntry] = []
    for path in map(Path, paths):
        if path.is_file():
            found.append(MeshEntry(path, path.name))
        elif path.is_dir():
            found += _search_folder(path)
        else:
            raise GeoscalerError(f"{path}: no such file or folder; check the path")
    unique = {entry.path.resolve(): entry for entry in reversed(found)}
    meshes = [e for e in found if unique.get(e.path.resolve()) is e]
    if not meshes:
        suffixes = ", ".join(SUPPORTED_SUFFIXES)
        where = " ".join(str(p) for p in paths)
        raise GeoscalerError(
            f"no mesh files ({suffixes}) found in {where}; give mesh files or folders that hold "
            'some (a folder\'s meta.json may name its mesh under "entry")'
        )
    return meshes


def bench_meshes(
    meshes: Sequence[MeshEntry],
    scales: Sequence[int],
    methods: Sequence[str],
    distances: Sequence[float] = (VALIDATION_DISTANCE,),
    options: MethodOptions | None = None,
    evaluation: Evaluation = PROTOCOL_EVALUATION,
    progress: bool = True,
    report: Callable[[str], None] | None = None,
    clock: Clock = WALL_CLOCK,
    protocol: int = 1,
) -> BenchResult:
    """Compare ``methods`` on every mesh; a mesh that fails is reported and skipped.

    Args:
        meshes: from :func:`find_meshes`.
        scales, methods, distances, options: as :func:`geoscaler.pipeline.job.compare_mesh`.
        evaluation: image size and views of every mesh's renders (default: protocol 1's).
        progress: show a tqdm bar on stderr.
        report: receives one line per skipped mesh (default: printed above the bar).
        clock: where the time is read.
        protocol: the protocol every mesh is scored under (one for all, so that means
            average like with like).

    Returns:
        A :class:`BenchResult` (possibly with no rows if every mesh failed).
    """
    from tqdm import tqdm

    scales, distances = check_scales(scales), check_distances(distances)
    methods = [check_method(name) for name in methods]
    options = options or MethodOptions()
    result = BenchResult(protocol=check_protocol(protocol))
    start = clock.now()
    with tqdm(meshes, desc="bench", unit="mesh", disable=not progress) as bar:
        say = report or (lambda line: bar.write(line, file=sys.stderr))
        for entry in bar:
            try:
                mesh = load_mesh(entry.path)
                comparison = compare_mesh(
                    mesh,
                    scales,
                    methods,
                    distances,
                    options,
                    Renderer(mesh, options.device, evaluation),
                    _MeshPostfix(bar, entry.name),
                    clock=clock,
                    protocol=result.protocol,
                )
            except (KeyboardInterrupt, MemoryError):
                raise
            except Exception as error:  # one bad mesh must not stop the batch
                message = _failure_message(error, entry.path)
                result.failed.append((str(entry.path), message))
                say(f"geoscaler: skipped a mesh: {message}")
                continue
            result.device = comparison.device
            result.meshes.append(entry)
            result.rows += [
                {"mesh": entry.name, "path": str(entry.path), **row} for row in comparison.rows
            ]
    result.seconds = clock.now() - start
    return result


class _MeshPostfix(JobObserver):
    """Shows ``name: what (done/total)`` after the bar over meshes."""

    def __init__(self, bar: Any, name: str):
        self.bar, self.name = bar, name

    def stage(self, what: str, done: int, total: int) -> None:
        self.bar.set_postfix_str(f"{self.name}: {what} ({done}/{total})")


def _failure_message(error: Exception, path: Path) -> str:
    """A user's error as it is, anything else with its type, flagged as unexpected; both name
    the mesh file."""
    if isinstance(error, GeoscalerError):
        message = str(error)
    else:
        message = f"unexpected {type(error).__name__}: {error} (please report this)"
    return message if str(path) in message else f"{path}: {message}"


def plural(count: int, noun: str) -> str:
    """``"1 mesh"``, ``"9 meshes"``, ``"60 views"``."""
    if count == 1:
        return f"{count} {noun}"
    return f"{count} {noun}es" if noun.endswith(("s", "sh", "ch")) else f"{count} {noun}s"


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if values else math.nan


def summarize(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Means over meshes, one dict per (distance, scale, method), in first-seen order.

    Keys: ``method, scale, distance, meshes`` (count), ``texture_bytes`` (mean over meshes),
    the metrics, ``gain_db`` and ``seconds`` (means over meshes).
    """
    groups: dict[tuple[float, int, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["distance"], row["scale"], row["method"]), []).append(row)
    keys = ["texture_bytes", *METRIC_NAMES, "gain_db", "seconds"]
    return [
        {
            "method": method,
            "scale": scale,
            "distance": distance,
            "meshes": len(group),
            **{key: _mean([r[key] for r in group]) for key in keys},
        }
        for (distance, scale, method), group in groups.items()
    ]


def _value(key: str, value: float) -> str:
    """A metric as tables print it: dB with 2 decimals (gain signed), SSIM with 4."""
    if not math.isfinite(value):
        return "inf" if value > 0 else "n/a"
    if key == "gain_db":
        return f"{value:+.2f}"
    return f"{value:.4f}" if key.startswith("ssim") else f"{value:.2f}"


def paper_table(summary: Sequence[dict[str, Any]], distance: float) -> list[list[str]]:
    """The paper-style grid at one distance: header, then per scale one row per metric.

    Columns: scale, metric, then one per method; cells are means over meshes.
    """
    rows = [s for s in summary if s["distance"] == distance]
    methods = list(dict.fromkeys(s["method"] for s in rows))
    cell = {(s["scale"], s["method"]): s for s in rows}
    grid = [["scale", "metric", *methods]]
    for scale in dict.fromkeys(s["scale"] for s in rows):
        for key, title in METRIC_TITLES.items():
            grid.append([f"x{scale}", title, *(_value(key, cell[scale, m][key]) for m in methods)])
    return grid


def per_mesh_table(rows: Sequence[dict[str, Any]], distance: float) -> list[list[str]]:
    """Per-mesh PSNR-fg grid at one distance: mesh, scale, texture, then one column per method."""
    rows = [r for r in rows if r["distance"] == distance]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cell = {(r["mesh"], r["scale"], r["method"]): r for r in rows}
    grid = [["mesh", "scale", "texture", *methods]]
    for mesh, scale in dict.fromkeys((r["mesh"], r["scale"]) for r in rows):
        first = cell[mesh, scale, methods[0]]
        size = "x".join(map(str, first["texture_size"]))
        grid.append(
            [
                mesh,
                f"x{scale}",
                size,
                *(_value("psnr_fg", cell[mesh, scale, m]["psnr_fg"]) for m in methods),
            ]
        )
    return grid


def format_text(grid: Sequence[Sequence[str]]) -> str:
    """A grid as aligned plain text (first column left-aligned, the rest right-aligned)."""
    widths = [max(len(row[c]) for row in grid) for c in range(len(grid[0]))]
    lines = []
    for row in grid:
        rest = [value.rjust(width) for value, width in zip(row[1:], widths[1:], strict=True)]
        cells = [row[0].ljust(widths[0]), *rest]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


def format_markdown(grid: Sequence[Sequence[str]], text_columns: int = 1) -> str:
    """A grid as a GitHub Markdown table; columns after ``text_columns`` right-aligned."""
    align = ["---"] * text_columns + ["---:"] * (len(grid[0]) - text_columns)
    lines = [grid[0], align, *grid[1:]]
    return "\n".join("| " + " | ".join(row) + " |" for row in lines)


def _set_name(distance: float) -> str:
    names = {2.4: "validation set Q", 1.5: "near set", 4.0: "far set"}
    return names.get(distance, "custom set")


def markdown_report(result: BenchResult, command_line: str, device: str) -> str:
    """``results.md``: the command, protocol and device, then the tables per distance."""
    summary = summarize(result.rows)
    views = result.rows[0]["views"] if result.rows else 0
    lines = [
        f"`{command_line}`",
        "",
        f"protocol: {result.protocol}  ",
        f"device: {device}  ",
        f"meshes: {len(result.meshes)} evaluated, {len(result.failed)} skipped; "
        f"{plural(views, 'view')} per set; wall time {result.seconds:.0f} s",
    ]
    for _, message in result.failed:
        lines.append(f"- skipped: {message}")
    for distance in dict.fromkeys(r["distance"] for r in result.rows):
        lines += [
            "",
            f"Mean over {plural(len(result.meshes), 'mesh')}, distance {distance:g} "
            f"({_set_name(distance)}):",
            "",
            format_markdown(paper_table(summary, distance), text_columns=2),
            "",
            f"PSNR-fg (dB) per mesh, distance {distance:g}:",
            "",
            format_markdown(per_mesh_table(result.rows, distance), text_columns=3),
        ]
    return "\n".join(lines) + "\n"


CSV_COLUMNS = [
    "mesh",
    "path",
    *(k for k in ROW_KEYS if k != "texture_size"),
    "texture_width",
    "texture_height",
]


def csv_text(rows: Sequence[dict[str, Any]]) -> str:
    """``results.csv``: one line per (mesh, distance, scale, method); infinities as ``inf``."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        width, height = row["texture_size"]
        flat = {key: row[key] for key in CSV_COLUMNS if key in row}
        writer.writerow({**flat, "texture_width": width, "texture_height": height})
    return buffer.getvalue()


def results_document(result: BenchResult, command_line: str, device: str) -> dict[str, Any]:
    """``results.json`` (and ``--json``): strict JSON, infinities written as null."""
    return json_safe(
        {
            "protocol": result.protocol,
            "command": command_line,
            "device": device,
            "seconds": result.seconds,
            "texture_memory": MEMORY_NOTE,
            "meshes": [{"name": m.name, "path": str(m.path)} for m in result.meshes],
            "failed": [{"path": p, "error": e} for p, e in result.failed],
            "results": result.rows,
            "summary": summarize(result.rows),
        }
    )


def plot_name(distance: float, distances: Sequence[float]) -> str:
    """File name of the trade-off plot for ``distance``."""
    return "tradeoff.png" if len(distances) == 1 else f"tradeoff_d{distance:g}.png"


def tradeoff_picture(result: BenchResult, distance: float) -> np.ndarray:
    """Mean PSNR-fg against mean texture memory, one line per method across scales."""
    from geoscaler.report.figures import tradeoff_plot

    series: dict[str, list[tuple[float, float, str]]] = {}
    for s in summarize(result.rows):
        if s["distance"] == distance:
            point = (s["texture_bytes"], s["psnr_fg"], f"x{s['scale']}")
            series.setdefault(s["method"], []).append(point)
    return tradeoff_plot(
        series,
        title=f"Quality against texture memory: mean over {plural(len(result.meshes), 'mesh')}, "
        f"distance {distance:g}, protocol {result.protocol}",
        x_label="texture memory per mesh, mean (uncompressed RGBA8, 4 bytes/texel, no mips)",
        y_label="PSNR-fg (dB)",
    )


def command_line(args: Any) -> str:
    """The canonical ``geoscaler bench`` command line that reproduces ``args``."""
    parts = ["geoscaler", "bench", *args.paths, "--scale", *map(str, args.scale)]
    if args.methods:
        parts += ["--methods", args.methods]
    for flag in ("variant", "preset", "vgg19"):
        if getattr(args, flag, None) is not None:
            parts += [f"--{flag}", getattr(args, flag)]
    if list(args.distance) != [VALIDATION_DISTANCE]:
        parts += ["--distance", *(f"{d:g}" for d in args.distance)]
    optional = {
        "protocol": (getattr(args, "protocol", None), (None, 1)),
        "device": (args.device, ("auto",)),
        "seed": (args.seed, (0,)),
        "steps": (args.steps, (None,)),
    }
    for flag, (value, defaults) in optional.items():
        if value not in defaults:
            parts += [f"--{flag}", str(value)]
    if args.time_budget is not None:
        parts += ["--time-budget", f"{args.time_budget:g}"]
    if args.out:
        parts += ["--out", args.out]
    return shlex.join(parts)


def command(args: Any) -> None:
    """``geoscaler bench``: run, print the tables (or JSON), write the files under --out."""
    from geoscaler.io import save_png, write_atomically

    scales, methods, distances, options = comparison_settings(args)
    meshes = find_meshes(args.paths)
    names = [*OUTPUT_FILES, *(plot_name(d, distances) for d in distances)]
    if args.out:
        prepare_out_dir(args.out, names, args.force, [m.path for m in meshes])
    protocol = 1 if args.protocol is None else check_protocol(args.protocol)
    result = bench_meshes(
        meshes, scales, methods, distances, options, args.evaluation, protocol=protocol
    )
    if not result.rows:
        raise GeoscalerError(f"none of the {len(meshes)} meshes could be evaluated (reasons above)")
    line = command_line(args)
    device = describe_device(result.device)
    document = results_document(result, line, device)
    if args.json:
        print(dumps(document))
    else:
        _print_tables(result, device)
    if args.out:
        out = Path(args.out)
        texts = {
            "results.csv": csv_text(result.rows),
            "results.json": dumps(document) + "\n",
            "results.md": markdown_report(result, line, device),
        }
        for name, text in texts.items():
            write_atomically(out / name, lambda tmp, text=text: tmp.write_text(text, "utf-8"))
        for distance in distances:
            save_png(out / plot_name(distance, distances), tradeoff_picture(result, distance))
        where = sys.stderr if args.json else sys.stdout
        print(f"wrote {', '.join(names)} into {out}", file=where)


def _print_tables(result: BenchResult, device: str) -> None:
    """The console report: paper-style means, then per-mesh PSNR-fg, per distance."""
    summary = summarize(result.rows)
    print(
        f"protocol {result.protocol}   device {device}   {plural(len(result.meshes), 'mesh')} "
        f"({len(result.failed)} skipped)   {result.seconds:.0f} s"
    )
    for distance in dict.fromkeys(r["distance"] for r in result.rows):
        print(
            f"\nmean over {plural(len(result.meshes), 'mesh')}, distance {distance:g} "
            f"({_set_name(distance)})"
        )
        print(format_text(paper_table(summary, distance)))
        print(f"\nPSNR-fg (dB) per mesh, distance {distance:g}")
        print(format_text(per_mesh_table(result.rows, distance)))
