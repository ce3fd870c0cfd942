"""Where the seconds of one whole ``geoscaler downsample`` go, per mesh.

For every mesh (and ``--uv`` mode) this runs ``geoscaler downsample MESH --scale S --uv U
--time-budget B -o OUT.glb --report R.json`` in a new process, as a user runs it (the budget
counts from that process's start), with nothing in the library changed: the child process
(this file with ``--child``) wraps, from outside, the library functions that mark the job's
phases with a timer as their modules are imported, and times every first import of a module
(the same figures as ``python -X importtime``: a package's time includes what it imports first).
Each timed call is recorded with its parent, so that a phase's own time excludes the timed
phases and imports inside it; the rows of the table add up to the wall time ("untimed" is the
glue between the timed calls).

Caching is split by kind (the training pool, the validation sets, the layout planning, the
report's scoring: the innermost of these around the call) and by piece: the G-buffer
(``Renderer.rasterize``), the reference render (``Renderer.render_reference``), the foreground
mask, and the taps (``ViewCache.find_taps``: tap matrices, the reference gathered at the
object's pixels). Each row has two figures: the seconds before the first optimisation step
starts, and over the whole run.

The wrappers cost a few microseconds a call (a few thousand calls a run); cProfile would cost
more and change how many steps a budgeted run takes.

Usage:
    python benchmarks/profile.py [MESH[:UV] ...] [--scale 4] [--budget 25] [--out DIR]
        [--markdown FILE]

MESH: a mesh file, or a folder of ../shared/data (its meta.json names the entry); ``:auto``,
``:repack`` or ``:keep`` (default) after it is the ``--uv`` mode. Default: spot, ph_sofa_03,
ycb_chain, ycb_mug_ig with ``--uv keep`` and ycb_chain with ``--uv auto``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
DEFAULT_MESHES = ["spot", "ph_sofa_03", "ycb_chain", "ycb_mug_ig", "ycb_chain:auto"]
HEAVY = [
    "numpy",
    "torch",
    "PIL.Image",
    "scipy.sparse",
    "scipy.special",
    "scipy.ndimage",
    "trimesh",
    "xatlas",
    "tqdm",
]

# --------------------------------------------------------------------------- what is timed

VIEW = "view"  # a piece of a cached view: its row is named by the kind around it
KIND = "kind"  # marks the kind of the views cached inside it

FIRST_STEP = {"taken": False}


def _step_label(loop, *_args, **_kwargs) -> str:
    if FIRST_STEP["taken"]:
        return "optimisation steps 2.."
    FIRST_STEP["taken"] = True
    return "optimisation step 1"


def _method_label(mesh, rule, name, *_args, **_kwargs) -> str:
    return f"method {name} (own time)"


# module -> qualified name -> row label, (VIEW, piece) or (KIND, kind)
TARGETS: dict[str, dict[str, object]] = {
    "geoscaler.cli": {"cmd_downsample": "cli: the command's glue"},
    "geoscaler.io.load": {"load_mesh": "load mesh"},
    "geoscaler.pipeline.downsampling": {
        "prepare": "prepare: checks (load excluded)",
        "run_job": "job glue",
        "export": "export: glue",
    },
    "geoscaler.pipeline.job": {
        "_MethodRuns.__init__": "job set-up",
        "_run": _method_label,
        "learned_fits": "learned_fits (prices a view)",
        "no_worse_than_filters": "ship choice",
        "_cache_for_rows": (KIND, "report scoring"),
    },
    "geoscaler.pipeline.rows": {"validation_row": "report scoring (rows)"},
    "geoscaler.pipeline.shipping": {
        "ship_asset": "export: maps as they ship",
        "relayout_maps": "export: other maps relaid",
    },
    "geoscaler.io.save": {"save_mesh": "export: write files"},
    "geoscaler.report.runner": {"downsample_and_report": "report glue"},
    "geoscaler.report.documents": {
        "report_document": "report document",
        "format_report": "report document",
    },
    "geoscaler.resize.filters": {"reference_textures": "reference maps (original reduced)"},
    "geoscaler.render.renderer": {
        "Renderer.__init__": "renderer set-up",
        "Renderer.reference_textures": "reference textures (mip chains)",
        "Renderer.relaid": "layout: relaid renderer",
        "Renderer.rasterize": (VIEW, "G-buffer"),
        "Renderer.render_reference": (VIEW, "reference render"),
        "Renderer.foreground": (VIEW, "foreground"),
    },
    "geoscaler.render.views": {
        "ViewSet.cache_next": (VIEW, "other"),
        "ViewCache.find_taps": (VIEW, "taps"),
        "ViewCache._taps": (VIEW, "taps"),
    },
    "geoscaler.optim.validation_views": {
        "validation_view_sets": "validation cameras",
        "ValidationViews.cache_view": (KIND, "validation sets"),
        "ValidationViews.freeze": (KIND, "validation sets"),
        "ValidationViews.find_taps": (KIND, "validation sets"),
    },
    "geoscaler.optim.validation": {
        "Validation.cache_next": (KIND, "validation sets"),
        "Validation.psnr": "validations: renders + metrics",
        "Validation.baseline_scores": "validations: the filters' scores",
    },
    "geoscaler.optim.loop": {
        "optimize": "loop glue",
        "TrainingLoop.run": "loop glue",
        "_Caching._cache_pool_view": (KIND, "training pool"),
        "_Caching.after_step": "loop glue",
        "_Caching.close": "loop glue",
        "TrainingLoop._step": _step_label,
        "TrainingLoop.reachable": "reachable texels (gutters)",
        "finished_candidate": "validations: gutters filled",
        "validate": "validations: renders + metrics",
    },
    "geoscaler.methods.direct": {
        "direct": "method glue",
        "lanczos_starts": "direct: Lanczos start",
    },
    "geoscaler.methods.repacked": {
        "repacked_direct": "method glue",
        "raced": "race glue",
        "_timely_layouts": "layout: planning",
        "plan_layout": (KIND, "layout planning"),
        "PlanningViews.render_by": (KIND, "layout planning"),
        "baked_maps": "layout: bake",
        "_new_layout": "layout: set-up",
        "_Trials.run": "race glue",
        "LayoutValidation.cache_next": (KIND, "validation sets"),
    },
    "geoscaler.uv.atlas": {"repack": "layout: repack (charts, scales)"},
    "geoscaler.uv.packing": {"pack": "layout: xatlas packing"},
    "geoscaler.uv.bake": {"bake": "layout: bake"},
}


class Recorder:
    """Timed calls on the main thread: ``[qualname, label, parent, start, end]`` each."""

    def __init__(self) -> None:
        self.events: list[list] = []
        self.stack: list[int] = []
        self.main = threading.get_ident()

    def call(self, qualname: str, label: object, fn, args, kwargs):
        if threading.get_ident() != self.main:
            return fn(*args, **kwargs)
        index = len(self.events)
        event = [qualname, label, self.stack[-1] if self.stack else -1, time.perf_counter(), None]
        self.events.append(event)
        self.stack.append(index)
        try:
            return fn(*args, **kwargs)
        finally:
            event[4] = time.perf_counter()
            self.stack.pop()


RECORDER = Recorder()


def _wrapped(qualname: str, spec: object, fn):
    @functools.wraps(fn)
    def timed(*args, **kwargs):
        label = spec(*args, **kwargs) if callable(spec) else spec
        return RECORDER.call(qualname, label, fn, args, kwargs)

    return timed


def _patch(module) -> None:
    for qualname, spec in TARGETS.get(module.__name__, {}).items():
        owner, _, name = qualname.rpartition(".")
        holder = getattr(module, owner) if owner else module
        setattr(holder, name, _wrapped(qualname, spec, getattr(holder, name)))


def install_hooks() -> None:
    """Time every first import (``importlib._bootstrap._find_and_load``, which the import
    statement looks up at each call) and wrap the targets of a module as it is imported,
    before any other module binds their names."""
    import importlib._bootstrap as bootstrap

    find_and_load = bootstrap._find_and_load

    def timed_find_and_load(name, import_):
        module = RECORDER.call("import", name, find_and_load, (name, import_), {})
        if name in TARGETS:
            _patch(module)
        return module

    bootstrap._find_and_load = timed_find_and_load


def process_start() -> float:
    """This process's start on ``time.perf_counter``'s scale (Linux /proc, to 10 ms)."""
    ticks = os.sysconf("SC_CLK_TCK")
    fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
    uptime = float(Path("/proc/uptime").read_text().split()[0])
    return time.perf_counter() - max(uptime - int(fields[19]) / ticks, 0.0)


def child(events_path: str, command: list[str]) -> int:
    """Run the command as ``geoscaler`` would, recording; write the events."""
    started, script = process_start(), time.perf_counter()
    install_hooks()
    sys.argv = ["geoscaler", *command]
    from geoscaler.cli import main

    called = time.perf_counter()
    status = main()  # argv None: the budget counts from this process's start
    ended = time.perf_counter()
    document = {"process_start": started, "script_start": script, "main_called": called,
                "main_returned": ended, "status": status, "events": RECORDER.events}  # fmt: skip
    Path(events_path).write_text(json.dumps(document))
    return status


# ------------------------------------------------------------------------------ analysis


def _children(events: list[list]) -> list[list[int]]:
    children: list[list[int]] = [[] for _ in events]
    for index, event in enumerate(events):
        if event[2] >= 0:
            children[event[2]].append(index)
    return children


def _overlap(event: list, window: tuple[float, float]) -> float:
    return max(0.0, min(event[4], window[1]) - max(event[3], window[0]))


def _kind_of(events: list[list], index: int) -> str:
    parent = events[index][2]
    while parent >= 0:
        label = events[parent][1]
        if isinstance(label, list) and label[0] == KIND:
            return label[1]
        parent = events[parent][2]
    return "other"


def _row(events: list[list], index: int) -> str:
    qualname, label = events[index][:2]
    if qualname == "import":
        if label.startswith("geoscaler"):
            return "imports: geoscaler's own modules"
        return "imports: third-party packages"
    if isinstance(label, list):
        kind = label[1] if label[0] == KIND else _kind_of(events, index)
        piece = "glue" if label[0] == KIND else label[1]
        return f"caching, {kind}: {piece}"
    return label


def attribute(document: dict, window_end: float) -> dict[str, float]:
    """Seconds per row in [process start, ``window_end``]: each timed call's own time (its
    timed children excluded), the interpreter's start, and the untimed rest."""
    events = document["events"]
    for event in events:
        if event[4] is None:  # still open (an exception): ends with the command
            event[4] = document["main_returned"]
    window = (document["process_start"], window_end)
    children = _children(events)
    rows: dict[str, float] = {}
    rows["interpreter start"] = max(0.0, min(document["script_start"], window_end) - window[0])
    timed = 0.0
    for index, event in enumerate(events):
        own = _overlap(event, window) - sum(_overlap(events[c], window) for c in children[index])
        row = _row(events, index)
        rows[row] = rows.get(row, 0.0) + own
        if event[2] < 0:
            timed += _overlap(event, window)
    span = window[1] - window[0]
    rows["untimed (glue between timed calls)"] = span - timed - rows["interpreter start"]
    return rows


def view_seconds(whole: dict[str, float]) -> dict[str, dict[str, float]]:
    """Per kind: seconds per piece of caching (G-buffer, reference render, taps, ...)."""
    found: dict[str, dict[str, float]] = {}
    for row, seconds in whole.items():
        if row.startswith("caching, "):
            kind, piece = row[len("caching, ") :].split(": ", 1)
            found.setdefault(kind, {})[piece] = seconds
    return found


def view_counts(document: dict) -> dict[str, dict[str, int]]:
    """Per kind: G-buffers rasterised, reference renders, tap matrices built."""
    events, counts = document["events"], {}
    names = {"Renderer.rasterize": "G-buffers", "Renderer.render_reference": "references",
             "ViewCache._taps": "taps"}  # fmt: skip
    for index, event in enumerate(events):
        if event[0] in names:
            kind = counts.setdefault(_kind_of(events, index), {})
            kind[names[event[0]]] = kind.get(names[event[0]], 0) + 1
    return counts


def imports(document: dict) -> list[dict]:
    """The first import of each heavy package: seconds (its own first imports included, as
    ``-X importtime``'s cumulative figure), the geoscaler module that imported it and the
    phase that was running."""
    events, found = document["events"], []
    for package in HEAVY:
        for event in events:
            if event[0] == "import" and event[1] == package:
                importer, parent = None, event[2]
                phase = "import of geoscaler.cli"
                if event[3] >= document["main_called"]:
                    phase = "command line parsed"
                via = events[parent][1] if parent >= 0 and events[parent][0] == "import" else ""
                while parent >= 0:
                    qualname, label = events[parent][:2]
                    if qualname == "import" and importer is None and label.startswith("geoscaler"):
                        importer = label
                    if qualname != "import":
                        phase = _row(events, parent)
                        break
                    parent = events[parent][2]
                if importer and via and via != importer:
                    importer = f"{importer} (via {via})"
                found.append({"package": package, "seconds": event[4] - event[3],
                              "importer": importer, "phase": phase})  # fmt: skip
                break
        else:
            found.append({"package": package, "seconds": 0.0, "importer": None, "phase": None})
    return found


def third_party(document: dict, least: float = 0.02) -> list[tuple[str, float, str]]:
    """Every third-party package a geoscaler module (or this process's start) imported first,
    with its cumulative seconds, of ``least`` seconds or more, largest first."""
    events, found = document["events"], []
    for event in events:
        parent = event[2]
        parent_name = events[parent][1] if parent >= 0 and events[parent][0] == "import" else None
        if (event[0] == "import" and "." not in event[1] and not event[1].startswith("geoscaler")
                and (parent_name is None or parent_name.startswith("geoscaler"))
                and event[4] - event[3] >= least):  # fmt: skip
            found.append((event[1], event[4] - event[3], parent_name or "-"))
    return sorted(found, key=lambda item: -item[1])


def first_step_start(document: dict) -> float | None:
    for event in document["events"]:
        if event[1] == "optimisation step 1":
            return event[3]
    return None


def needed(package: str, mesh: Path, uv: str) -> str:
    """Whether the job needs ``package`` for its inputs (by what the library uses it for)."""
    if package == "trimesh":
        return "yes (OBJ geometry)" if mesh.suffix.lower() == ".obj" else "**no** (not an OBJ)"
    if package == "xatlas":
        return "yes (packing)" if uv != "keep" else "**no** (--uv keep never packs)"
    if package == "scipy.ndimage":
        return "yes (bake)" if uv != "keep" else "**no** (only the bake uses it)"
    if package == "tqdm":
        return "progress bar only"
    return "yes"


# ------------------------------------------------------------------------------- running


def mesh_path(spec: str) -> tuple[Path, str]:
    name, _, uv = spec.partition(":")
    path = Path(name)
    if not path.exists() and (DATA / name / "meta.json").exists():
        path = DATA / name / json.loads((DATA / name / "meta.json").read_text())["entry"]
    return path, uv or "keep"


def command_for(mesh: Path, uv: str, scale: int, budget: float, out: Path) -> list[str]:
    stem = f"{mesh.parent.name}_{uv}"
    return ["downsample", str(mesh), "--scale", str(scale), "--uv", uv, "--time-budget",
            str(budget), "-o", str(out / f"{stem}.glb"), "--report", str(out / f"{stem}.json"),
            "--force"]  # fmt: skip


def run_one(mesh: Path, uv: str, scale: int, budget: float, out: Path) -> dict:
    stem = f"{mesh.parent.name}_{uv}"
    events_path = out / f"{stem}.events.json"
    command = command_for(mesh, uv, scale, budget, out)
    load_before = os.getloadavg()
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, __file__, "--child", str(events_path), "--", *command],
        capture_output=True, text=True, cwd=ROOT, check=False,
    )  # fmt: skip
    outside = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{stem}: exit {done.returncode}\n{done.stderr[-3000:]}")
    document = json.loads(events_path.read_text())
    report = json.loads((out / f"{stem}.json").read_text())
    wall = document["main_returned"] - document["process_start"]
    step = first_step_start(document)
    whole = attribute(document, document["main_returned"])
    before = attribute(json.loads(events_path.read_text()), step) if step else {}
    return {
        "mesh": mesh.parent.name, "file": mesh.name, "uv": uv, "budget": budget,
        "wall": wall, "outside": outside, "first_step_at": None if step is None else
        step - document["process_start"], "whole": whole, "before": before,
        "views": view_counts(document), "imports": imports(document),
        "third_party": third_party(document), "view_seconds": view_seconds(whole),
        "load": [load_before, os.getloadavg()], "report": report,
        "command": "geoscaler " + " ".join(command),
    }  # fmt: skip


# ------------------------------------------------------------------------------ printing


def _find(document, *keys):
    """The first value of any of ``keys`` anywhere in a JSON document."""
    if isinstance(document, dict):
        for key in keys:
            if key in document:
                return document[key]
        values = document.values()
    elif isinstance(document, list):
        values = document
    else:
        return None
    for value in values:
        found = _find(value, *keys)
        if found is not None:
            return found
    return None


def table(run: dict) -> str:
    wall, whole, before = run["wall"], run["whole"], run["before"]
    report = run["report"]
    steps = _find(report, "steps")
    shipped = _find(report, "shipped")
    lines = [
        f"### {run['mesh']} ({run['file']}), --uv {run['uv']}, --time-budget {run['budget']:g}",
        "",
        f"Wall {wall:.1f} s from the process's start to the command's return "
        f"({run['outside']:.1f} s seen from outside, interpreter exit included); first step "
        f"started at {_s(run['first_step_at'])}; {steps} steps; shipped {shipped}; "
        f"load average {run['load'][0][0]:.2f} before, {run['load'][1][0]:.2f} after.",
        "",
        "| phase | s before step 1 | s whole run | share of wall |",
        "|---|---:|---:|---:|",
    ]
    order = sorted(whole, key=lambda r: -whole[r])
    for row in order:
        if whole[row] < 0.005 and before.get(row, 0) < 0.005:
            continue
        lines.append(f"| {row} | {_s(before.get(row))} | {whole[row]:.2f} | "
                     f"{100 * whole[row] / wall:.1f} % |")  # fmt: skip
    lines.append(f"| **total** | {_s(sum(before.values()) if before else None)} | "
                 f"{sum(whole.values()):.2f} | 100 % |")  # fmt: skip
    lines += [
        "",
        "| views cached, by kind | G-buffers | ms each | references | ms each | "
        "tap matrices | ms each (find_taps) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for kind, counts in sorted(run["views"].items()):
        seconds = run["view_seconds"].get(kind, {})
        cells = []
        for count_key, piece in (("G-buffers", "G-buffer"), ("references", "reference render"),
                                 ("taps", "taps")):  # fmt: skip
            count = counts.get(count_key, 0)
            cells += [str(count), f"{1000 * seconds.get(piece, 0) / count:.0f}" if count else "-"]
        lines.append(f"| {kind} | " + " | ".join(cells) + " |")
    lines += ["", "| first import of | s (cumulative) | imported by | during | needed here? |",
              "|---|---:|---|---|---|"]  # fmt: skip
    mesh = Path(run["file"])
    for item in run["imports"]:
        if item["importer"] is None and item["seconds"] == 0:
            lines.append(f"| {item['package']} | not imported | | | |")
            continue
        lines.append(f"| {item['package']} | {item['seconds']:.2f} | {item['importer']} | "
                     f"{item['phase']} | {needed(item['package'], mesh, run['uv'])} |")  # fmt: skip
    others = [f"{name} {seconds:.2f} s (by {by})" for name, seconds, by in run["third_party"]
              if name not in {h.split(".")[0] for h in HEAVY}]  # fmt: skip
    if others:
        lines += ["", "Other third-party first imports of 20 ms or more: " + "; ".join(others)]
    return "\n".join(lines)


SUMMARY = [
    ("interpreter start + imports", ("interpreter start", "imports: ")),
    ("load mesh", ("load mesh",)),
    ("filters (bicubic, Lanczos)", ("method bicubic", "method lanczos")),
    ("reference maps + textures", ("reference maps", "reference textures")),
    ("direct's Lanczos start", ("direct: Lanczos start",)),
    ("caching: training pool", ("caching, training pool",)),
    ("caching: validation sets", ("caching, validation sets",)),
    ("layout: planning (G-buffers, repack, xatlas)", ("caching, layout planning", "layout: p",
                                                      "layout: repack", "layout: xatlas")),
    ("layout: bake and set-up", ("layout: bake", "layout: set-up", "layout: relaid")),
    ("optimisation step 1", ("optimisation step 1",)),
    ("optimisation steps 2..", ("optimisation steps 2..",)),
    ("validations", ("validations: ",)),
    ("reachable texels (gutters)", ("reachable texels",)),
    ("report scoring + document", ("report scoring", "report document")),
    ("export", ("export: ",)),
]  # fmt: skip


def summary_rows(rows: dict[str, float]) -> dict[str, float]:
    """The rows of a run grouped as :data:`SUMMARY` (the rest: "everything else")."""
    grouped = {name: 0.0 for name, _ in SUMMARY}
    grouped["everything else (checks, glue, set-up)"] = 0.0
    for row, seconds in rows.items():
        name = next((n for n, prefixes in SUMMARY if row.startswith(prefixes)), None)
        grouped[name or "everything else (checks, glue, set-up)"] += seconds
    return grouped


def summary(runs: list[dict]) -> str:
    """One table of every run: seconds before the first step / over the whole run."""
    heads = [f"{run['mesh']} {run['uv']}" for run in runs]
    loads = [value[0] for run in runs for value in run["load"]]
    title = (f"seconds: before step 1 / whole run (load average {min(loads):.1f} to "
             f"{max(loads):.1f} on {os.cpu_count()} cores: shared when above 0)")  # fmt: skip
    lines = [f"| {title} | " + " | ".join(heads) + " |",
             "|---|" + "---:|" * len(runs)]  # fmt: skip
    grouped = [(summary_rows(run["before"]), summary_rows(run["whole"])) for run in runs]
    for name in grouped[0][1]:
        cells = [f"{_s(before.get(name) if before else None)} / {whole[name]:.2f}"
                 for before, whole in grouped]  # fmt: skip
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    facts = [("first step starts at (s)", lambda r: _s(r["first_step_at"])),
             ("wall to the command's return (s)", lambda r: f"{r['wall']:.1f}"),
             ("steps", lambda r: str(_find(r["report"], "steps"))),
             ("shipped", lambda r: str(_find(r["report"], "shipped")))]  # fmt: skip
    for name, fact in facts:
        lines.append(f"| {name} | " + " | ".join(fact(run) for run in runs) + " |")
    return "\n".join(lines)


def _s(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def machine() -> str:
    model = "unknown"
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            model = line.split(":", 1)[1].strip()
            break
    torch_version = subprocess.run(
        [sys.executable, "-c", "import torch; print(torch.__version__)"],
        capture_output=True, text=True, check=False,
    ).stdout.strip()  # fmt: skip
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return (f"{os.cpu_count()} cores ({model}), Python {platform.python_version()}, torch "
            f"{torch_version}, load average {load} (1, 5, 15 min) as the runs started")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("meshes", nargs="*", default=DEFAULT_MESHES)
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--budget", type=float, default=25.0)
    parser.add_argument("--out", type=Path, default=Path("/tmp/geoscaler_profile"))
    parser.add_argument("--markdown", type=Path, help="also write the tables here")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    facts = machine()
    print(facts, flush=True)
    runs = []
    for spec in args.meshes:
        mesh, uv = mesh_path(spec)
        run = run_one(mesh, uv, args.scale, args.budget, args.out)
        runs.append(run)
        print("\n" + table(run), flush=True)
    (args.out / "profile.json").write_text(json.dumps(runs, indent=1, default=str))
    print("\n" + summary(runs))
    if args.markdown:
        text = [f"Machine: {facts}.", "", summary(runs), ""]
        text += [f"`{run['command']}`" for run in runs]
        text += ["", *("\n" + table(run) for run in runs)]
        args.markdown.write_text("\n".join(text) + "\n")


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        sys.exit(child(sys.argv[2], sys.argv[4:]))
    main()
