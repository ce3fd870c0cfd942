"""How far `direct`'s loop gets in its first steps: Adam from Lanczos against the majorised start.

For each mesh, the training pool (``--pool`` cameras over the loop's training range) and 20 views of
the protocol's Q (every third) are cached first, so that only the steps differ. Then the loop
(:func:`geoscaler.optim.loop.optimize`, no time budget, no backtracking) runs N steps for each
setting and N, from the same Lanczos start, and the candidate after its last step is scored on
those Q views, 8-bit as it ships; printed as the gain over bicubic in dB.

Settings: ``adam``: AdamW at 0.02 from the first step (3 warm-up steps; `direct` before the
majorised start, without its boost for short runs); ``direct``: `direct`'s defaults (its first
``majorized_steps`` majorise-minimise steps, then AdamW).

Usage:
    python benchmarks/first_steps.py [PATH ...] [--scale 4] [--steps 5 20 80]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from entry import exit_status  # beside this script

from geoscaler.io import load_mesh
from geoscaler.methods import run_method
from geoscaler.methods.direct import DEFAULT_CONFIG, lanczos_texel_model
from geoscaler.methods.registry import RunContext
from geoscaler.optim.loop import TRAINING_RANGES, LoopSetup, OptimizeConfig, optimize
from geoscaler.optim.validation import Validation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.cameras import sample_training_cameras, view_set_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.views import ViewSet, training_views
from geoscaler.report.bench import find_meshes
from geoscaler.resize.filters import output_sizes

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SETTINGS = {
    "adam": {"lr": 0.02, "warmup_steps": 3, "majorized_steps": 0},
    "direct": {key: DEFAULT_CONFIG[key] for key in ("lr", "warmup_steps", "majorized_steps")},
}


def gains(path: Path, scale: int, steps: list[int], pool_views: int) -> dict[str, list[float]]:
    """Setting -> gain over bicubic on the Q views after each number of ``steps``."""
    mesh = load_mesh(path)
    renderer = Renderer(mesh, "cpu", PROTOCOL_EVALUATION)
    sizes = output_sizes(mesh, scale, PROTOCOL_EVALUATION.reference_max_size)
    q_cameras = view_set_cameras(2.4, PROTOCOL_EVALUATION)[::3]
    validation = Validation({"Q": ViewSet(renderer, q_cameras)}, sizes)
    validation.cache_all()
    validation.freeze()
    cameras = sample_training_cameras(pool_views, 0, TRAINING_RANGES)
    pool = training_views(renderer, cameras, sizes, True)
    while pool.views.cache_next():
        pass
    context = RunContext(renderer=renderer)
    bicubic = run_method("bicubic", mesh, scale, context=context).textures
    floor = validation.sets["Q"].score(bicubic)["psnr_fg"].mean().item()
    found: dict[str, list[float]] = {}
    for name, setting in SETTINGS.items():
        for count in steps:
            config = OptimizeConfig(
                steps=count, ssim_weight=0.0, validate_every=count, seed=0, **setting
            )
            model = lanczos_texel_model(mesh, scale, renderer)
            result = optimize(renderer, model, config, validation, LoopSetup(pool=pool))
            found.setdefault(name, []).append(result.history[-1]["validation_psnr_fg"] - floor)
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("paths", nargs="*", default=[str(DATA)])
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--steps", type=int, nargs="+", default=[5, 20, 80])
    parser.add_argument(
        "--pool", type=int, default=48, help="training views (a short budget caches few)"
    )
    args = parser.parse_args()
    print(
        f"gain over bicubic on 20 Q views after {args.steps} steps, x{args.scale}, "
        f"{args.pool} training views"
    )
    for entry in find_meshes(args.paths):
        started = time.perf_counter()
        found = gains(entry.path, args.scale, args.steps, args.pool)
        cells = "   ".join(
            f"{name} " + " / ".join(f"{g:+.2f}" for g in values) for name, values in found.items()
        )
        print(f"{entry.path.parent.name:28} {cells}   {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(exit_status(main))
