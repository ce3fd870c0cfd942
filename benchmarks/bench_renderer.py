"""Renderer benchmark: rasterise, sample from the cache, and cache size per protocol view.

Usage:
    python benchmarks/bench_renderer.py [--views 12] [--threads N] [--device auto|cpu|cuda]
        [--json OUT.json] [MESH ...]

With no MESH it measures the procedural demo mesh at 19,200 faces and, when ../shared/data is
present, the 16,384-face YCB scans. Figures are medians over validation views 0..views-1:
  raster    one 1024 x 1024 G-buffer (2 x 2 supersampling of the 512 x 512 view)
  ref ms    shade every covered sample from the G-buffer with the reference texture (2048 at
            most) and resolve to 512 x 512, forward only
  4x ms     the same with a texture 4 times smaller (a candidate at scale 4)
  train ms  one training view of that candidate from cached pixel taps, forward + backward
            (after a first one, which also makes the taps' transpose: once per view)
  cache MB  bytes held by one view's G-buffer; taps MB: one view's cached training taps
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

from geoscaler.color import texture_to_linear
from geoscaler.io import load_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.optim.losses import view_loss
from geoscaler.procedural import demo_mesh
from geoscaler.render.cameras import validation_cameras
from geoscaler.render.renderer import Renderer, resolve_device
from geoscaler.render.texture import MipTexture
from geoscaler.render.views import ViewCache, ViewSet
from geoscaler.resize.filters import lanczos, reference_textures

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DEFAULT_SCANS = ["ycb_lego_duplo_a/textured.obj", "ycb_chain/textured.obj"]


def _timed(fn, device: torch.device) -> float:
    _sync(device)
    start = time.perf_counter()
    fn()
    _sync(device)
    return time.perf_counter() - start


def bench_mesh(name: str, mesh: TexturedMesh, views: int, device: torch.device) -> dict:
    renderer = Renderer(mesh, device)
    reference = renderer.reference_textures()
    small = lanczos(reference_textures(mesh)[0], 4)
    small_linear = texture_to_linear(small, device)
    cameras = validation_cameras()[:views]
    renderer.rasterize(cameras[0])  # warm-up
    raster, sample_ref, sample_small, train, cache, taps_mb, samples = ([] for _ in range(7))
    for camera in cameras:
        start = time.perf_counter()
        gbuffer = renderer.rasterize(camera)
        _sync(device)
        raster.append(time.perf_counter() - start)
        cache.append(gbuffer.nbytes)
        samples.append(gbuffer.num_samples)
        with torch.no_grad():
            sample_ref.append(_timed(lambda g=gbuffer: renderer.render(g, reference), device))
            mips = [MipTexture(small_linear)]
            sample_small.append(_timed(lambda g=gbuffer, m=mips: renderer.render(g, m), device))
        view = ViewCache(ViewSet(renderer, [camera]), [tuple(small.shape[:2])], with_taps=True)
        texels = small_linear.clone().requires_grad_(True)
        step = lambda v=view, t=texels: view_loss(v, 0, [t], None, 0.0).backward()  # noqa: E731
        step()  # the first backward pass also makes the taps' transpose, once per view
        train.append(_timed(step, device))
        taps_mb.append(view.taps[0][0].nbytes / 1e6)  # the taps and their transpose
    return {
        "mesh": name,
        "faces": len(mesh.faces),
        "texture": list(reference[0].size),
        "covered_samples": int(statistics.median(samples)),
        "raster_s": statistics.median(raster),
        "sample_reference_ms": 1000 * statistics.median(sample_ref),
        "sample_4x_ms": 1000 * statistics.median(sample_small),
        "train_view_ms": 1000 * statistics.median(train),
        "cache_mb": statistics.median(cache) / 1e6,
        "taps_mb": statistics.median(taps_mb),
    }


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("meshes", nargs="*", help="mesh files (default: demo + YCB scans)")
    parser.add_argument("--views", type=int, default=12)
    parser.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--json", help="also write the results here")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = resolve_device(args.device)

    cases: list[tuple[str, TexturedMesh]] = []
    if args.meshes:
        cases = [(Path(p).name, load_mesh(p)) for p in args.meshes]
    else:
        cases.append(("procedural demo (40x40/chart)", demo_mesh(subdivisions=40)))
        cases += [
            (s.split("/")[0], load_mesh(DATA / s)) for s in DEFAULT_SCANS if (DATA / s).exists()
        ]

    cpu = platform.processor() or platform.machine()
    where = f"{device.type}, {torch.get_num_threads()} threads, {cpu}"
    print(f"renderer benchmark on {where}; medians over {args.views} validation views")
    columns = ["faces", "texture", "samples", "raster s", "ref ms", "4x ms", "train ms"]
    columns += ["cache MB", "taps MB"]
    print(f"{'mesh':30} " + " ".join(f"{c:>9}" for c in columns))
    results = []
    for name, mesh in cases:
        row = bench_mesh(name, mesh, args.views, device)
        results.append(row)
        texture = "x".join(map(str, row["texture"]))
        print(
            f"{name:30} {row['faces']:>9,} {texture:>9} {row['covered_samples']:>9,} "
            f"{row['raster_s']:>9.3f} {row['sample_reference_ms']:>9.1f} "
            f"{row['sample_4x_ms']:>9.1f} {row['train_view_ms']:>9.1f} {row['cache_mb']:>9.2f} "
            f"{row['taps_mb']:>9.1f}"
        )
    if args.json:
        Path(args.json).write_text(json.dumps({"device": where, "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
