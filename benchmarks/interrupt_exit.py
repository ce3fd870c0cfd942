"""Exit statuses of ``geoscaler batch`` stopped by Ctrl-C twice, over many runs.

Each run starts ``geoscaler batch LIB -o OUT --method direct`` (one local job, one quick
validation view) as a user's command line does, in a process group of its own, waits until the
first asset's job has started and ``--lead`` seconds more, then sends SIGINT to the group (the
first Ctrl-C: no new asset starts, the running job keeps its best result). The second SIGINT
is sent either ``--gap`` seconds later (``--second gap``, as
``tests/test_batch.py::test_a_killed_worker_and_ctrl_c_leave_only_complete_outputs`` does),
or once ``summary.json`` has appeared, after a random delay of up to ``--jitter`` seconds
(``--second late``, the default): then it lands where the command ends and the interpreter
shuts down, the window where a late Ctrl-C once turned exit status 130 into death by SIGINT
(-2). Every run must end with 130.

Usage:
    nice -n 10 python benchmarks/interrupt_exit.py [--runs 300] [--second late|gap]
        [--lead 0.2] [--gap 0.5] [--jitter 0.4] [--seed 0]

Prints the count of each exit status every 10 runs and at the end with the wall time, and the
stderr of the first run that did not end with 130. A run whose batch had ended before the
first Ctrl-C (its jobs failed at once, say) is counted as "not interrupted" with its status.
"""

from __future__ import annotations

import argparse
import collections
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

STAGING_PREFIX = ".geoscaler-batch-"
COMMAND = textwrap.dedent(
    """
    import sys
    import geoscaler.cli
    from geoscaler.protocol import Evaluation
    sys.exit(geoscaler.cli.main(evaluation=Evaluation.quick((0,))))
    """
)
"""The console script's ``sys.exit(main())`` with the tests' quick evaluation: ``main`` reads
``sys.argv`` and runs as the process's command line."""


def make_library(root: Path) -> Path:
    """Two tiny assets: the first is interrupted, the second must not start."""
    from geoscaler.io import save_mesh
    from geoscaler.procedural import demo_mesh

    root.mkdir(parents=True)
    save_mesh(demo_mesh(subdivisions=4, texture_size=64), root / "a.glb")
    save_mesh(demo_mesh(subdivisions=3, texture_size=32), root / "b.glb")
    return root


def wait_for(found, process: subprocess.Popen, timeout: float = 120) -> bool:
    """Poll ``found()`` every 10 ms until it is true or the process has ended."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and process.poll() is None:
        if found():
            return True
        time.sleep(0.01)
    return False


def one_run(library: Path, out: Path, args: argparse.Namespace, rng: random.Random):
    """One interrupted batch: its exit status (``"not interrupted X"`` where the batch had
    ended before the first Ctrl-C, e.g. its jobs failed at once) and stderr."""
    shutil.rmtree(out, ignore_errors=True)
    argv = ["batch", str(library), "-o", str(out), "--method", "direct", "--scale", "4"]
    argv += ["--device", "cpu", "--time-budget", "30"]
    process = subprocess.Popen(
        [sys.executable, "-c", COMMAND, *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    interrupted = False
    try:
        if wait_for(lambda: any(out.rglob(STAGING_PREFIX + "*")), process):
            time.sleep(args.lead)
            interrupted = process.poll() is None and not (out / "summary.json").exists()
            os.killpg(process.pid, signal.SIGINT)
            if args.second == "gap":
                time.sleep(args.gap)
            else:
                wait_for((out / "summary.json").exists, process)
                time.sleep(rng.uniform(0.0, args.jitter))
            os.killpg(process.pid, signal.SIGINT)
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    status = process.returncode
    return (status if interrupted else f"not interrupted {status}"), stderr


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=300)
    parser.add_argument("--second", choices=["late", "gap"], default="late")
    parser.add_argument("--lead", type=float, default=0.2, help="seconds after the job starts")
    parser.add_argument("--gap", type=float, default=0.5, help="--second gap: seconds between")
    parser.add_argument("--jitter", type=float, default=0.4, help="--second late: most delay")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    counts: collections.Counter = collections.Counter()
    first_bad = None
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="geoscaler-interrupt-") as tmp:
        library = make_library(Path(tmp) / "library")
        for run in range(args.runs):
            status, stderr = one_run(library, Path(tmp) / "out", args, rng)
            counts[status] += 1
            if status != 130 and first_bad is None:
                first_bad = (run, status, stderr)
                print(f"run {run}: status {status}; stderr:\n{stderr}", flush=True)
            if (run + 1) % 10 == 0:
                print(f"{run + 1} runs: {dict(counts)}", flush=True)
    wall = time.perf_counter() - start
    print(f"exit statuses over {args.runs} runs: {dict(counts)}; {wall:.0f} s")
    return 0 if counts[130] == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
