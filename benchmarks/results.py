"""The results tables, re-made by one command (`make results`): the development set at 4x and 8x.

For every development mesh (each folder of the shared data whose ``meta.json`` names an
``"entry"``) this runs two commands, as a user runs them, and reads their JSON:

    geoscaler compare MESH --scale 4 8 --methods bicubic,lanczos,direct --uv keep --protocol 1
        --distance 2.4 1.5 4.0 --time-budget 60 --device DEVICE --json
    geoscaler compare MESH --scale 4 8 --methods bicubic,lanczos,direct --uv auto  (the same)

so that bicubic, Lanczos, `direct` on the mesh's own UVs and `direct --uv auto` are scored the
way `geoscaler compare` and `geoscaler bench` score them (protocol 1: every view of Q, near and
far, references capped at 2048, each learned method under the same budget, what shipped after
the job's validation). It then writes one JSON per table (one per scale) into ``--out``, each
with a header (commit, date, machine, load, command, wall time), and renders the Markdown page
from those JSON files only; with the default ``--markdown`` it also fills the README's summary
between ``<!-- results:start -->`` and ``<!-- results:end -->``.

Usage:
    python benchmarks/results.py [--alone] [--device auto] [--budget 60]
        [--scale 4 8] [--meshes NAME ...] [--data DIR] [--out DIR] [--markdown FILE]
    python benchmarks/results.py --quick [--out DIR]     # the pipeline's check, about a minute
    python benchmarks/results.py --render-only [--out DIR] [--markdown FILE]

Default ``--out`` docs/results and ``--markdown`` docs/results.md. ``--quick``: spot and
ph_wooden_table_02 at 4x, a 10 s budget, 6 views of each set at 128 pixels (not protocol
figures, and the page says so), written into a new temporary folder unless ``--out`` is given;
its Markdown goes to ``OUT/results.md``. ``--alone``: you assert that nothing else ran on the
machine meanwhile (the header records it beside the load averages it measured).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import math
import os
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
OUT = ROOT / "docs" / "results"
MARKDOWN = ROOT / "docs" / "results.md"
README = ROOT / "README.md"

SETS = {"Q": 2.4, "near": 1.5, "far": 4.0}
"""The protocol's view sets and their distances, in the order tables show them."""
METHODS = ("bicubic", "lanczos", "direct", "direct --uv auto")
"""Table columns: the row key ``method`` of every row."""
JOBS = {
    "keep": ("bicubic,lanczos,direct", "direct"),
    "auto": ("bicubic,lanczos,direct", "direct --uv auto"),
}
"""``--uv`` mode -> (``--methods`` of its command, the name its ``direct`` rows get). Both
commands run both filters: they are the floor the learned method's validation must clear, as
in `geoscaler downsample`."""

PROTOCOL = 1
"""Every row is protocol 1, the unlit base colour (PBR meshes included: `compare` scores them
lit, protocol 2, unless told): the paper's measure, comparable across the whole set. The lit
figures of the PBR meshes are in docs/protocol.md."""

QUICK_MESHES = ("spot", "ph_wooden_table_02")
QUICK_VIEWS = (0, 10, 20, 30, 40, 50)
QUICK_IMAGE_SIZE = 128
QUICK_EVALUATION = (
    "import json, sys; from geoscaler.cli import main; from geoscaler.protocol import "
    "Evaluation; quick = json.loads(sys.argv[1]); "
    "sys.exit(main(sys.argv[2:], evaluation=Evaluation.quick(quick['views'], quick['size'])))"
)
"""The command line in-process with a cheaper evaluation (``geoscaler.cli.main``'s
``evaluation``, for callers that are not users): the quick check's fewer, smaller views."""


# --- running ------------------------------------------------------------------------------


def find_meshes(data: Path, names: list[str] | None = None) -> list[tuple[str, Path]]:
    """``(folder name, entry file)`` of every mesh folder under ``data`` (``names``: only
    those), sorted by name."""
    found = []
    for meta in sorted(data.glob("*/meta.json")):
        name = meta.parent.name
        if names is None or name in names:
            found.append((name, meta.parent / json.loads(meta.read_text())["entry"]))
    missing = sorted(set(names or []) - {name for name, _ in found})
    if missing:
        raise SystemExit(f"no such meshes in {data}: {', '.join(missing)}")
    return found


def compare_command(mesh: Path, uv: str, args: argparse.Namespace) -> list[str]:
    """The `geoscaler compare` command of one mesh and ``--uv`` mode."""
    if args.quick:
        quick = json.dumps({"views": list(QUICK_VIEWS), "size": QUICK_IMAGE_SIZE})
        head = [sys.executable, "-c", QUICK_EVALUATION, quick]
    else:
        head = [sys.executable, "-m", "geoscaler.cli"]
    return [*head, "compare", str(mesh), "--scale", *map(str, args.scale),
            "--methods", JOBS[uv][0], "--uv", uv, "--protocol", str(PROTOCOL),
            "--distance", *(f"{d:g}" for d in SETS.values()),
            "--time-budget", f"{args.budget:g}", "--device", args.device, "--json"]  # fmt: skip


def run_job(name: str, mesh: Path, uv: str, args: argparse.Namespace, logs: Path) -> dict:
    """One command's rows (``method`` renamed for ``--uv auto``) and facts; a failed command
    gives no rows and its error."""
    command = compare_command(mesh, uv, args)
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - started
    (logs / f"{name}_{uv}.log").write_text(done.stderr)
    job = {"mesh": name, "uv": uv, "wall_s": round(wall, 1), "returncode": done.returncode}
    print(f"# {name} --uv {uv}: {wall:.0f} s, exit {done.returncode}", file=sys.stderr)
    if done.returncode != 0:
        job["error"] = done.stderr.strip()[-400:]
        return {"job": job, "rows": [], "device": None, "filters": {}}
    document = json.loads(done.stdout)
    if document.get("protocol") != PROTOCOL:
        job["error"] = f"scored under protocol {document.get('protocol')}, not {PROTOCOL}"
        return {"job": job, "rows": [], "device": None, "filters": {}}
    distances = {d: s for s, d in SETS.items()}
    layouts = {run["scale"]: run.get("layout_used", "keep") for run in document.get("runs", [])
               if run["method"] == "direct"}  # fmt: skip
    rows, filters = [], {}
    for r in document["results"]:
        if r["method"] != "direct":
            filters[r["method"], r["scale"], r["distance"]] = r["psnr_fg"]
        if uv == "auto" and r["method"] != "direct":
            continue  # the filters' rows are the keep command's (the same figures)
        rows.append({
            "mesh": name, "method": JOBS[uv][1] if r["method"] == "direct" else r["method"],
            "scale": r["scale"], "set": distances[r["distance"]], "distance": r["distance"],
            "views": r["views"], "psnr_fg": r["psnr_fg"], "gain_db": r["gain_db"],
            "seconds": round(r["seconds"], 2), "shipped": r["shipped"],
            **({"layout": layouts[r["scale"]]} if r["method"] == "direct" and layouts else {}),
        })  # fmt: skip
    return {"job": job, "rows": rows, "device": document.get("device"), "filters": filters}


def git(*arguments: str) -> str:
    """The output of a git command in the repository ("" where it fails)."""
    done = subprocess.run(["git", *arguments], capture_output=True, text=True, cwd=ROOT)
    return done.stdout if done.returncode == 0 else ""


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def header_start(args: argparse.Namespace, argv: list[str]) -> dict:
    """What the header knows before the run: commit, date, machine, load, command."""
    dirty = [line[3:] for line in git("status", "--porcelain").splitlines() if line.strip()]
    try:
        torch = importlib.metadata.version("torch")
    except importlib.metadata.PackageNotFoundError:
        torch = "absent"
    command = shlex.join(["benchmarks/results.py", *argv])
    return {
        "commit": git("rev-parse", "--short", "HEAD").strip(),
        "dirty": bool(dirty),
        "dirty_paths": dirty,
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": {
            "cores": os.cpu_count(),
            "cpu": cpu_model(),
            "device": args.device,
            "torch": torch,
        },  # fmt: skip
        "alone": {"asserted": args.alone, "load_start": load_average(), "load_end": None},
        "command": command,
        "wall_s": None,
        "budget_s": args.budget,
        "evaluation": (
            f"quick: views {', '.join(map(str, QUICK_VIEWS))} of each set at "
            f"{QUICK_IMAGE_SIZE} px (not protocol figures)"
            if args.quick
            else "protocol 1: all 60 views of each set at 512 px"
        ),
        "sets": SETS,
        "methods": list(METHODS),
    }


def run_all(args: argparse.Namespace, argv: list[str]) -> list[Path]:
    """Run every command, write one JSON per scale into ``args.out``; their paths. After each
    mesh the tables so far go into the logs folder (``partial_x<scale>.json``; each command's
    stderr is there too), so that an interrupted run keeps what it measured."""
    started = time.perf_counter()
    header = header_start(args, argv)
    meshes = find_meshes(args.data, list(QUICK_MESHES) if args.quick else args.meshes)
    if not meshes:
        raise SystemExit(f"no mesh folders (with a meta.json) in {args.data}")
    if args.quick:  # its own folder is a temporary one: the logs go beside its tables
        logs = args.out / "logs"
        logs.mkdir(parents=True, exist_ok=True)
    else:
        logs = Path(tempfile.mkdtemp(prefix="geoscaler_results_logs_"))
    print(f"# {len(meshes)} meshes, logs in {logs}", file=sys.stderr)
    rows, jobs, devices = [], [], set()
    for number, (name, mesh) in enumerate(meshes, 1):
        filters = []
        for uv in JOBS:
            result = run_job(name, mesh, uv, args, logs)
            rows += result["rows"]
            jobs.append(result["job"])
            devices.add(result["device"])
            filters.append(result["filters"])
        shared = set(filters[0]) & set(filters[1])  # the filters are deterministic: a check
        if shared:
            differ = max(abs(filters[0][k] - filters[1][k]) for k in shared)
            jobs[-1]["filters_differ_db"] = round(differ, 6)
        header["wall_s"] = round(time.perf_counter() - started, 1)
        header["alone"]["load_end"] = load_average()
        header["machine"]["device"] = ", ".join(sorted(d for d in devices if d)) or args.device
        done = [entry for entry, _ in meshes[:number]]
        last = number == len(meshes)
        written = write_tables(args.out if last else logs, header, done, rows, jobs, args.scale,
                               "" if last else "partial_")  # fmt: skip
    return written


def write_tables(
    out: Path, header: dict, meshes: list[str], rows: list, jobs: list, scales: list, prefix=""
) -> list[Path]:
    """One JSON table per scale, ``out/<prefix>x<scale>.json``; their paths."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for scale in scales:
        document = {
            "table": f"x{scale}",
            "header": {**header, "scale": scale},
            "meshes": meshes,
            "rows": [r for r in rows if r["scale"] == scale],
            "jobs": jobs,
        }
        path = out / f"{prefix}x{scale}.json"
        path.write_text(json.dumps(document, indent=1, allow_nan=False) + "\n")
        written.append(path)
    return written


# --- rendering (from the JSON files only) ----------------------------------------------------


def _cell(row: dict | None) -> str:
    """A method's cell: gain over bicubic (its PSNR-fg), and what shipped where the job's
    validation shipped a filter in its place, or where it shipped in new UVs (a ``layout``
    other than the mesh's own, which rows from documents without ``runs`` do not say)."""
    if row is None:
        return "-"
    if row["method"] == "bicubic":
        return f"{row['psnr_fg']:.2f}"
    cell = f"{row['gain_db']:+.2f} ({row['psnr_fg']:.2f})"
    learned = row["method"].split()[0]
    if row["shipped"] not in (row["method"], learned):
        return f"{cell}, {row['shipped']}"
    return cell if row.get("layout", "keep") == "keep" else f"{cell}, new UVs"


def _summary_cells(rows: list[dict | None]) -> tuple[str, str]:
    """The mean and the worst mesh of one column: gains for methods, PSNR-fg for bicubic."""
    present = [r for r in rows if r is not None]
    if not present:
        return "-", "-"
    key = "psnr_fg" if present[0]["method"] == "bicubic" else "gain_db"
    sign = "" if key == "psnr_fg" else "+"
    mean = statistics.fmean(r[key] for r in present)
    worst = min(present, key=lambda r: r[key])
    count = "" if len(present) == len(rows) else f" (of {len(present)})"
    mean_cell = f"{mean:{sign}.2f}{count}"
    if key == "gain_db":
        mean_cell += f" ({statistics.fmean(r['psnr_fg'] for r in present):.2f})"
    return mean_cell, f"{worst[key]:{sign}.2f} ({worst['mesh']})"


def header_lines(header: dict, jobs: list[dict]) -> list[str]:
    """The facts a table stands on, as a Markdown list."""
    machine, alone = header["machine"], header["alone"]
    paths = len(header["dirty_paths"])
    dirty = f", working tree dirty ({paths} path{'s' * (paths != 1)})" if header["dirty"] else ""
    asserted = "yes (`--alone`)" if alone["asserted"] else "not asserted"
    end = "?" if alone["load_end"] is None else f"{alone['load_end'][0]:g}"
    lines = [
        f"- commit: `{header['commit']}`{dirty}; date: {header['date']}",
        f"- machine: {machine['cores']} cores, {machine['cpu']}; device: {machine['device']}; "
        f"torch {machine['torch']}",
        f"- ran alone: {asserted}; 1-minute load average {alone['load_start'][0]:g} at the "
        f"start, {end} at the end",
        f"- command: `{header['command']}`; wall time {header['wall_s']:.0f} s for the whole run",
        f"- learned methods: {header['budget_s']:g} s budget per mesh and command; evaluation: "
        f"{header['evaluation']}",
    ]
    failed = [j for j in jobs if j["returncode"] != 0]
    if failed:
        lines.append("- failed: " + "; ".join(
            f"{j['mesh']} (`--uv {j['uv']}`, exit {j['returncode']})" for j in failed))  # fmt: skip
    return lines


def render_table(document: dict) -> list[str]:
    """One scale's section: the header facts, then a table per view set with a mean and a
    worst row per column."""
    header, methods = document["header"], document["header"]["methods"]
    lines = [f"## {document['header']['scale']}x", "", *header_lines(header, document["jobs"])]
    index = {(r["mesh"], r["method"], r["set"]): r for r in document["rows"]}
    for name, distance in header["sets"].items():
        if not any(r["set"] == name for r in document["rows"]):
            continue
        titles = ["bicubic PSNR-fg" if m == "bicubic" else m for m in methods]
        lines += [
            "",
            f"### {name} (distance {distance:g})",
            "",
            "| mesh | " + " | ".join(titles) + " |",
            "| --- |" + " ---: |" * len(methods),
        ]
        columns = {m: [index.get((mesh, m, name)) for mesh in document["meshes"]] for m in methods}
        for i, mesh in enumerate(document["meshes"]):
            lines.append(f"| {mesh} | " + " | ".join(_cell(columns[m][i]) for m in methods) + " |")
        summaries = [_summary_cells(columns[m]) for m in methods]
        count = len(document["meshes"])
        lines.append(f"| **mean of {count}** | " + " | ".join(s[0] for s in summaries) + " |")
        lines.append("| **worst** | " + " | ".join(s[1] for s in summaries) + " |")
    return lines


INTRODUCTION = """\
Generated by `make results` (`benchmarks/results.py`) from the JSON files in {where};
re-render with `python benchmarks/results.py --render-only`. Do not edit by hand.

Every figure is measured by `geoscaler compare` ([protocol 1](protocol.md)): the mesh's renders
with the original base colour against renders with the candidate, PSNR-fg in dB on the view sets
Q (distance 2.4), near (1.5) and far (4.0). A method's cell is its gain over bicubic on the same
mesh, scale and set, with its PSNR-fg in brackets; `direct` keeps the mesh's UVs and
`direct --uv auto` races the mesh's layout against a repacked one ([method](method.md)). Where
the job's validation shipped a filter instead of the learned texture, the cell names it; where
the learned texture shipped in a new UV layout, the cell says "new UVs". The
mean row averages the meshes; the worst row names the mesh with the lowest value of the column."""


def render_markdown(documents: list[dict], where: str = "`results/`") -> str:
    """The results page from the tables' JSON documents (sorted by scale)."""
    lines = ["# Results", "", INTRODUCTION.format(where=where)]
    if any(not d["header"]["evaluation"].startswith("protocol") for d in documents):
        lines += ["", "**A quick check: fewer and smaller views than the protocol's; these "
                  "figures are not protocol figures.**"]  # fmt: skip
    for document in sorted(documents, key=lambda d: d["header"]["scale"]):
        lines += ["", *render_table(document)]
    return "\n".join(lines) + "\n"


def render_summary(documents: list[dict], page: str = "docs/results.md") -> str:
    """The README's summary: per scale and view set, the mean over the meshes (bicubic's
    PSNR-fg, each method's gain over it) and the worst mesh of each method, and the facts
    the tables stand on."""
    documents = sorted(documents, key=lambda d: d["header"]["scale"])
    header, methods = documents[0]["header"], documents[0]["header"]["methods"]
    learned = [m for m in methods if m != "bicubic"]
    lines = [
        "| scale | set | bicubic PSNR-fg | " + " | ".join(learned) + " |",
        "| --- | --- |" + " ---: |" * (1 + len(learned)),
    ]
    for document in documents:
        index = {(r["mesh"], r["method"], r["set"]): r for r in document["rows"]}
        for name in document["header"]["sets"]:
            column = {
                m: [index.get((mesh, m, name)) for mesh in document["meshes"]] for m in methods
            }
            if not any(column["bicubic"]):
                continue
            cells = [_summary_cells(column["bicubic"])[0]]
            for method in learned:
                present = [r for r in column[method] if r is not None]
                if not present:
                    cells.append("-")
                    continue
                worst = min(present, key=lambda r: r["gain_db"])
                mean = statistics.fmean(r["gain_db"] for r in present)
                cells.append(f"{mean:+.2f} (worst {worst['gain_db']:+.2f}, {worst['mesh']})")
            scale = document["header"]["scale"]
            lines.append(f"| {scale}x | {name} | " + " | ".join(cells) + " |")
    alone = "run alone (`--alone`)" if header["alone"]["asserted"] else "not said to run alone"
    lines += [
        "",
        f"Mean gain over bicubic in dB on {len(documents[0]['meshes'])} development meshes, the "
        f"worst mesh in brackets; {header['budget_s']:g} s per learned job. Commit "
        f"`{header['commit']}`{' (dirty tree)' if header['dirty'] else ''}, {header['date'][:10]}, "
        f"{header['machine']['cores']} cores, {header['machine']['device']}, {alone} (load "
        f"{header['alone']['load_start'][0]:g} at the start). Every mesh, with PSNR-fg: "
        f"[{page}]({page}).{_new_uvs(documents)}",
    ]
    return "\n".join(lines)


def _new_uvs(documents: list[dict]) -> str:
    """The summary's sentence on where a learned method shipped new UVs, per scale (empty
    where the rows do not say: tables from documents without ``runs``)."""
    parts = []
    for document in documents:
        rows = [r for r in document["rows"] if r["set"] == "Q" and "layout" in r]
        if rows:
            moved = [r["mesh"] for r in rows if r["layout"] != "keep"]
            parts.append(f"{document['header']['scale']}x {', '.join(moved) or 'none'}")
    return f" New UVs shipped on: {'; '.join(parts)}." if parts else ""


MARKERS = ("<!-- results:start -->", "<!-- results:end -->")
"""Where the README's generated summary goes."""


def fill_markers(text: str, summary: str) -> str:
    """``text`` with what lies between :data:`MARKERS` replaced by ``summary``."""
    start, end = text.index(MARKERS[0]) + len(MARKERS[0]), text.index(MARKERS[1])
    return text[:start] + "\n" + summary + "\n" + text[end:]


def render(out: Path, markdown: Path, readme: Path | None = None) -> Path:
    paths = sorted(out.glob("x*.json"))
    if not paths:
        raise SystemExit(f"no tables (x*.json) in {out}: run without --render-only first")
    documents = [json.loads(p.read_text()) for p in paths]
    for document in documents:
        check_finite(document)
    try:
        folder = out.resolve().relative_to(markdown.resolve().parent)
        where = "this page's folder" if folder == Path() else f"`{folder}/`"
    except ValueError:
        where = f"`{out}`"
    markdown.write_text(render_markdown(documents, where))
    text = readme.read_text() if readme is not None and readme.is_file() else ""
    if all(marker in text for marker in MARKERS):
        page = markdown.resolve().relative_to(readme.resolve().parent).as_posix()
        readme.write_text(fill_markers(text, render_summary(documents, page)))
        print(f"wrote the summary into {readme}", file=sys.stderr)
    return markdown


def check_finite(document: dict) -> None:
    """Refuse to render a table with a NaN or infinite figure."""
    bad = [r for r in document["rows"] if not all(map(math.isfinite, (r["psnr_fg"], r["gain_db"])))]
    if bad:
        raise SystemExit(f"{document['table']}: figures not finite: {bad[:3]}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the pipeline's check (see above)")
    parser.add_argument("--render-only", action="store_true", help="only re-render the page")
    parser.add_argument("--alone", action="store_true", help="assert nothing else ran meanwhile")
    parser.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    parser.add_argument("--budget", type=float, help="seconds per learned job (60; quick 10)")
    parser.add_argument("--scale", type=int, nargs="+", help="scales (4 8; quick 4)")
    parser.add_argument("--meshes", nargs="+", help="mesh folder names (default: all)")
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--out", type=Path, help="folder of the JSON tables")
    parser.add_argument("--markdown", type=Path, help="the page (default: OUT/results.md, or "
                        "docs/results.md with the default --out)")  # fmt: skip
    args = parser.parse_args(argv)
    args.budget = args.budget or (10.0 if args.quick else 60.0)
    args.scale = args.scale or ([4] if args.quick else [4, 8])
    if args.out is None:
        quick = args.quick and not args.render_only
        args.out = Path(tempfile.mkdtemp(prefix="geoscaler_results_")) if quick else OUT
    if args.markdown is None:
        args.markdown = MARKDOWN if args.out.resolve() == OUT else args.out / "results.md"
    if not args.render_only:
        if not args.data.is_dir():
            print(f"no meshes at {args.data}: skipped", file=sys.stderr)
            return 0
        for path in run_all(args, argv):
            print(f"wrote {path}", file=sys.stderr)
    readme = README if args.markdown.resolve() == MARKDOWN else None  # the project's own page
    print(f"wrote {render(args.out, args.markdown, readme)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
