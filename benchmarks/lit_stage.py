"""The lit stage's settings: how lit validation scores move with the steps, per setting.

Usage:
    python benchmarks/lit_stage.py [MESH ...] [--scale 4] [--steps 80] [--lr 0.002]
        [--views-per-step 4] [--pool 48] [--training-share 0.75]

Per mesh: the lit stage's loop (:mod:`geoscaler.optim.lit`) from the class filters with Lanczos
base colours and Toksvig roughness, Lanczos-every-map as its baseline, every view of the
training pool cached first (so that steps, not caching, are compared); every 10 steps the
mean training loss over the pool (dB) and the lit PSNR-fg of the maps as they ship on the
validation sets (8 views each), and the protocol-1 (unlit) PSNR-fg of the base colour on 8 Q
views. A pool too small for the maps shows as a training loss that
keeps falling while the validation turns back. Also the bytes the pool and the sets hold.

Without MESH: the PBR development meshes in ../shared/data (skipped cleanly when absent).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from lit_maps import DATA, PBR_MESHES  # the PBR development meshes, beside this script

from geoscaler.io import load_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.optim.lit import LitRun, LitSettings
from geoscaler.pipeline.shipping import every_map_by, ship_asset
from geoscaler.protocol import VALIDATION_DISTANCE, Evaluation
from geoscaler.render.cameras import Camera, spread_order, validation_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewSet
from geoscaler.resize.filters import lanczos, output_sizes
from geoscaler.resize.sizes import SizePlan, SizeRule


def unlit(original: TexturedMesh, candidate: TexturedMesh, cameras: list[Camera]) -> float:
    """Protocol 1's PSNR-fg (unlit base colour, full-size references) on ``cameras``."""
    renderer = Renderer(original, "cpu", Evaluation(reference_max_size=None))
    views = ViewSet(renderer, cameras)
    bases = [m.base_color_texture for m in candidate.materials]
    return float(views.score(bases)["psnr_fg"].mean())


def trace(path: Path, scale: int, steps: int, settings: LitSettings) -> None:
    mesh = load_mesh(path)
    rule = SizeRule(scale=scale)
    plan = SizePlan(rule, rule, rule)
    originals = [m.base_color_texture for m in mesh.materials]
    sizes = output_sizes(mesh, rule, None)
    bases = [None if t is None else lanczos(t, s) for t, s in zip(originals, sizes, strict=True)]
    start = ship_asset(mesh, plan, bases, "lanczos")[0]
    baselines = {"lanczos": every_map_by(mesh, plan, "lanczos")}
    evaluation = Evaluation(reference_max_size=None)
    began = time.perf_counter()
    run = LitRun(mesh, start, baselines, settings, "cpu", evaluation)
    run.begin()
    while run.pool.cache_next():
        pass
    print(f"{path.parent.name} x{scale}: views cached in {time.perf_counter() - began:.1f} s")
    for name, scores in run.scores.items():
        print(f"  {name:8s} " + "  ".join(f"{k} {v:.3f}" for k, v in scores.items()))

    def training_db() -> float:
        with torch.no_grad():
            materials = run.maps.materials()
            losses = [float(run.pool.loss(i, materials)) for i in range(len(run.pool))]
        return float(np.mean(10 * np.log10(losses)))

    cameras = [validation_cameras(VALIDATION_DISTANCE)[i] for i in spread_order(60)[:8]]
    print(f"  step   0 training {training_db():.3f} dB  unlit Q {unlit(mesh, start, cameras):.3f}")
    began = time.perf_counter()
    while run.facts.steps < steps:
        run.step(cache=False)
        if run.facts.steps % 10 == 0:
            seconds = (time.perf_counter() - began) / run.facts.steps
            asset = run.maps.asset()
            scores = run.score(asset)
            print(
                f"  step {run.facts.steps:3d} training {training_db():.3f} dB  "
                + "  ".join(f"{k} {v:.3f}" for k, v in scores.items())
                + f"  unlit Q {unlit(mesh, asset, cameras):.3f}  ({seconds:.2f} s a step)",
                flush=True,
            )
    held = run.pool.nbytes, sum(views.nbytes for views in run.sets.values())
    print(f"  pool {held[0] / 1e6:.0f} MB ({len(run.pool)} views), sets {held[1] / 1e6:.0f} MB")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("meshes", type=Path, nargs="*")
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--steps", type=int, default=80)
    defaults = LitSettings()
    parser.add_argument("--lr", type=float, default=defaults.lr)
    parser.add_argument("--views-per-step", type=int, default=defaults.views_per_step)
    parser.add_argument("--pool", type=int, default=defaults.pool_views)
    parser.add_argument("--training-share", type=float, default=defaults.training_share)
    parser.add_argument("--keep", nargs="*", default=[], help="slots not trained")
    args = parser.parse_args()
    settings = LitSettings(
        lr=args.lr,
        views_per_step=args.views_per_step,
        pool_views=args.pool,
        training_share=args.training_share,
        view_memory=None,
        kept=tuple(args.keep),
    )
    for path in args.meshes or [DATA / entry for entry in PBR_MESHES]:
        if not path.exists():
            print(f"no mesh at {path}: skipped", file=sys.stderr)
            continue
        trace(path, args.scale, args.steps, settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())
