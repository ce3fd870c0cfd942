"""The texel ceiling: how far any texture of the candidate's size could go on a view set.

`direct` trains free texels on random training views and is scored on the protocol's view
set. Here the same texels (same start, same loop, same renderer) are trained on the scored
views themselves, which no method may do: the result bounds from above, up to the optimiser's
convergence, what any texture of that size on the mesh's own UVs can reach on that set. The gap
between a method's gain and the ceiling's says how much is left to find by optimising texels;
a target above the ceiling can only be reached by changing the UVs.

Usage:
    python benchmarks/texel_ceiling.py [PATH ...] [--scale 4 8] [--distance 2.4]
        [--steps 300] [--lr 0.01] [--json OUT.json] [--product]

PATH: mesh files or folders, as `geoscaler bench` takes them (default: ../shared/data).
Prints, per mesh and scale, PSNR-fg of bicubic and the gains over it of Lanczos and of the
ceiling (8-bit textures, protocol 1), then their means.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch
from entry import exit_status  # beside this script

from geoscaler.color import linear_to_texture
from geoscaler.io import load_mesh
from geoscaler.methods import run_method
from geoscaler.methods.direct import lanczos_texel_model
from geoscaler.methods.registry import RunContext
from geoscaler.optim.loop import LoopSetup, OptimizeConfig, optimize
from geoscaler.optim.validation import Validation
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.cameras import validation_cameras
from geoscaler.render.renderer import Renderer, resolve_device
from geoscaler.render.views import ViewCache, ViewSet
from geoscaler.report.bench import find_meshes
from geoscaler.resize.filters import output_sizes

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def ceiling_row(
    path: Path, scale: int, distance: float, steps: int, lr: float, device, product: bool
) -> dict:
    """Bicubic's PSNR-fg and the gains of Lanczos and of the texel ceiling on one mesh.

    ``product``: as `geoscaler downsample` works (sizes and reference images from the
    full-resolution originals), not the protocol's originals reduced to 2048."""
    mesh = load_mesh(path)
    evaluation = product_evaluation(PROTOCOL_EVALUATION) if product else PROTOCOL_EVALUATION
    renderer = Renderer(mesh, device, evaluation)
    cameras = validation_cameras(distance)
    sizes = output_sizes(mesh, scale, evaluation.reference_max_size)
    views = ViewCache(ViewSet(renderer, cameras), sizes, with_taps=True)
    psnr = {}
    for name in ("bicubic", "lanczos"):
        textures = run_method(name, mesh, scale, context=RunContext(renderer=renderer)).textures
        psnr[name] = float(views.score(textures)["psnr_fg"].mean())
    start = time.perf_counter()
    config = OptimizeConfig(steps=steps, lr=lr, ssim_weight=0.0, validate_every=steps)
    model = lanczos_texel_model(mesh, scale, renderer)
    validation = Validation({"Q": views.views}, views.sizes)  # Q alone: no floor, no guards
    result = optimize(renderer, model, config, validation, LoopSetup(training_cameras=cameras))
    textures = [None if t is None else linear_to_texture(t) for t in result.textures]
    psnr["ceiling"] = float(views.score(textures)["psnr_fg"].mean())
    return {
        "mesh": path.parent.name,
        "scale": scale,
        "distance": distance,
        "bicubic_psnr_fg": psnr["bicubic"],
        "lanczos_gain": psnr["lanczos"] - psnr["bicubic"],
        "ceiling_gain": psnr["ceiling"] - psnr["bicubic"],
        "steps": steps,
        "references": "full resolution" if product else "protocol (2048)",
        "seconds": time.perf_counter() - start,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("paths", nargs="*", default=[str(DATA)])
    parser.add_argument("--scale", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--distance", type=float, default=2.4)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--lr", type=float, default=0.01)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--json", help="also write the rows here")
    parser.add_argument(
        "--product",
        action="store_true",
        help="sizes and references from the full-resolution originals, as the job ships",
    )
    args = parser.parse_args()
    device = resolve_device(args.device)
    meshes = find_meshes(args.paths)
    print(f"texel ceiling on {device.type}, {torch.get_num_threads()} threads, {args.steps} steps")
    print(f"{'mesh':28} {'scale':>5} {'bicubic':>8} {'lanczos':>8} {'ceiling':>8} {'s':>6}")
    rows = []
    for entry in meshes:
        for scale in args.scale:
            row = ceiling_row(
                entry.path, scale, args.distance, args.steps, args.lr, device, args.product
            )
            rows.append(row)
            print(
                f"{row['mesh']:28} {scale:>5} {row['bicubic_psnr_fg']:>8.2f} "
                f"{row['lanczos_gain']:>+8.2f} {row['ceiling_gain']:>+8.2f} {row['seconds']:>6.0f}",
                flush=True,
            )
    for scale in args.scale:
        mine = [r for r in rows if r["scale"] == scale]
        lanczos = statistics.mean(r["lanczos_gain"] for r in mine)
        ceiling = statistics.mean(r["ceiling_gain"] for r in mine)
        print(f"{'mean':28} {scale:>5} {'':>8} {lanczos:>+8.2f} {ceiling:>+8.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(exit_status(main))
