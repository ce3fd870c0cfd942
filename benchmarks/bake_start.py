"""Where a new layout starts: the bake of the original into each layout the job plans,
against Lanczos in the mesh's own layout, view by view on the protocol's sets (protocol 1).

A plan that gives some charts fewer texels than their own layout starves the views that look
at them: the mean over a set hides that, its worst views show it. Per mesh, scale and planned
layout (aligned where the far views minify, then the unaligned one, as the job offers them)
this prints ``k`` and, per set, the mean gain of the bake over Lanczos (dB, PSNR-fg) and its
10th percentile over the views. No training: a few seconds a mesh and scale. To compare two
planning rules on the same views, copy it (with ``entry.py``) into another tree's
``benchmarks/`` and run it there too, that tree first on the path (``PYTHONPATH=.`` from its
root).

Usage:
    python benchmarks/bake_start.py [PATH ...] [--scale 4 8] [--views 30] [--device cpu]
        [--json OUT]

PATH: mesh files or folders (default: ../shared/data; a missing folder skips cleanly).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys

import numpy as np
from entry import exit_status  # beside this script
from layout_bounds import planning_arguments  # beside this script, in older trees too

from geoscaler.io import load_mesh
from geoscaler.methods import MethodOptions, RunContext
from geoscaler.methods.direct import DEFAULT_CONFIG
from geoscaler.methods.learned import loop_config
from geoscaler.methods.registry import output_sizes_for
from geoscaler.methods.repacked import PlanningViews, baked_maps, plan_layout
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.cameras import view_set_cameras
from geoscaler.render.metrics import psnr_fg
from geoscaler.render.renderer import Renderer
from geoscaler.resize.filters import lanczos
from geoscaler.resize.sizes import SizeRule

SETS = {"Q": 2.4, "near": 1.5, "far": 4.0}


def view_scores(renderer: Renderer, views: list, textures: list, uvs=None) -> np.ndarray:
    """``(V,)`` PSNR-fg of ``textures`` (uint8, per material) on each of ``views``
    (G-buffer, reference, foreground), rendered on ``uvs`` (None: the mesh's own)."""
    chains = renderer.mip_textures([None if t is None else t[..., :3] for t in textures])
    scores = [psnr_fg(renderer.render(g, chains, uvs)[None], r[None], f[None]) for g, r, f in views]
    return np.array([float(score) for score in scores])


def mesh_rows(entry, scales: list[int], count: int, device: str) -> list[dict]:
    """One row per scale and planned layout."""
    mesh = load_mesh(entry.path)
    renderer = Renderer(mesh, device, PROTOCOL_EVALUATION)
    config = loop_config(DEFAULT_CONFIG, MethodOptions(device=device), RunContext())
    planning = PlanningViews(renderer, config)
    step = max(1, len(view_set_cameras(2.4, PROTOCOL_EVALUATION)) // count)
    sets = {}
    for name, distance in SETS.items():
        cameras = view_set_cameras(distance, PROTOCOL_EVALUATION)[::step]
        sets[name] = [renderer.cached_view(camera) for camera in cameras]
    references = renderer.reference_maps()
    rows = []
    for scale in scales:
        rule = SizeRule(scale=scale)
        sizes = output_sizes_for(mesh, rule, renderer)
        own = [None if r is None else lanczos(r, s) for r, s in zip(references, sizes, strict=True)]
        start = {name: view_scores(renderer, views, own) for name, views in sets.items()}
        for align in (True, False):
            atlas = plan_layout(mesh, rule, renderer, config, None, align, planning)
            if not atlas.moved:
                rows.append({"mesh": entry.name, "scale": scale, "kept": atlas.kept})
                break
            baked = baked_maps(mesh, atlas, references, sizes)
            baked = [b if b is not None else o for b, o in zip(baked, own, strict=True)]
            uvs = renderer.relaid(atlas.uvs).uvs
            row = {"mesh": entry.name, "scale": scale, "aligned": atlas.aligned,
                   "k": round(atlas.facts.k, 3)}  # fmt: skip
            for name, views in sets.items():
                gains = view_scores(renderer, views, baked, uvs) - start[name]
                gains = gains[np.isfinite(gains)]
                row[name] = round(float(gains.mean()), 3)
                row[f"{name}_p10"] = round(float(np.percentile(gains, 10)), 3)
            rows.append(row)
            print(f"# {row}", file=sys.stderr, flush=True)
            if not atlas.aligned:
                break
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| mesh | x | layout | k | " + " | ".join(f"{s} mean (p10)" for s in SETS) + " |",
        "| --- | ---: | --- | ---: |" + " ---: |" * len(SETS),
    ]
    for r in rows:
        if "k" not in r:
            lines.append(f"| {r['mesh']} | {r['scale']} | kept: {r['kept']} | | | | |")
            continue
        cells = " | ".join(f"{r[s]:+.2f} ({r[f'{s}_p10']:+.2f})" for s in SETS)
        layout = "aligned" if r["aligned"] else "unaligned"
        lines.append(f"| {r['mesh']} | {r['scale']} | {layout} | {r['k']:.2f} | {cells} |")
    for scale in sorted({r["scale"] for r in rows}):
        part = [r for r in rows if r["scale"] == scale and "k" in r]
        if part:
            cells = " | ".join(
                f"{statistics.fmean(r[s] for r in part):+.2f} "
                f"({statistics.fmean(r[f'{s}_p10'] for r in part):+.2f})"
                for s in SETS
            )
            lines.append(f"| **mean of {len(part)} layouts** | {scale} | | | {cells} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=30, help="views a set (of 60)")
    args, meshes = planning_arguments(parser.description, parser)
    if not meshes:
        return 0
    rows = [r for entry in meshes for r in mesh_rows(entry, args.scale, args.views, args.device)]
    print(table(rows))  # not layout_bounds.emit: the script runs in older trees, without it
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(exit_status(main))
