"""Renderer benchmark: rasterise, sample from the cache, and cache size per protocol view.

Usage:
    python benchmarks/bench_renderer.py [--views 12] [--threads N] [--device auto|cpu|cuda]
        [--json OUT.json] [MESH ...]

With no MESH it measures the procedural demo mesh at 19,200 faces and, when ../shared/data is
present, the 16,384-face YCB scans. Figures are medians over validation views 0..views-1:
  raster   one 1024 x 1024 G-buffer (2 x 2 supersampling of the 512 x 512 view)
  sample   shade every covered sample from the cache and resolve to 512 x 512 (forward only)
  train    the same with gradients to the texels and the backward pass
  cache    bytes held by one view's G-buffer
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

from geoscaler.cameras import validation_cameras
from geoscaler.mesh import TexturedMesh, load_mesh
from geoscaler.procedural import demo_mesh
from geoscaler.render import Renderer, resolve_device
from geoscaler.texture import MipTexture

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DEFAULT_SCANS = ["ycb_lego_duplo_a/textured.obj", "ycb_chain/textured.obj"]


def _timed(fn, device: torch.device) -> float:
    if device.type == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    fn()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - start


def bench_mesh(name: str, mesh: TexturedMesh, views: int, device: torch.device) -> dict:
    renderer = Renderer(mesh, device)
    reference = renderer.reference_textures()
    cameras = validation_cameras()[:views]
    renderer.rasterize(cameras[0])  # warm-up
    raster, sample, train, cache, samples = [], [], [], [], []
    texels = torch.rand(*mesh.materials[0].base_color_texture.shape[:2], 3, device=device)
    texels.requires_grad_(True)
    for camera in cameras:
        start = time.perf_counter()
        gbuffer = renderer.rasterize(camera)
        if device.type == "cuda":
            torch.cuda.synchronize()
        raster.append(time.perf_counter() - start)
        cache.append(gbuffer.nbytes)
        samples.append(gbuffer.num_samples)
        with torch.no_grad():
            sample.append(_timed(lambda g=gbuffer: renderer.render(g, reference), device))

        def step(g=gbuffer):
            image = renderer.render(g, [MipTexture(texels)])
            image.square().mean().backward()

        train.append(_timed(step, device))
    return {
        "mesh": name,
        "faces": len(mesh.faces),
        "texture": list(mesh.materials[0].base_color_texture.shape[:2]),
        "covered_samples": int(statistics.median(samples)),
        "raster_s": statistics.median(raster),
        "sample_ms": 1000 * statistics.median(sample),
        "train_step_ms": 1000 * statistics.median(train),
        "cache_mb": statistics.median(cache) / 1e6,
    }


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
        cases.append(("procedural demo (40 x 40 per chart)", demo_mesh(subdivisions=40)))
        cases += [
            (s.split("/")[0], load_mesh(DATA / s)) for s in DEFAULT_SCANS if (DATA / s).exists()
        ]

    cpu = platform.processor() or platform.machine()
    where = f"{device.type}, {torch.get_num_threads()} threads, {cpu}"
    print(f"renderer benchmark on {where}; medians over {args.views} validation views")
    columns = ["faces", "samples", "raster s", "sample ms", "train ms", "cache MB"]
    print(f"{'mesh':38} " + " ".join(f"{c:>9}" for c in columns))
    results = []
    for name, mesh in cases:
        row = bench_mesh(name, mesh, args.views, device)
        results.append(row)
        print(
            f"{name:38} {row['faces']:>7,} {row['covered_samples']:>8,} {row['raster_s']:>9.3f} "
            f"{row['sample_ms']:>10.1f} {row['train_step_ms']:>9.1f} {row['cache_mb']:>9.2f}"
        )
    if args.json:
        Path(args.json).write_text(json.dumps({"device": where, "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
