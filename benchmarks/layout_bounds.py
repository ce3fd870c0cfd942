"""How far re-allocating the atlas can go: per mesh and scale, the texel density
gain ``k`` the job's new layout reaches and two bounds on any layout that, like it, moves each
of its charts whole by a similarity at the planned relative scales (where the layout cut
charts, its pieces are its charts; ``k whole`` is what the uncut charts reached).

- ``k area``: every texel of the square used, no padding (the charts' UV area bounds it);
- ``k side``: the chart whose longer side is largest at its planned scale spans the square
  less the padding (no packing of whole charts beats it, however clever);
- ``bound``: the smaller of the two, and which one binds.

Each ``k`` is the footprint-weighted geometric mean over the moved charts of new texels per old
texel at the same texture size (as the report's ``k``). ``dB`` columns turn them into the
issue's prediction, bicubic's loss of about 5 dB per halving of the texel density on the
development set: ``5 log2 k``. Planning only (the job's own :func:`plan_layout` on its training
cameras): no training, a few seconds a mesh.

Usage:
    python benchmarks/layout_bounds.py [PATH ...] [--scale 4 8] [--device cpu] [--json OUT]

PATH: mesh files or folders (default: ../shared/data; a missing folder skips cleanly).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np
from entry import exit_status  # beside this script

from geoscaler.io import load_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.methods import MethodOptions, RunContext
from geoscaler.methods.direct import DEFAULT_CONFIG
from geoscaler.methods.learned import loop_config
from geoscaler.methods.registry import output_sizes_for
from geoscaler.methods.repacked import PlanningViews, plan_layout
from geoscaler.render.renderer import Renderer
from geoscaler.report.bench import find_meshes
from geoscaler.resize.sizes import SizeRule
from geoscaler.uv.atlas import (
    DB_PER_HALVING,
    Atlas,
    chart_boxes,
    planned_scales,
    uv_areas,
    weighted_gain,
)
from geoscaler.uv.detail import LostDetail

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def group_bounds(mesh: TexturedMesh, atlas: Atlas, group: int, lost: LostDetail) -> dict:
    """One packed group's ``k`` and bounds, with the footprint weight they average over
    (relative scales as the plan's, weighed by ``lost`` detail)."""
    count = len(atlas.planned)
    charts = np.where(atlas.chart_of_face >= 0, atlas.chart_of_face, count)  # kept: one more
    area = np.bincount(charts, np.abs(uv_areas(mesh.uvs, mesh.faces)), minlength=count + 1)
    faces = np.isin(mesh.face_material, atlas.groups[group]) & (atlas.chart_of_face >= 0)
    ids = np.unique(charts[faces])
    weights = atlas.footprint[ids]
    detail = lost.per_chart(charts, count + 1)[ids]
    relative = planned_scales(weights, area[ids], detail)  # total UV area as the original's
    padding = atlas.paddings[group]
    size = atlas.sizes[atlas.groups[group][0]][0]
    side = chart_boxes(mesh, charts, count + 1)[1][ids].max(axis=1) * relative
    factors = {
        "area": 1.0 / math.sqrt(float((relative**2 * area[ids]).sum())),
        "side": (1.0 - 2.0 * padding / size) / float(side.max()),
    }

    return {
        "weight": float(weights.sum()),
        "size": size,
        "padding": padding,
        "charts": len(ids),
        "coverage": float(area[ids].sum()),
        "k": weighted_gain(atlas.scales[ids], weights),
        "k_area": weighted_gain(relative * factors["area"], weights),
        "k_side": weighted_gain(relative * factors["side"], weights),
    }


def mesh_rows(entry, scales: list[int], device: str) -> list[dict]:
    """One row per scale: the job's layout and its bounds (groups averaged by footprint)."""
    mesh = load_mesh(entry.path)
    renderer = Renderer(mesh, device)
    config = loop_config(DEFAULT_CONFIG, MethodOptions(device=device), RunContext())
    views = PlanningViews(renderer, config)  # rendered once, the lost detail measured once
    rows = []
    for scale in scales:
        rule = SizeRule(scale=scale)
        atlas = plan_layout(mesh, rule, renderer, config, views=views)
        lost = views.lost_detail(output_sizes_for(mesh, rule, renderer))  # as the plan's
        groups = [group_bounds(mesh, atlas, g, lost) for g in range(len(atlas.groups))]
        if not groups:
            rows.append({"mesh": entry.name, "scale": scale, "kept": atlas.kept})
            continue
        weight = sum(g["weight"] for g in groups)

        def average(key: str, groups: list[dict] = groups, weight: float = weight) -> float:
            return math.exp(sum(g["weight"] * math.log(g[key]) for g in groups) / weight)

        row = {
            "mesh": entry.name,
            "scale": scale,
            "size": max(g["size"] for g in groups),
            "charts": sum(g["charts"] for g in groups),
            "coverage": sum(g["coverage"] for g in groups) / len(groups),
            "padding": min(g["padding"] for g in groups),
            "kept": atlas.kept,
            **{key: average(key) for key in ("k", "k_area", "k_side")},
            "k_whole": atlas.facts.k_whole,
            "vertices_added": atlas.facts.vertices_added,
        }
        row["bound"] = min(row["k_area"], row["k_side"])
        row["binds"] = "area" if row["k_area"] <= row["k_side"] else "side"
        rows.append(row)
        print(
            f"# {entry.name} x{scale}: k {row['k']:.2f}, bound {row['bound']:.2f}", file=sys.stderr
        )
    return rows


def decibels(k: float) -> float:
    return DB_PER_HALVING * math.log2(k)


def table(rows: list[dict]) -> str:
    lines = [
        "| mesh | x | size | charts | UV coverage | padding | k whole | k | dV | k area | "
        "k side | bound (binds) | 5 log2 k: now / bound (dB) |",
        "| --- |" + " ---: |" * 10 + " --- | ---: |",
    ]
    for r in rows:
        if "k" not in r:
            lines.append(f"| {r['mesh']} | {r['scale']} | layout kept: {r['kept']} |")
            continue
        lines.append(
            f"| {r['mesh']} | {r['scale']} | {r['size']} | {r['charts']} | "
            f"{r['coverage']:.2f} | {r['padding']} | {r['k_whole']:.2f} | {r['k']:.2f} | "
            f"{r['vertices_added']:+d} | {r['k_area']:.2f} | "
            f"{r['k_side']:.2f} | {r['bound']:.2f} ({r['binds']}) | "
            f"{decibels(r['k']):+.2f} / {decibels(r['bound']):+.2f} |"
        )
    for scale in sorted({r["scale"] for r in rows}):
        part = [r for r in rows if r["scale"] == scale and "k" in r]
        if part:
            now = statistics.fmean(decibels(r["k"]) for r in part)
            bound = statistics.fmean(decibels(r["bound"]) for r in part)
            lines.append(
                f"| **mean of {len(part)}** | {scale} | | | | | | | | | | | "
                f"{now:+.2f} / {bound:+.2f} |"
            )
    return "\n".join(lines)


def planning_arguments(
    description: str, parser: argparse.ArgumentParser | None = None
) -> tuple[argparse.Namespace, list]:
    """The arguments of a benchmark that plans layouts of meshes (PATH ..., ``--scale``,
    ``--device``, ``--json``; ``parser``: one holding the benchmark's own arguments already)
    and the meshes they name (:func:`find_meshes`; default: the development set, none where
    it is absent, said on stderr)."""
    parser = parser or argparse.ArgumentParser(description=description)
    parser.add_argument("paths", nargs="*", type=Path)
    parser.add_argument("--scale", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if not args.paths and not DATA.is_dir():
        print(f"no development data at {DATA}: nothing to measure", file=sys.stderr)
        return args, []
    return args, find_meshes(args.paths or [DATA])


def emit(rows: list[dict], text: str, path: Path | None) -> int:
    """Print a benchmark's table ``text`` and write its ``rows`` to ``path`` as JSON (None:
    not written); the exit status, 0."""
    print(text)
    if path:
        path.write_text(json.dumps(rows, indent=1))
    return 0


def main() -> int:
    args, meshes = planning_arguments(__doc__.splitlines()[0])
    if not meshes:
        return 0
    rows = [row for entry in meshes for row in mesh_rows(entry, args.scale, args.device)]
    return emit(rows, table(rows), args.json)


if __name__ == "__main__":
    sys.exit(exit_status(main))
