"""Seconds per training step of ``direct``, as its loop takes them: K views rendered from cached
taps, the default loss, backward, AdamW.

For each mesh it caches ``--pool`` training views at the loop's training distances (timed: the
G-buffer and reference render of each view, then its taps), takes a few steps to warm up (the
first backward pass through a view also makes its taps' transpose), then times ``--steps``
steps of ``--views`` views each and prints the medians.

To compare two versions, run this file from each checkout in turn, interleaved, with the same
arguments (timings on a shared machine drift between runs):

    for i in 1 2; do for tree in OLD NEW; do
        PYTHONPATH=$tree python $tree/benchmarks/train_step.py MESH ...; done; done

Usage:
    python benchmarks/train_step.py MESH [MESH ...] [--scale 4] [--views 4] [--pool 8]
        [--steps 10]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from geoscaler.io import load_mesh
from geoscaler.methods.direct import DEFAULT_CONFIG, lanczos_texel_model
from geoscaler.optim.adamw import AdamW
from geoscaler.optim.loop import TRAINING_RANGES, OptimizeConfig, train_step
from geoscaler.pipeline.arguments import check_rules
from geoscaler.process import configure_process
from geoscaler.render.cameras import sample_training_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import training_views
from geoscaler.resize.filters import output_sizes


def step_seconds(
    path: str, scale: int, views: int, pool: int, steps: int
) -> tuple[list[float], list[float], list[float]]:
    """Seconds of each view's G-buffer and reference, of each view's taps, and of each of
    ``steps`` timed training steps on the mesh at ``path``."""
    mesh = load_mesh(path)
    renderer = Renderer(mesh, "cpu")
    (rule,) = check_rules([scale])
    sizes = output_sizes(mesh, rule, renderer.evaluation.reference_max_size)
    cache = training_views(
        renderer, sample_training_cameras(pool, 0, TRAINING_RANGES), sizes, with_taps=True
    )
    view_seconds, tap_seconds = [], []
    while True:
        started = time.perf_counter()
        if not cache.views.cache_next():
            break
        cached = time.perf_counter()
        cache.find_taps(len(cache) - 1)
        view_seconds.append(cached - started)
        tap_seconds.append(time.perf_counter() - cached)
    model = lanczos_texel_model(mesh, rule, renderer)
    config = OptimizeConfig(ssim_weight=DEFAULT_CONFIG["ssim_weight"])
    optimizer = AdamW(model.parameters(), lr=1e-3)
    order = [list(range(i, i + views)) for i in range(0, pool - views + 1, views)]
    for chosen in order:  # warm-up: every view's first backward pass
        train_step(cache, model, optimizer, chosen, config, lambda: 1.0)
    seconds = []
    for index in range(steps):
        started = time.perf_counter()
        train_step(cache, model, optimizer, order[index % len(order)], config, lambda: 1.0)
        seconds.append(time.perf_counter() - started)
    return view_seconds, tap_seconds, seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("meshes", nargs="+")
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--pool", type=int, default=8)
    parser.add_argument("--steps", type=int, default=10)
    args = parser.parse_args()
    configure_process()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    for path in args.meshes:
        views, taps, steps = step_seconds(path, args.scale, args.views, args.pool, args.steps)
        print(
            f"{path}: median s per view {statistics.median(views):.4f} (G-buffer, reference) "
            f"+ {statistics.median(taps):.4f} (taps); per step of {args.views} views "
            f"{statistics.median(steps):.4f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
