"""The main job under its time budget, as a user runs it: on an idle machine and beside a busy one.

For every mesh, scale, budget, load and UV mode this runs ``geoscaler downsample MESH --scale
S --time-budget B --uv U -o OUT.glb --report R.json`` in a new process, timed from outside
(``busy``: a CPU-bound busy loop, started here, runs beside it). Then, with the machine quiet
again, it scores every written file, bicubic and Lanczos on all views of the protocol's sets (Q,
and near and far with ``--sets``), as PROTOCOL.md defines them: not the job's own validation
views.

Columns: seconds from the command's start to its first optimisation step (from its report),
steps, wall seconds, what shipped, the gain over bicubic per set, the share of the texel
ceiling's gain on Q (``--ceiling``: JSON rows of ``benchmarks/texel_ceiling.py``), and whether
the file is below the best filter on any set (the filters scored in the file's UVs as written
where it keeps the mesh's layout: :data:`KEPT_UV_TOLERANCE`).

With ``--uv auto keep`` the summary also gives, per scale, budget and load, auto's gain on Q
over keep's on the same mesh: the mean and the worst mesh.

``--loop JSON`` overrides settings of the learned method's loop (``OptimizeConfig`` fields, as
``geoscaler.cli.main(optimize=...)`` takes them; e.g. ``'{"distances": [[1.8, 3.0]]}'``): to
measure a setting in the job itself, as users run it.

Usage:
    python benchmarks/budget.py [PATH ...] [--scale 4 8] [--budget 15 30 60]
        [--load idle busy] [--uv auto keep] [--sets 2.4 1.5 4.0] [--ceiling CEILING.json ...]
        [--loop JSON] [--out DIR]

PATH: mesh files or folders (default: ../shared/data). Writes ``budget.json`` and
``budget.md`` into ``--out`` (default: /tmp/geoscaler_budget), and beside them each run's report
and log (``MESH_xS_Bs_LOAD_UV.json`` and ``.log``: the race's trials are in the report).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from entry import exit_status  # beside this script

from geoscaler.io import load_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.cameras import view_set_cameras
from geoscaler.render.metrics import mean_metrics
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, ViewSet
from geoscaler.report.bench import find_meshes
from geoscaler.resize.filters import bicubic, lanczos, output_sizes, reference_textures

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BUSY_LOOP = "while True: pass"
LOOP_OVERRIDE = (
    "import json, sys; from geoscaler.cli import main; "
    "optimize = json.loads(sys.argv.pop(1)); sys.exit(main(optimize=optimize))"
)
"""``--loop``'s job: ``main()`` with argv None reads the command from ``sys.argv`` and counts
the budget from the process's start, as the plain command does (``main(argv)`` counts from
its call)."""


def run_downsample(
    mesh: Path,
    scale: int,
    budget: float,
    busy: bool,
    out: Path,
    loop: str | None = None,
    uv: str = "auto",
) -> dict:
    """One ``geoscaler downsample`` as a user runs it (``loop``: JSON overrides of the loop's
    settings; ``uv``: its ``--uv``); its report's facts and the wall time."""
    mesh, out = mesh.resolve(), out.resolve()
    run = f"{mesh.parent.name}_x{scale}_{budget:g}s_{'busy' if busy else 'idle'}_{uv}"
    output, report = out / "out.glb", out / f"{run}.json"  # each run's report is kept
    cli = ["-m", "geoscaler.cli"] if loop is None else ["-c", LOOP_OVERRIDE, loop]
    command = [sys.executable, *cli, "downsample", str(mesh), "--scale",
               str(scale), "--time-budget", str(budget), "--uv", uv, "-o", str(output),
               "--report", str(report), "--force"]  # fmt: skip
    load_before = os.getloadavg()[0]  # the 1-minute load average: what else was running
    neighbour = subprocess.Popen([sys.executable, "-c", BUSY_LOOP]) if busy else None
    try:
        started = time.perf_counter()
        # run in the output folder: `-m` puts the working directory first on the module path,
        # so a checkout there would shadow the package PYTHONPATH names (comparing two trees)
        done = subprocess.run(command, capture_output=True, text=True, env=os.environ, cwd=out)
        wall = time.perf_counter() - started
    finally:
        if neighbour is not None:
            neighbour.kill()
            neighbour.wait()
    log = out / f"{run}.log"
    log.write_text(done.stderr)  # the command's progress and messages, to read afterwards
    if done.returncode != 0:
        raise RuntimeError(f"{mesh} x{scale} {budget}s: {done.stderr.strip()[-500:]}")
    details = json.loads(report.read_text())["details"]
    return {
        "wall_s": round(wall, 2),
        "load_before": round(load_before, 2),
        "first_step_s": details.get("first_step_after_start"),
        "steps": details.get("steps"),
        "shipped": details.get("shipped"),
        "training_views": details.get("training_views"),
        "validation_views": details.get("validation_views"),
        "output": load_mesh(output),
    }


def corner_uvs_of(mesh: TexturedMesh, output: TexturedMesh) -> np.ndarray:
    """``(F, 3, 2)`` UVs of ``output``'s face corners in ``mesh``'s face order: a job with
    ``--uv auto`` may ship a new layout, and the writer may order faces by material. Faces are
    matched by their corners' positions (the job keeps the geometry).

    Raises:
        SystemExit: the output's faces are not the input's."""

    def keys(m: TexturedMesh) -> np.ndarray:
        return np.round(m.positions[m.faces].reshape(len(m.faces), 9).astype(np.float64), 5)

    mine, theirs = keys(mesh), keys(output)
    if mine.shape != theirs.shape:
        raise SystemExit(f"the output has {len(theirs)} faces, the input {len(mine)}")
    order_in, order_out = np.lexsort(mine.T[::-1]), np.lexsort(theirs.T[::-1])
    if not np.array_equal(mine[order_in], theirs[order_out]):
        raise SystemExit("the output's faces are not the input's: cannot score it in its UVs")
    uvs = np.empty((len(mesh.faces), 3, 2), np.float32)
    uvs[order_in] = output.corner_uvs()[order_out]
    return uvs


KEPT_UV_TOLERANCE = 1e-6
"""A written file keeps the mesh's layout where each corner's UV is within this of the mesh's:
glTF stores v flipped (``1 - v``) in float32, which moves an OBJ's UVs by one float32 step
(3e-8 to 6e-8) and a score by up to a few 1e-4 dB (ycb_chain shipping Lanczos's own texels:
0.0004 dB below Lanczos on the far set)."""

SCORE_ROUNDING_DB = 1e-5
"""A file scores below a filter where it does by more than this: the same texels scored in the
same UVs differ by float32 summation alone (ph_wooden_table_02 at 4x shipping Lanczos's maps:
1.3e-7 dB below Lanczos), far under the hundredth of a dB the tables print."""


def score_runs(mesh_path: Path, scale: int, distances: list[float], runs: list[dict]) -> dict:
    """PSNR-fg of bicubic and Lanczos per distance; each run gets its own ``psnr`` per distance,
    its output rendered in its own UVs (:func:`corner_uvs_of`), and ``filter_psnr``: the
    filters in the same UVs as written where the file keeps the mesh's layout
    (:data:`KEPT_UV_TOLERANCE`; one scoring per distinct written layout), else the returned ones,
    so that a file is found below a filter only where it is, not by its writer's rounding.

    The shipped textures have the sizes the product gives (``scale`` on the full-resolution
    original); bicubic and Lanczos resize the originals to the same sizes; every image is
    rendered as protocol 1 does, except that the reference images come from the full-resolution
    originals, as the job's own (the protocol reduces originals over 2048 to 2048 first)."""
    mesh = load_mesh(mesh_path)
    renderer = Renderer(mesh, "cpu", product_evaluation(PROTOCOL_EVALUATION))
    sizes = output_sizes(mesh, scale, None)  # what the product ships: the originals' sizes
    originals = reference_textures(mesh, None)  # a user's filters resize the originals
    filters = {
        name: [None if t is None else f(t, scale) for t in originals]
        for name, f in (("bicubic", bicubic), ("lanczos", lanczos))
    }
    filter_psnr: dict[str, dict[float, float]] = {name: {} for name in filters}
    own_uvs = mesh.corner_uvs()
    written: dict[bytes, dict[str, dict[float, float]]] = {}  # kept layouts, as written
    for run in runs:
        run["psnr"] = {}
        run["uvs"] = corner_uvs_of(mesh, run["output"])  # its own layout where it ships a new one
        if np.array_equal(run["uvs"], own_uvs):  # the filters' own scores hold as they are
            run["filter_psnr"] = filter_psnr
        elif np.abs(run["uvs"] - own_uvs).max() <= KEPT_UV_TOLERANCE:
            run["filter_psnr"] = written.setdefault(run["uvs"].tobytes(), {n: {} for n in filters})
        else:
            run["filter_psnr"] = filter_psnr
    for distance in distances:
        views = ViewSet(renderer, view_set_cameras(distance, PROTOCOL_EVALUATION))
        cache = ViewCache(views, sizes, with_taps=True)
        for name, textures in filters.items():
            filter_psnr[name][distance] = mean_metrics(cache.score(textures))["psnr_fg"]
        for run in runs:
            output = run["output"]
            shipped = [m.base_color_texture for m in output.materials]
            textures = [None if s is None else t for s, t in zip(sizes, shipped, strict=True)]
            run["psnr"][distance] = mean_metrics(cache.score(textures, run["uvs"]))["psnr_fg"]
            for name, psnr in run["filter_psnr"].items():
                if distance not in psnr:
                    psnr[distance] = mean_metrics(cache.score(filters[name], run["uvs"]))["psnr_fg"]
        del cache, views  # the next set's caches replace these
    return filter_psnr


def ceilings(paths: list[str]) -> dict[tuple[str, int], float]:
    """(mesh folder, scale) -> the texel ceiling's gain on Q, from texel_ceiling.py's JSON."""
    found = {}
    for path in paths:
        for row in json.loads(Path(path).read_text()):
            found[row["mesh"], row["scale"]] = row["ceiling_gain"]
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("paths", nargs="*", default=[str(DATA)])
    parser.add_argument("--scale", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--budget", type=float, nargs="+", default=[15.0, 30.0, 60.0])
    parser.add_argument("--load", nargs="+", choices=["idle", "busy"], default=["idle", "busy"])
    parser.add_argument("--uv", nargs="+", choices=["auto", "keep"], default=["auto"])
    parser.add_argument("--sets", type=float, nargs="+", default=[2.4])
    parser.add_argument("--ceiling", nargs="*", default=[])
    parser.add_argument("--loop", help="JSON overrides of the learned method's loop settings")
    parser.add_argument("--out", default="/tmp/geoscaler_budget")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ceiling = ceilings(args.ceiling)
    rows = []
    for entry in find_meshes(args.paths):
        name = entry.path.parent.name
        for scale in args.scale:
            runs = []
            for budget, load, uv in itertools.product(args.budget, args.load, args.uv):
                run = run_downsample(entry.path, scale, budget, load == "busy", out, args.loop, uv)
                facts = {"mesh": name, "scale": scale, "budget": budget, "load": load, "uv": uv}
                runs.append({**facts, **run})
            filters = score_runs(entry.path, scale, args.sets, runs)
            for run in runs:
                del run["output"], run["uvs"]
                mine = run.pop("filter_psnr")  # the filters in the file's UVs where it kept them
                best = {d: max(f[d] for f in mine.values()) for d in args.sets}
                run["gain_db"] = {d: run["psnr"][d] - filters["bicubic"][d] for d in args.sets}
                run["lanczos_gain_db"] = {
                    d: filters["lanczos"][d] - filters["bicubic"][d] for d in args.sets
                }
                run["below_best_filter"] = any(
                    run["psnr"][d] < best[d] - SCORE_ROUNDING_DB for d in args.sets
                )
                top = ceiling.get((name, scale))
                run["ceiling_share"] = None if not top else run["gain_db"][args.sets[0]] / top
                rows.append(run)
                print(format_row(run, args.sets), flush=True)
            (out / "budget.json").write_text(json.dumps(rows, indent=2, default=str))
    (out / "budget.md").write_text(markdown(rows, args.sets))
    print(summary(rows, args.sets))
    return 0


def format_row(run: dict, sets: list[float]) -> str:
    gains = " ".join(f"{run['gain_db'][d]:+6.2f}" for d in sets)
    share = "" if run["ceiling_share"] is None else f"{100 * run['ceiling_share']:5.0f}%"
    return (
        f"{run['mesh']:26} x{run['scale']} {run['budget']:>4.0f}s {run['load']:5} "
        f"{run['uv']:4} first "
        f"{run['first_step_s'] or 0:5.1f}s steps {run['steps'] or 0:4} wall {run['wall_s']:6.1f}s "
        f"{run['shipped']:8} gain {gains} {share} {'BELOW' if run['below_best_filter'] else ''}"
    )


def markdown(rows: list[dict], sets: list[float]) -> str:
    head = "| mesh | scale | budget | load | uv | first step s | steps | wall s | shipped | "
    head += " | ".join(f"gain {d:g}" for d in sets) + " | ceiling share | below a filter |"
    lines = [head, "|" + " --- |" * (11 + len(sets) - 1)]
    for r in rows:
        share = "" if r["ceiling_share"] is None else f"{100 * r['ceiling_share']:.0f}%"
        gains = " | ".join(f"{r['gain_db'][d]:+.2f}" for d in sets)
        lines.append(
            f"| {r['mesh']} | x{r['scale']} | {r['budget']:.0f} | {r['load']} | {r['uv']} | "
            f"{r['first_step_s']} | {r['steps']} | {r['wall_s']:.1f} | {r['shipped']} | "
            f"{gains} | {share} | {'yes' if r['below_best_filter'] else 'no'} |"
        )
    return "\n".join(lines) + "\n\n" + summary(rows, sets) + "\n"


def summary(rows: list[dict], sets: list[float]) -> str:
    """Per scale, budget, load and UV mode: mean and worst gain on Q, worst wall-clock overrun,
    the slowest first step, the lowest ceiling share and how many files fell below a filter;
    then auto against keep where both ran (:func:`auto_over_keep`)."""
    lines = []
    keys = sorted({(r["scale"], r["budget"], r["load"], r["uv"]) for r in rows})
    for key in keys:
        scale, budget, load, uv = key
        mine = [r for r in rows if (r["scale"], r["budget"], r["load"], r["uv"]) == key]
        gains = [r["gain_db"][sets[0]] for r in mine]
        shares = [r["ceiling_share"] for r in mine if r["ceiling_share"] is not None]
        overrun = max(r["wall_s"] / budget - 1 for r in mine)
        first = max(r["first_step_s"] or 0 for r in mine)
        share = f", ceiling share min {100 * min(shares):.0f}%" if shares else ""
        worst = min(mine, key=lambda r: r["gain_db"][sets[0]])["mesh"]
        lines.append(
            f"x{scale} {budget:.0f} s {load} {uv}: {len(mine)} meshes, gain on Q mean "
            f"{statistics.mean(gains):+.2f} worst {min(gains):+.2f} dB ({worst}){share}, wall at "
            f"most {100 * overrun:+.0f}% of the budget, first step by {first:.1f} s, below a "
            f"filter: {sum(r['below_best_filter'] for r in mine)}"
        )
    return "\n".join(lines + auto_over_keep(rows, sets[0]))


def auto_over_keep(rows: list[dict], distance: float) -> list[str]:
    """Per scale, budget and load where both modes ran: auto's gain on the first set minus
    keep's, mesh by mesh; the mean and the worst mesh."""
    lines = []
    for scale, budget, load in sorted({(r["scale"], r["budget"], r["load"]) for r in rows}):
        gain = {
            (r["mesh"], r["uv"]): r["gain_db"][distance]
            for r in rows
            if (r["scale"], r["budget"], r["load"]) == (scale, budget, load)
        }
        both = sorted({m for m, _ in gain if (m, "auto") in gain and (m, "keep") in gain})
        if not both:
            continue
        over = {m: gain[m, "auto"] - gain[m, "keep"] for m in both}
        worst = min(over, key=over.get)
        lines.append(
            f"x{scale} {budget:.0f} s {load}: auto over keep on Q, {len(both)} meshes: mean "
            f"{statistics.mean(over.values()):+.2f}, worst {over[worst]:+.2f} dB ({worst})"
        )
    return lines


if __name__ == "__main__":
    sys.exit(exit_status(main))
