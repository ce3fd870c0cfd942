"""Peak resident memory of ``geoscaler downsample`` on a large texture, as a user runs it.

Builds (in a temporary folder) a mesh whose base colour is ``--size`` x ``--size`` (default
8192): the demo cube-sphere (:func:`geoscaler.procedural.demo_mesh`, every chart of its atlas
seen from the views, frame-filling), or ``--mesh PATH``'s mesh, its base colour upscaled with
Pillow's bicubic and saved as OBJ + JPEG (quick to encode). Then it runs ``geoscaler downsample
MESH --scale 4 --steps S --time-budget B --full-budget -o OUT.glb --report R.json`` in a new
process per ``--uv`` mode: loading, the filters, the reference renders, the loop's steps, the
validation and the export all run (``--full-budget``: an upscaled texture looks lossless at 4x,
and the job would stop early, before the views that memory grows with are cached).

The child's peak resident set size comes from the kernel (``os.wait4``'s ``ru_maxrss`` of that
child alone), the wall time from here; ``--timeline`` also samples the child's RSS every 0.2 s
and prints its growth (where the peak comes from). The table says how many views the job
cached (training / Q + near + far, from its report): under a time budget that depends on the
machine's speed, and every cached view holds its G-buffer, reference render and taps (tens of
MB a view where the mesh fills the frame), so peaks are comparable at equal view counts.

Usage:
    python benchmarks/peak_memory.py [--size 8192] [--mesh PATH] [--uv keep repack]
        [--steps 3] [--time-budget 120] [--timeline] [--keep DIR]

``geoscaler`` keeps freed memory for reuse (as the Makefile's ``MALLOC_MMAP_THRESHOLD_`` and
``MALLOC_TRIM_THRESHOLD_`` do), so the peak is the most the process held at once, freed
buffers included; run it with and without those variables exported to see both ways in.
A long ``--time-budget`` shows the memory limit at work: without it the caching would go on.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from PIL import Image

from geoscaler.color import to_rgb
from geoscaler.io import load_mesh, save_mesh
from geoscaler.procedural import demo_mesh

SAMPLE_SECONDS = 0.2


def build_asset(folder: Path, size: int, source: Path | None = None) -> Path:
    """The demo cube-sphere (or the mesh at ``source``) with every base colour upscaled to
    ``size`` x ``size``, as OBJ + MTL + JPEG in ``folder``."""
    mesh = demo_mesh() if source is None else load_mesh(source)
    upscaled: dict[int, np.ndarray] = {}
    for material in mesh.materials:
        texture = material.base_color_texture
        if texture is not None and id(texture) not in upscaled:
            image = Image.fromarray(np.ascontiguousarray(to_rgb(texture)))
            upscaled[id(texture)] = np.asarray(image.resize((size, size), Image.BICUBIC))
    mesh.materials = [
        m
        if m.base_color_texture is None
        else replace(m, base_color_texture=upscaled[id(m.base_color_texture)])
        for m in mesh.materials
    ]
    path = folder / "large.obj"
    save_mesh(mesh, path, image_format="jpeg")
    return path


def _rss_bytes(pid: int) -> int:
    """Resident set size of a running process, bytes (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _sample(pid: int, samples: list[tuple[float, int]], stop: threading.Event) -> None:
    start = time.perf_counter()
    while not stop.wait(SAMPLE_SECONDS):
        samples.append((time.perf_counter() - start, _rss_bytes(pid)))


def run_downsample(
    mesh: Path, out: Path, uv: str, steps: int, budget: float, timeline: bool
) -> dict:
    """One ``geoscaler downsample`` in a new process: its peak RSS (bytes), wall seconds,
    exit status, the views it cached (from its report; memory grows with them too) and
    (``timeline``) ``(seconds, RSS bytes)`` samples."""
    report = out.with_suffix(".json")
    command = [
        str(Path(sys.executable).with_name("geoscaler")), "downsample", str(mesh), "--scale", "4",
        "--steps", str(steps), "--time-budget", str(budget), "--uv", uv, "--device", "cpu",
        "--full-budget",
        "-o", str(out), "--report", str(report), "--force",
    ]  # fmt: skip
    samples: list[tuple[float, int]] = []
    stop = threading.Event()
    start = time.perf_counter()
    # A file, not a pipe: a long run's progress bar would fill a pipe read only at the end.
    stderr = tempfile.TemporaryFile()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr)
    sampler = threading.Thread(target=_sample, args=(child.pid, samples, stop), daemon=True)
    if timeline:
        sampler.start()
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    stop.set()
    child.returncode = os.waitstatus_to_exitcode(status)
    stderr.seek(0)
    errors = stderr.read().decode(errors="replace")[-2000:]
    stderr.close()
    return {
        "uv": uv,
        "peak_rss": usage.ru_maxrss * 1024,  # Linux reports kilobytes
        "wall": wall,
        "rc": child.returncode,
        "stderr": errors,
        "samples": samples,
        "views": _views_cached(report),
    }


def _views_cached(report: Path) -> str:
    """``training / Q + near + far`` views the job cached, from its report ("?" without one)."""
    try:
        details = json.loads(report.read_text())["details"]
    except (OSError, ValueError, KeyError):
        return "?"
    validation = details.get("validation_views", {})
    sets = " + ".join(str(validation.get(name, 0)) for name in ("Q", "near", "far"))
    return f"{details.get('training_views', 0)} / {sets}"


def _print_timeline(samples: list[tuple[float, int]]) -> None:
    """Each sample where RSS moved by 100 MB or more since the last one printed."""
    shown = 0
    for seconds, rss in samples:
        if abs(rss - shown) >= 100e6:
            print(f"    {seconds:7.1f} s  {rss / 1e9:6.2f} GB")
            shown = rss


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=8192, help="texture side (default 8192)")
    parser.add_argument("--mesh", type=Path, help="mesh to upscale (default: the demo sphere)")
    parser.add_argument("--uv", nargs="+", default=["keep"], help="--uv modes (default keep)")
    parser.add_argument("--steps", type=int, default=3, help="loop steps (default 3)")
    parser.add_argument("--time-budget", type=float, default=120.0, help="seconds (default 120)")
    parser.add_argument("--timeline", action="store_true", help="print RSS over time")
    parser.add_argument("--keep", help="build the asset here (reused when present)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="geoscaler_memory_") as temporary:
        folder = Path(args.keep or temporary)
        folder.mkdir(parents=True, exist_ok=True)
        mesh = folder / "large.obj"
        if not mesh.exists():
            started = time.perf_counter()
            mesh = build_asset(folder, args.size, args.mesh)
            print(f"built {mesh} in {time.perf_counter() - started:.1f} s")
        rows = []
        for uv in args.uv:
            row = run_downsample(
                mesh, folder / f"out_{uv}.glb", uv, args.steps, args.time_budget, args.timeline
            )
            if row["rc"] != 0:
                print(row["stderr"], file=sys.stderr)
            if args.timeline:
                print(f"--uv {uv}: RSS over time")
                _print_timeline(row["samples"])
            rows.append(row)
    texels = args.size * args.size
    print(f"\n{args.size} x {args.size} input, --scale 4 --steps {args.steps}")
    print("| --uv | peak RSS (GB) | bytes per input texel | wall (s) | views cached | exit |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for row in rows:
        per_texel = row["peak_rss"] / texels
        print(
            f"| {row['uv']} | {row['peak_rss'] / 1e9:.2f} | {per_texel:.1f} | "
            f"{row['wall']:.1f} | {row['views']} | {row['rc']} |"
        )


if __name__ == "__main__":
    main()
