"""Repacking the atlas: bicubic, `direct` on the mesh's own UVs, the bake alone on
the new layout, and repack + `direct`, per development mesh and scale, protocol 1.

Every method runs through the job's own comparison (`geoscaler.pipeline.job.compare_mesh`), as
`geoscaler bench` runs it: the same cached views, validation and scoring, references always the
original maps on the original UVs, every learned method under the same time budget. The bake alone
is registered here as a filter (it is what repack + `direct` starts from, not validated); the
repacked layout is planned on training views only.

Usage:
    python benchmarks/repack.py [PATH ...] [--scale 4 8] [--time-budget 60]
        [--methods bicubic direct bake repack auto] [--distance 2.4 [1.5 4.0]]
        [--device cpu] [--json OUT.json] [--product]

PATH: mesh files or folders (default: ../shared/data; a missing folder skips cleanly).
Prints per mesh and scale the PSNR-fg of bicubic on each view set and the gains over it, k
(linear texel density gain of the new layout, footprint-weighted), the vertex count change,
each learned method's seconds, and `--uv auto`'s gain with the layout its race chose.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
from entry import exit_status  # beside this script

from geoscaler.io import load_mesh
from geoscaler.methods import LayoutFacts, MethodOptions, MethodResult, RunContext
from geoscaler.methods.direct import DEFAULT_CONFIG
from geoscaler.methods.learned import loop_config
from geoscaler.methods.registry import get_method, output_sizes_for, register
from geoscaler.methods.repacked import baked_maps, offered_layouts
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.pipeline.job import compare_mesh
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.renderer import Renderer
from geoscaler.report.bench import find_meshes
from geoscaler.report.documents import method_details
from geoscaler.resize.sizes import SizeRule

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
METHODS = ["bicubic", "lanczos", "direct", "bake", "repack", "auto"]
LEARNED = ["direct", "repack", "auto"]


def bake_alone(mesh, rule, options: MethodOptions, context: RunContext) -> MethodResult:
    """The first new layout a race weighs (:func:`offered_layouts`) and the reference maps
    baked into it: that layout's start; Lanczos where no layout is offered."""
    renderer = context.renderer or Renderer(mesh, options.device)
    config = loop_config(DEFAULT_CONFIG, options, RunContext())
    offered = offered_layouts(mesh, rule, renderer, config, LayoutFacts(uv="repack"))
    if not offered:
        return get_method("lanczos").run(mesh, rule, options, context)
    atlas = offered[0]
    sizes = output_sizes_for(mesh, rule, renderer)
    textures = baked_maps(mesh, atlas, renderer.reference_maps(), sizes)
    kept = get_method("lanczos").run(mesh, rule, options, context).textures
    textures = [t if t is not None else k for t, k in zip(textures, kept, strict=True)]
    facts = LayoutFacts(uv="repack", used="repack", planned=atlas.facts)
    return MethodResult(textures, atlas.uvs, layout=atlas, layout_facts=facts)


def register_methods() -> None:
    register("bake", bake_alone, learned=False)
    direct = get_method("direct")
    for mode in ("repack", "auto"):
        register(mode, direct.run, learned=True, settings={"uv": mode}, steps=direct.steps)


def mesh_rows(
    entry, scales, distances, methods, budget: float, device: str, product: bool = False
) -> list[dict]:
    """The rows of one mesh (:func:`geoscaler.report.bench.find_meshes`' entry), one per scale and
    view set; ``product``: sizes and references as `geoscaler downsample` has them (the
    original at full resolution, not the protocol's 2048 cap)."""
    mesh = load_mesh(entry.path)
    evaluation = product_evaluation(PROTOCOL_EVALUATION) if product else PROTOCOL_EVALUATION
    renderer = Renderer(mesh, device, evaluation)
    options = MethodOptions(device=device, time_budget=budget)
    started = time.perf_counter()
    comparison = compare_mesh(mesh, scales, methods, distances, options, renderer)
    rows = []
    for scale in scales:
        outputs = {m: comparison.outputs[m, scale] for m in methods if m in LEARNED + ["bake"]}
        facts = [o.layout_facts for o in outputs.values() if o.layout_facts is not None]
        layouts = [f.planned for f in facts if f.planned is not None]
        layout = asdict(layouts[0]) if layouts else {}
        relaid = [o.uvs for o in outputs.values() if o.uvs is not None]
        for distance in distances:
            by = {
                r["method"]: r
                for r in comparison.rows
                if r["scale"] == scale and r["distance"] == distance
            }
            row = {
                "mesh": entry.name,
                "scale": scale,
                "distance": distance,
                "bicubic": by["bicubic"]["psnr_fg"],
                **{f"{m}_gain": by[m]["gain_db"] for m in methods if m != "bicubic"},
                **{f"{m}_seconds": by[m]["seconds"] for m in methods if m in LEARNED},
                **{f"{m}_shipped": by[m]["shipped"] for m in methods if m in LEARNED},
                "k": layout.get("k", 1.0),
                "charts": layout.get("charts", 0),
                "kept": layout.get("kept", {}),
                "k_whole": layout.get("k_whole") or layout.get("k", 1.0),
                "cut": bool(layout.get("cut")),
                "vertex_change": len(mesh.with_uvs(relaid[0]).uvs) - len(mesh.uvs) if relaid else 0,
            }
            if "auto" in outputs:
                row["auto_layout"] = method_details(outputs["auto"]).get("layout_used", "keep")
                row["auto_race"] = method_details(outputs["auto"]).get("race")
            rows.append(row)
    print(f"# {entry.name}: {time.perf_counter() - started:.0f} s", file=sys.stderr)
    return rows


def _gain(row: dict, method: str) -> str:
    """A method's gain cell: what shipped in brackets when the job's floor rejected it, and
    the layout ``auto`` went on with."""
    if f"{method}_gain" not in row:
        return "-"
    cell = f"{row[f'{method}_gain']:+.2f}"
    shipped = row.get(f"{method}_shipped", method)
    notes = [] if shipped == method else [shipped]
    if method == "auto":
        notes.insert(0, row["auto_layout"])
    return cell + (f" ({', '.join(notes)})" if notes else "")


def table(rows: list[dict]) -> str:
    head = (
        "| mesh | x | dist | bicubic | lanczos | direct | bake | repack+direct | auto (layout) | "
        "k | dV | s direct / repack / auto |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | "
        "---: | ---: | ---: | ---: | ---: |"
    )
    lines = [head]
    for r in rows:
        seconds = " / ".join(
            f"{r[f'{m}_seconds']:.0f}" if f"{m}_seconds" in r else "-" for m in LEARNED
        )
        lines.append(
            f"| {r['mesh']} | {r['scale']} | {r['distance']:g} | {r['bicubic']:.2f} | "
            f"{_gain(r, 'lanczos')} | {_gain(r, 'direct')} | {_gain(r, 'bake')} | "
            f"{_gain(r, 'repack')} | {_gain(r, 'auto')} | "
            f"{r['k']:.2f}{' (cut)' if r.get('cut') else ''} | "
            f"{r['vertex_change']:+d} | {seconds} |"
        )
    for scale in sorted({r["scale"] for r in rows}):
        for distance in sorted({r["distance"] for r in rows}):
            part = [r for r in rows if r["scale"] == scale and r["distance"] == distance]
            lines.append(_mean_line(part, scale, distance))
    return "\n".join(lines)


def _mean_line(part: list[dict], scale: int, distance: float) -> str:
    """The table's mean row of one scale and distance, with how often auto fell below direct
    and the worst mesh's gain per method."""
    cells = []
    for method in ("lanczos", "direct", "bake", "repack", "auto"):
        key = f"{method}_gain"
        if key not in part[0]:
            cells.append("-")
            continue
        values = [r[key] for r in part]
        cells.append(f"{statistics.fmean(values):+.2f} (worst {min(values):+.2f})")
    if "auto_gain" in part[0] and "direct_gain" in part[0]:
        below = sum(r["auto_gain"] < r["direct_gain"] - 1e-9 for r in part)
        worst = min(r["auto_gain"] - r["direct_gain"] for r in part)
        cells[-1] += f", {below} below direct (by at most {max(-worst, 0):.3f})"
    bicubic = statistics.fmean(r["bicubic"] for r in part)
    k = statistics.fmean(r["k"] for r in part)
    return (
        f"| **mean of {len(part)}** | {scale} | {distance:g} | {bicubic:.2f} | "
        f"{' | '.join(cells)} | {k:.2f} | | |"
    )


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
    print(f"{path}: k {method_details(result).get('layout', {}).get('k')}", file=sys.stderr)
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", type=Path)
    parser.add_argument("--scale", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--distance", type=float, nargs="+", default=[2.4])
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=METHODS)
    parser.add_argument("--time-budget", type=float, default=60.0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--product", action="store_true", help="sizes and references as `downsample` has them"
    )
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
        methods = ["bicubic", *(m for m in args.methods if m != "bicubic")]
        rows.extend(
            mesh_rows(
                path,
                args.scale,
                args.distance,
                methods,
                args.time_budget,
                args.device,
                args.product,
            )
        )
        print(table(rows[-len(args.scale) * len(args.distance) :]), flush=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1, default=float))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(exit_status(main))
