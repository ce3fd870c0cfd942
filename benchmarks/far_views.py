"""Why a texture loses far away: PSNR-fg on the first views of the
protocol's sets, per distance, of bicubic on the mesh's own UVs against the new layout's bake
alone, or against whole textures resized by bicubic to other sizes.

Usage:
    python benchmarks/far_views.py MESH [--scale 4] [--product] [--views 6]
        [--distance 4.0 2.4 1.5] [--sizes 512 724]

Without ``--sizes``: the layout `--uv repack` plans (:func:`plan_layout`, aligned where the far
views minify) and its bake. With ``--sizes``: bicubic of the reference map to each size, own UVs
(a non-power-of-two ratio to the reference is a texture whose mip blocks are not the
original's). A missing mesh skips cleanly.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from bake_start import view_scores  # beside this script

from geoscaler.io import load_mesh
from geoscaler.methods.direct import DEFAULT_CONFIG
from geoscaler.methods.learned import loop_config
from geoscaler.methods.registry import MethodOptions, RunContext, output_sizes_for
from geoscaler.methods.repacked import baked_maps, plan_layout
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.cameras import view_set_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.resize.filters import bicubic
from geoscaler.resize.sizes import SizeRule


def mean_psnr(renderer: Renderer, views: list, textures: list, uvs=None) -> float:
    """Mean PSNR-fg of ``textures`` (uint8, per material) over ``views`` (G-buffer, reference,
    foreground), rendered on ``uvs`` (None: the mesh's own): :func:`bake_start.view_scores`'
    mean."""
    return float(np.mean(view_scores(renderer, views, textures, uvs)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", type=Path)
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--product", action="store_true", help="references at full size")
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument("--distance", type=float, nargs="+", default=[4.0, 2.4, 1.5])
    parser.add_argument("--sizes", type=int, nargs="+")
    args = parser.parse_args()
    if not args.mesh.exists():
        print(f"no mesh at {args.mesh}: skipped", file=sys.stderr)
        return 0
    mesh = load_mesh(args.mesh)
    evaluation = product_evaluation(PROTOCOL_EVALUATION) if args.product else PROTOCOL_EVALUATION
    renderer = Renderer(mesh, "cpu", evaluation)
    rule = SizeRule(scale=args.scale)
    sizes = output_sizes_for(mesh, rule, renderer)
    references = renderer.reference_maps()
    own = [None if r is None else bicubic(r, s) for r, s in zip(references, sizes, strict=True)]
    candidates = {}
    if args.sizes:
        for side in args.sizes:
            candidates[f"bicubic {side}"] = (
                [None if r is None else bicubic(r, (side, side)) for r in references],
                None,
            )
    else:
        config = loop_config(DEFAULT_CONFIG, MethodOptions(device="cpu"), RunContext())
        atlas = plan_layout(mesh, rule, renderer, config)
        baked = baked_maps(mesh, atlas, references, sizes)
        baked = [b if b is not None else o for b, o in zip(baked, own, strict=True)]
        print(f"layout: k {atlas.facts.k}, aligned to {atlas.facts.alignment_texels}")
        candidates["bake"] = (baked, renderer.relaid(atlas.uvs).uvs)  # (F, 3, 2) corners
    for distance in args.distance:
        views = []
        for camera in view_set_cameras(distance, evaluation)[: args.views]:
            g = renderer.rasterize(camera)
            views.append((g, renderer.render_reference(g), renderer.foreground(g)))
        line = f"distance {distance}: bicubic {mean_psnr(renderer, views, own):.2f}"
        for name, (textures, uvs) in candidates.items():
            line += f", {name} {mean_psnr(renderer, views, textures, uvs):.2f}"
        print(line + " dB PSNR-fg", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
