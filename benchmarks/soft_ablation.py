"""Ablation of the training renderer: the same methods trained through the exact
renderer and through the paper's soft rasteriser (:mod:`geoscaler.render.soft`), every result scored
by the exact renderer, as a GPU shows it (protocol 1: Q at 2.4, near 1.5, far 4.0).

Each learned run is scored twice, 8-bit, never replaced by a filter: as the method returns it
(the best state on the exact validation, which may be its Lanczos start: ``best_step`` 0) and
as its last step left it (``<method> (last)``, gutters filled as the loop fills them): the
paper keeps the last state, and only that one says what training through the soft renderer
alone does. The ``shipped`` column says what the job would ship
(:func:`geoscaler.pipeline.job.no_worse_than_filters`). Bicubic and Lanczos are scored beside them;
the gain is PSNR-fg over bicubic's on the same mesh, scale and set.

Usage:
    python benchmarks/soft_ablation.py [PATH ...] [--scale 4 8] [--methods direct,geoscaler-full]
        [--renderers exact,soft] [--steps N | --time-budget S] [--device cpu] [--out DIR]
        [--quick]
    python benchmarks/soft_ablation.py spot.obj --step-seconds 5   # seconds per training step

PATH: mesh files or folders, as ``geoscaler bench`` takes them (default: ../shared/data).
``--out`` writes ``results.json`` (every row) and ``results.md`` (mean PSNR-fg and gain per
scale, set, method and renderer, and seconds). The validation views are cached before the
runs, so a run's seconds are its own set-up, training and validations.

The soft renderer reaches the methods through the loop's settings
(``settings["optimize"]["training_renderer"] = "soft"``); the network's variants are the
registered aliases (``geoscaler-full``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

from entry import exit_status  # beside this script

from geoscaler.color import linear_to_texture, texture_to_linear
from geoscaler.io import load_mesh
from geoscaler.methods import MethodOptions, MethodResult, RunContext, Shipping, run_method
from geoscaler.methods.direct import TexelModel
from geoscaler.optim.adamw import AdamW
from geoscaler.optim.loop import TRAINING_RANGES, OptimizeConfig, finish, train_step
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.pipeline.job import no_worse_than_filters
from geoscaler.pipeline.rows import protocol_row
from geoscaler.protocol import (
    FAR_DISTANCE,
    NEAR_DISTANCE,
    PROTOCOL_EVALUATION,
    VALIDATION_DISTANCE,
    Evaluation,
)
from geoscaler.render.cameras import sample_training_cameras, spread_order, view_set_cameras
from geoscaler.render.renderer import Renderer, resolve_device
from geoscaler.render.soft import SoftSettings
from geoscaler.render.views import ViewCache, ViewSet, training_views
from geoscaler.report.bench import MeshEntry, find_meshes
from geoscaler.report.documents import method_details
from geoscaler.resize.filters import lanczos, output_sizes, reference_textures
from geoscaler.uv.uvmaps import reachable_masks

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DISTANCES = (VALIDATION_DISTANCE, NEAR_DISTANCE, FAR_DISTANCE)
FILTERS = ("bicubic", "lanczos")


def method_options(args, renderer_name: str) -> MethodOptions:
    loop = {"training_renderer": renderer_name}
    return MethodOptions(
        device=args.device,
        seed=args.seed,
        steps=args.steps,
        time_budget=args.time_budget,
        settings={"optimize": loop},
    )


def mesh_rows(entry: MeshEntry, args) -> list[dict]:
    """Every row of one mesh: filters and each (method, renderer), per scale and distance."""
    mesh = load_mesh(entry.path)
    renderer = Renderer(mesh, args.device, args.evaluation)
    protocol_sets = {}
    for distance in DISTANCES:  # the protocol's sets, cached once, Q's views in spread order
        cameras = view_set_cameras(distance, renderer.evaluation)
        cameras = [cameras[i] for i in spread_order(len(cameras))]
        protocol_sets[distance] = ViewSet(renderer, cameras)
    view_sets = validation_view_sets(renderer)
    rows = []
    for scale in args.scale:
        sizes = output_sizes(mesh, scale)
        caches = {d: ViewCache(views, sizes, with_taps=True) for d, views in protocol_sets.items()}
        filters = {name: run_method(name, mesh, scale) for name in FILTERS}
        validation = Validation(view_sets, sizes, {n: r.textures for n, r in filters.items()})
        validation.cache_all()  # before the runs: no run's seconds include it
        results = {(name, "-"): result for name, result in filters.items()}
        farthest = max(high for _, high in TRAINING_RANGES)
        masks = reachable_masks(mesh, sizes, farthest, renderer.resolution)
        reachable = [None if m is None else m.to(renderer.device) for m in masks]
        for renderer_name in args.renderers:
            for method in args.methods:
                state = []  # the loop's candidate(): the model's state when called (after the run)
                context = RunContext(
                    renderer,
                    validation,
                    on_event=lambda event, state=state: state.append(event.candidate),
                    time_budget=args.time_budget,
                )
                options = method_options(args, renderer_name)
                result = run_method(method, mesh, scale, options, context)
                no_worse_than_filters(method, result, validation, filters)  # sets "shipped"
                results[method, renderer_name] = result
                results[f"{method} (last)", renderer_name] = last_state(
                    next(c for c in reversed(state) if c), reachable, result
                )
                print(f"  {entry.name} x{scale} {method} {renderer_name}: {result.seconds:.1f} s")
        for distance, cache in caches.items():
            bicubic = None
            for (name, renderer_name), result in results.items():
                row = protocol_row(result, name, scale, distance, cache)
                row.update(mesh=entry.name, renderer=renderer_name)
                row["steps"] = method_details(result).get("steps")
                row["best_step"] = method_details(result).get("best_step")
                bicubic = row["psnr_fg"] if name == "bicubic" else bicubic
                rows.append(row)
            for row in rows[-len(results) :]:
                row["gain_db"] = row["psnr_fg"] - bicubic
    return rows


def last_state(candidate, reachable, result: MethodResult) -> MethodResult:
    """The model's last state as it would ship: gutters filled (where it keeps the UVs), 8-bit."""
    textures, uvs = candidate()
    if uvs is None:
        textures = finish(textures, reachable)
    textures = [None if t is None else linear_to_texture(t) for t in textures]
    uvs = None if uvs is None else uvs.cpu().numpy().astype("float32")
    return replace(result, textures=textures, uvs=uvs, shipping=Shipping("-"))


def table(rows: list[dict]) -> str:
    """Mean PSNR-fg (gain over bicubic) and seconds per scale, set, method and renderer."""
    groups = defaultdict(list)
    for row in rows:
        groups[row["scale"], row["distance"], row["method"], row["renderer"]].append(row)
    lines = [
        "| scale | set | method | trained through | meshes | PSNR-fg (dB) | gain (dB) | seconds |",
        "| --- | --- | --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for (scale, distance, method, renderer), group in sorted(groups.items()):
        psnr = statistics.fmean(r["psnr_fg"] for r in group)
        gain = statistics.fmean(r["gain_db"] for r in group)
        seconds = statistics.fmean(r["seconds"] for r in group)
        lines.append(
            f"| x{scale} | {distance:g} | {method} | {renderer} | {len(group)} | {psnr:.2f} | "
            f"{gain:+.2f} | {seconds:.1f} |"
        )
    return "\n".join(lines)


def step_seconds(entry: MeshEntry, args) -> None:
    """Seconds per training step of ``direct`` (4 views, forward and backward, AdamW) through
    the exact and the soft renderer, each with cached taps (as ``direct`` trains) and rendered
    in full (as methods that move UVs train), at the protocol's image size, and the seconds to
    cache one training view (taps included). Steps of the four alternate, round after round,
    so that a busy machine's drift falls on all alike."""
    mesh = load_mesh(entry.path)
    renderer = Renderer(mesh, args.device)
    scale = args.scale[0]
    cameras = sample_training_cameras(4, args.seed, TRAINING_RANGES)
    sizes = output_sizes(mesh, scale)
    starts = [None if t is None else lanczos(t, scale) for t in reference_textures(mesh)]
    config = OptimizeConfig(lr=0.005, ssim_weight=0.0)
    kinds = {
        "exact (taps)": (True, None),
        "exact (full render)": (False, None),
        "soft (taps)": (True, SoftSettings()),
        "soft (full render)": (False, SoftSettings()),
    }
    runs, seconds = {}, defaultdict(list)
    for kind, (taps, soft) in kinds.items():
        train = training_views(renderer, cameras, sizes, taps, soft)
        started = time.perf_counter()
        for view in range(len(cameras)):
            train.views.cache_next()
            train.find_taps(view)
        caching = (time.perf_counter() - started) / len(cameras)
        model = TexelModel(
            [None if t is None else texture_to_linear(t, renderer.device) for t in starts]
        )
        runs[kind] = train, model, AdamW(model.parameters(), lr=config.lr), caching
    for _ in range(args.step_seconds):
        for kind, (train, model, optimizer, _) in runs.items():
            started = time.perf_counter()
            train_step(train, model, optimizer, [0, 1, 2, 3], config, lambda: 1.0)
            seconds[kind].append(time.perf_counter() - started)
    for kind, (train, _, _, caching) in runs.items():
        extra = ""
        if kinds[kind][1] is not None:
            mb = statistics.fmean(g.nbytes for g in train.views.gbuffers) / 1e6
            extra = f", {mb:.0f} MB of fragments per view"
        print(
            f"{entry.name} x{scale} {kind}: step {statistics.median(seconds[kind]):.3f} s "
            f"(median of {len(seconds[kind])}: {', '.join(f'{s:.3f}' for s in seconds[kind])}), "
            f"caching {caching:.2f} s per view{extra}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="*", type=Path, default=[DATA])
    parser.add_argument("--scale", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--methods", default="direct,geoscaler-full")
    parser.add_argument("--renderers", default="exact,soft")
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--time-budget", type=float, default=None)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="3 views of 128 px: a smoke test")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--step-seconds", type=int, default=0, metavar="N", help="time N steps of each renderer"
    )
    args = parser.parse_args()
    args.methods = args.methods.split(",")
    args.renderers = args.renderers.split(",")
    args.device = str(resolve_device(args.device))
    args.evaluation = Evaluation.quick((0, 20, 40)) if args.quick else PROTOCOL_EVALUATION
    meshes = find_meshes(args.paths)
    if args.step_seconds:
        step_seconds(meshes[0], args)
        return
    rows = []
    started = time.perf_counter()
    for entry in meshes:
        print(entry.path)
        rows.extend(mesh_rows(entry, args))
    print(table(rows))
    print(f"{time.perf_counter() - started:.0f} s wall, device {args.device}")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps(rows, indent=1))
        (args.out / "results.md").write_text(table(rows) + "\n")


if __name__ == "__main__":
    sys.exit(exit_status(main))
