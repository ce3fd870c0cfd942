"""What caching one view costs, piece by piece: its G-buffer, its reference render and its taps.

For every mesh this loads it as `geoscaler downsample` does (originals at full resolution, the
product's output sizes for ``--scale``), then times, over the first ``--views`` cameras of the
protocol's Q set, ``Renderer.rasterize``, ``Renderer.render_reference`` and
``ViewCache.find_taps``, and prints milliseconds a view of each, the covered samples a view and
the taps kept (after merging). To compare two trees, run it once with each on ``PYTHONPATH``,
interleaved.

Usage:
    python benchmarks/view_caching.py [PATH ...] [--scale 4] [--views 12]

PATH: mesh files or folders (default: ../shared/data).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from entry import exit_status  # beside this script

from geoscaler.io import load_mesh
from geoscaler.methods.registry import output_sizes_for
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.cameras import view_set_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewCache, ViewSet
from geoscaler.report.bench import find_meshes
from geoscaler.resize.sizes import SizeRule

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def view_costs(path: Path, scale: int, views: int) -> dict:
    """Milliseconds a view of each piece of caching ``views`` cameras of Q for ``path``."""
    mesh = load_mesh(path)
    renderer = Renderer(mesh, "cpu", product_evaluation(PROTOCOL_EVALUATION))
    sizes = output_sizes_for(mesh, SizeRule(scale=scale), renderer)
    renderer.reference_textures()  # made once a job, not a view's cost
    cameras = view_set_cameras(2.4, PROTOCOL_EVALUATION)[:views]
    started = time.perf_counter()
    gbuffers = [renderer.rasterize(camera) for camera in cameras]
    rasterized = time.perf_counter()
    references = [renderer.render_reference(gbuffer) for gbuffer in gbuffers]
    referenced = time.perf_counter()
    renderer.view_memo = {  # the view set takes these views instead of rendering them again
        (camera.direction, camera.distance): (gbuffer, reference, renderer.foreground(gbuffer))
        for camera, gbuffer, reference in zip(cameras, gbuffers, references, strict=True)
    }
    cache = ViewCache(ViewSet(renderer, cameras), sizes, with_taps=True)
    tapped_from = time.perf_counter()
    cache.find_taps(len(cameras) - 1)
    tapped = time.perf_counter()
    taps = [t for view in cache.taps for t in view if t is not None]
    return {
        "mesh": path.parent.name,
        "scale": scale,
        "gbuffer_ms": round(1e3 * (rasterized - started) / views, 1),
        "reference_ms": round(1e3 * (referenced - rasterized) / views, 1),
        "taps_ms": round(1e3 * (tapped - tapped_from) / views, 1),
        "samples": sum(g.num_samples for g in gbuffers) // views,
        "taps": sum(t.weight.numel() for t in taps) // views,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("paths", nargs="*", default=[str(DATA)])
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--views", type=int, default=12)
    args = parser.parse_args()
    for entry in find_meshes(args.paths):
        print(json.dumps(view_costs(entry.path, args.scale, args.views)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(exit_status(main))
