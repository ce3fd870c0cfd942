"""Assets per hour of ``geoscaler batch`` on this machine: local jobs, and Ray.

Each configuration runs ``geoscaler batch DATA -o OUT --scale 4 --time-budget B --device cpu``
plus its engine options in a new process, timed from outside, into a fresh folder (Ray's start
included: ``--ray-address local`` starts a Ray instance for the run and stops it after). From
its ``summary.json``: assets done and failed, the mean gain over bicubic and the seconds per
asset. Assets per hour = assets done / wall time.

Usage:
    python benchmarks/batch.py [DATA] [--time-budget 15] [--configs jobs1 jobs2 ray]
        [--out DIR]

DATA: a folder of assets (default: ../shared/data). Prints a Markdown table and writes
``batch_bench.json`` and ``batch_bench.md`` into ``--out`` (default /tmp/geoscaler_batch_bench).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CONFIGS = {
    "jobs1": ["--jobs", "1"],
    "jobs2": ["--jobs", "2"],
    "ray": ["--engine", "ray", "--ray-address", "local", "--cpus-per-task", "1"],
}
"""Engine options per configuration: one job with every core's threads, one job per core with
one thread each, and one Ray task per core on a Ray instance started for the run."""


def run(data: Path, out: Path, budget: float, options: list[str]) -> dict:
    """One ``geoscaler batch`` as a user runs it; its summary's facts and the wall time."""
    command = [sys.executable, "-m", "geoscaler.cli", "batch", str(data), "-o", str(out)]
    command += ["--scale", "4", "--time-budget", f"{budget:g}", "--device", "cpu", *options]
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=os.environ)
    wall = time.perf_counter() - started
    summary = json.loads((out / "summary.json").read_text())
    rows = summary["assets"]
    ok = [row for row in rows if row["status"] == "done"]
    seconds = [row["seconds"] for row in ok]
    return {
        "command": shlex.join(["geoscaler", *command[3:]]),
        "status": done.returncode,
        "wall_s": round(wall, 1),
        "done": len(ok),
        "failed": sum(row["status"] == "failed" for row in rows),
        "errors": [row["error"] for row in rows if row["error"]],
        "assets_per_hour": round(3600 * len(ok) / wall, 1),
        "mean_gain_db": round(statistics.mean(r["gain_db"] for r in ok), 3) if ok else None,
        "mean_asset_s": round(statistics.mean(seconds), 1) if ok else None,
        "max_asset_s": round(max(seconds), 1) if ok else None,
        "workers": summary["run"]["workers"],
    }


def markdown(results: dict[str, dict], budget: float, assets: int) -> str:
    lines = [
        f"{assets} assets, `--scale 4 --time-budget {budget:g} --device cpu`, "
        f"{os.cpu_count()} cores",
        "",
        "| engine | workers | wall (s) | assets done | assets per hour | mean gain over bicubic "
        "(dB) | seconds per asset (mean / max) |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, r in results.items():
        gain = "" if r["mean_gain_db"] is None else f"{r['mean_gain_db']:+.2f}"
        lines.append(
            f"| {name} | {r['workers']} | {r['wall_s']:.0f} | {r['done']} | "
            f"{r['assets_per_hour']:.0f} | {gain} | {r['mean_asset_s']} / {r['max_asset_s']} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", nargs="?", default=str(DATA), help="folder of assets")
    parser.add_argument("--time-budget", type=float, default=15.0, help="seconds per asset")
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--out", default="/tmp/geoscaler_batch_bench", help="results folder")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in args.configs:
        folder = out / name
        shutil.rmtree(folder, ignore_errors=True)
        results[name] = run(Path(args.data), folder, args.time_budget, CONFIGS[name])
        print(f"{name}: {json.dumps(results[name])}", file=sys.stderr, flush=True)
    assets = max(r["done"] + r["failed"] for r in results.values())
    table = markdown(results, args.time_budget, assets)
    (out / "batch_bench.json").write_text(json.dumps(results, indent=2) + "\n")
    (out / "batch_bench.md").write_text(table)
    print(table)


if __name__ == "__main__":
    main()
