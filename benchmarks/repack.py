"""Repacking the atlas (issue 17): bicubic, `direct` on the mesh's own UVs, the bake alone on
the new layout, and repack + `direct`, per development mesh and scale, protocol 1.

Every method runs through the job's own comparison (`geoscaler.job.compare_mesh`), as `geoscaler
bench` runs it: the same cached views, validation and scoring, references always the original
maps on the original UVs, every learned method under the same time budget. The bake alone is
registered here as a filter (it is what repack + `direct` starts from, not validated); the
repacked layout is planned on training views only.

Usage:
    python benchmarks/repack.py [PATH ...] [--scale 4 8] [--time-budget 60]
        [--distance 2.4 [1.5 4.0]] [--device cpu] [--json OUT.json]

PATH: mesh files or folders (default: ../shared/data; a missing folder skips cleanly).
Prints per mesh and scale the PSNR-fg of bicubic on each view set and the gains over it, k
(linear texel density gain of the new layout, footprint-weighted), the vertex count change,
each method's seconds, and what `--uv auto` chooses (and so ships: `direct` or repack).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from geoscaler.bench import find_meshes
from geoscaler.io import load_mesh
from geoscaler.job import compare_mesh
from geoscaler.methods import MethodOptions, MethodResult, RunContext
from geoscaler.methods.direct import DEFAULT_CONFIG
from geoscaler.methods.learned import loop_config
from geoscaler.methods.registry import get_method, output_sizes_for, register
from geoscaler.methods.repacked import baked_maps, plan_layout
from geoscaler.render import Renderer
from geoscaler.sizes import SizeRule

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
METHODS = ["bicubic", "direct", "bake", "repack"]


def bake_alone(mesh, rule, options: MethodOptions, context: RunContext) -> MethodResult:
    """The new layout and the reference maps baked into it: repack + `direct`'s start."""
    renderer = context.renderer or Renderer(mesh, options.device)
    config = loop_config(DEFAULT_CONFIG, options, RunContext())
    atlas, _ = plan_layout(mesh, rule, renderer, config, {})
    if not atlas.moved:
        return get_method("lanczos").run(mesh, rule, options, context)
    sizes = output_sizes_for(mesh, rule, renderer)
    textures = baked_maps(mesh, atlas, renderer.reference_maps(), sizes)
    kept = get_method("lanczos").run(mesh, rule, options, context).textures
    textures = [t if t is not None else k for t, k in zip(textures, kept, strict=True)]
    return MethodResult(textures, atlas.uvs, details={"layout": atlas.facts}, layout=atlas)


def register_methods() -> None:
    register("bake", bake_alone, learned=False)
    direct = get_method("direct")
    register("repack", direct.run, learned=True, settings={"uv": "repack"}, steps=direct.steps)


def mesh_rows(entry, scales, distances, budget: float, device: str) -> list[dict]:
    """The rows of one mesh (:func:`geoscaler.bench.find_meshes`' entry), one per scale and
    view set."""
    path = entry.path
    mesh = load_mesh(path)
    renderer = Renderer(mesh, device)
    options = MethodOptions(device=device, time_budget=budget)
    started = time.perf_counter()
    comparison = compare_mesh(mesh, scales, METHODS, distances, options, renderer)
    rows = []
    for scale in scales:
        repacked = comparison.outputs["repack", scale]
        details = repacked.details
        layout = details.get("layout", {})
        uvs = repacked.uvs if repacked.uvs is not None else mesh.uvs
        for distance in distances:
            by = {
                r["method"]: r
                for r in comparison.rows
                if r["scale"] == scale and r["distance"] == distance
            }
            auto = "repack" if details.get("auto_choice") == "repack" else "direct"
            rows.append(
                {
                    "mesh": entry.name,
                    "scale": scale,
                    "distance": distance,
                    "bicubic": by["bicubic"]["psnr_fg"],
                    **{f"{m}_gain": by[m]["gain_db"] for m in METHODS[1:]},
                    "auto_gain": by[auto]["gain_db"],
                    "auto_choice": auto,
                    **{f"{m}_seconds": by[m]["seconds"] for m in METHODS[1:]},
                    "repack_shipped": by["repack"]["shipped"],
                    "k": layout.get("k", 1.0),
                    "charts": layout.get("charts", 0),
                    "kept": layout.get("kept", {}),
                    "vertex_change": int(len(uvs) - len(mesh.uvs)),
                    "start_psnr_training_views": details.get("start_psnr_training_views"),
                }
            )
    print(f"# {entry.name}: {time.perf_counter() - started:.0f} s", file=sys.stderr)
    return rows


def table(rows: list[dict]) -> str:
    head = (
        "| mesh | x | dist | bicubic | direct | bake | repack+direct | auto (choice) | k | "
        "dV | s direct / repack |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | "
        "---: | ---: | ---: |"
    )
    lines = [head]
    for r in rows:
        lines.append(
            f"| {r['mesh']} | {r['scale']} | {r['distance']:g} | {r['bicubic']:.2f} | "
            f"{r['direct_gain']:+.2f} | {r['bake_gain']:+.2f} | {r['repack_gain']:+.2f}"
            f"{'' if r['repack_shipped'] == 'repack' else ' (' + r['repack_shipped'] + ')'} | "
            f"{r['auto_gain']:+.2f} ({r['auto_choice']}) | {r['k']:.2f} | "
            f"{r['vertex_change']:+d} | {r['direct_seconds']:.0f} / {r['repack_seconds']:.0f} |"
        )
    for scale in sorted({r["scale"] for r in rows}):
        for distance in sorted({r["distance"] for r in rows}):
            part = [r for r in rows if r["scale"] == scale and r["distance"] == distance]
            keys = ("bicubic", "direct_gain", "bake_gain", "repack_gain", "auto_gain", "k")
            mean = {k: statistics.fmean(r[k] for r in part) for k in keys}
            below = sum(r["auto_gain"] < r["direct_gain"] - 1e-9 for r in part)
            lines.append(
                f"| **mean of {len(part)}** | {scale} | {distance:g} | {mean['bicubic']:.2f} | "
                f"{mean['direct_gain']:+.2f} | {mean['bake_gain']:+.2f} | "
                f"{mean['repack_gain']:+.2f} | {mean['auto_gain']:+.2f} ({below} below direct) "
                f"| {mean['k']:.2f} | | |"
            )
    return "\n".join(lines)


def layout_figure(entry, scale: int, out: Path, device: str) -> Path:
    """``out/repack_<mesh>_x<scale>.png``: the reference map and the bake into the new layout
    at the output size, side by side (each 512 pixels square, nearest neighbour), chart
    outlines not drawn: what the texels hold is the point."""
    from PIL import Image

    mesh = load_mesh(entry.path)
    renderer = Renderer(mesh, device)
    rule = SizeRule(scale=scale)
    result = bake_alone(mesh, rule, MethodOptions(device=device), RunContext(renderer))
    original = renderer.reference_maps()[0][..., :3]
    panels = [Image.fromarray(np.ascontiguousarray(t)).resize((512, 512), Image.NEAREST)
              for t in (original, result.textures[0][..., :3])]  # fmt: skip
    figure = Image.new("RGB", (1032, 512), (255, 255, 255))
    figure.paste(panels[0], (0, 0))
    figure.paste(panels[1], (520, 0))
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"repack_{entry.name}_x{scale}.png"
    figure.save(path)
    print(f"{path}: k {result.details.get('layout', {}).get('k')}", file=sys.stderr)
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", type=Path)
    parser.add_argument("--scale", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--distance", type=float, nargs="+", default=[2.4])
    parser.add_argument("--time-budget", type=float, default=60.0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--figures", type=Path, help="only write the reference and new-layout bake side by side"
    )
    args = parser.parse_args()
    paths = args.paths or [DATA]
    if not any(p.exists() for p in paths):
        print(f"no meshes at {', '.join(map(str, paths))}: skipped", file=sys.stderr)
        return 0
    register_methods()
    if args.figures:
        for entry in find_meshes([p for p in paths if p.exists()]):
            layout_figure(entry, args.scale[0], args.figures, args.device)
        return 0
    rows = []
    for path in find_meshes([p for p in paths if p.exists()]):
        rows.extend(mesh_rows(path, args.scale, args.distance, args.time_budget, args.device))
        print(table(rows[-len(args.scale) * len(args.distance) :]), flush=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1, default=float))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
