"""Would re-unwrapping charts let the new layout pack denser? Per mesh and scale, the texel
density gain ``k`` of the job's new layout (the mesh's own charts, moved whole or cut) against
that of the same plan made on the mesh re-unwrapped by ``xatlas`` (its charts computed and
parameterised from the 3D surface: the charts whose UV area fills at most ``--fill`` of their
bounding box, every chart by default).

The re-unwrapped charts are first scaled so each original chart keeps its UV area (the same
texels on average); the job's planning then scales and packs them as it does the own charts
(:func:`~geoscaler.methods.repacked.plan_layout`: its training cameras, padding, alignment,
and the sizes the job ships). Each side is the better of the job's two plans, aligned and
unaligned, and at least 1: where both are sparser than the mesh's own layout, or a material
does not pack, the job keeps its layout. ``k`` here is per face, not per chart: the
footprint-weighted geometric mean over the moved faces of ``sqrt(new UV area / original UV
area)``, so that the distortion an unwrap brings counts. Planning only, no training: seconds
a mesh.

Usage:
    python benchmarks/unwrap.py [PATH ...] [--scale 4 8] [--fill 1.0]
        [--chart-option NAME=VALUE ...] [--json OUT]

PATH: mesh files or folders (default: ../shared/data; a missing folder skips cleanly).
``--chart-option``: an ``xatlas.ChartOptions`` field, e.g. ``max_cost=8``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

import numpy as np
import xatlas
from entry import exit_status  # beside this script
from layout_bounds import emit, planning_arguments  # beside this script

from geoscaler.io import load_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.methods import MethodOptions, RunContext
from geoscaler.methods.direct import DEFAULT_CONFIG
from geoscaler.methods.learned import loop_config
from geoscaler.methods.repacked import PlanningViews, plan_layout
from geoscaler.optim.loop import OptimizeConfig
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.renderer import Renderer
from geoscaler.resize.sizes import SizeRule
from geoscaler.uv.atlas import DB_PER_HALVING, Atlas, chart_boxes, chart_footprint, uv_areas
from geoscaler.uv.packing import corner_areas
from geoscaler.uv.uvmaps import chart_labels

AWAY = 8.0
"""UV units the re-unwrapped charts are moved along u, clear of the charts kept."""


def chart_fill(mesh: TexturedMesh, charts: np.ndarray) -> np.ndarray:
    """``(C,)`` UV area of each chart over the area of its UV bounding box."""
    count = int(charts.max()) + 1
    area = np.bincount(charts, np.abs(uv_areas(mesh.uvs, mesh.faces)), minlength=count)
    _, extent = chart_boxes(mesh, charts, count)
    return area / np.maximum(extent.prod(axis=1), 1e-30)


def unwrapped(
    mesh: TexturedMesh, fill: float, options: xatlas.ChartOptions
) -> tuple[TexturedMesh, int, int, float]:
    """``mesh`` with the charts that fill at most ``fill`` of their box re-unwrapped by xatlas:
    ``(mesh, charts re-unwrapped, charts they became, seconds of xatlas)``."""
    charts = chart_labels(mesh)
    chosen = np.flatnonzero(chart_fill(mesh, charts) <= fill)
    faces = np.flatnonzero(np.isin(charts, chosen))
    corners = mesh.corner_uvs().astype(np.float64)
    if not len(faces):
        return mesh, 0, 0, 0.0
    atlas = xatlas.Atlas()
    atlas.add_mesh(mesh.positions.astype(np.float32), mesh.faces[faces].astype(np.uint32))
    started = time.perf_counter()
    atlas.generate(chart_options=options)
    seconds = time.perf_counter() - started
    _, indices, uvs = atlas.get_mesh(0)
    if len(indices) != len(faces):
        raise RuntimeError(f"xatlas returned {len(indices)} faces of {len(faces)}")
    new = uvs[indices].astype(np.float64)  # (G, 3, 2)
    old_area = np.abs(corner_areas(corners[faces]))
    new_area = np.abs(corner_areas(new))
    for chart in chosen:
        mine = charts[faces] == chart
        new[mine] *= math.sqrt(old_area[mine].sum() / max(new_area[mine].sum(), 1e-30))
    new[:, :, 0] += AWAY
    corners[faces] = new
    return mesh.with_uvs(corners.astype(np.float32)), len(chosen), atlas.chart_count, seconds


def face_k(original: TexturedMesh, atlas: Atlas, footprint: np.ndarray) -> float:
    """Footprint-weighted geometric mean over the moved faces of ``sqrt(new / original UV
    area)``; faces that keep their layout count as 1."""
    old = np.abs(corner_areas(original.corner_uvs().astype(np.float64)))
    new = np.abs(corner_areas(atlas.uvs.astype(np.float64)))
    live = (old > 0) & (new > 0) & (footprint > 0)
    ratio = np.divide(new, old, out=np.ones_like(old), where=live)
    gain = np.where(atlas.chart_of_face >= 0, 0.5 * np.log(ratio), 0.0)
    weights = np.where(live, footprint, 0.0)
    return float(math.exp((weights * gain).sum() / weights.sum())) if weights.sum() else 1.0


def best_k(
    original: TexturedMesh,
    mesh: TexturedMesh,
    rule: SizeRule,
    renderer: Renderer,
    config: OptimizeConfig,
    views: PlanningViews,
    footprint: np.ndarray,
) -> float:
    """The largest ``k`` (:func:`face_k`) of the aligned and the unaligned plan of ``mesh``,
    at least 1: where both are sparser, the job keeps the own layout."""
    plans = [
        plan_layout(mesh, rule, renderer, config, None, align, views) for align in (True, False)
    ]
    return max([1.0] + [face_k(original, atlas, footprint) for atlas in plans])


def mesh_rows(entry, args: argparse.Namespace, options: xatlas.ChartOptions) -> list[dict]:
    """One row per scale: ``k`` of the own charts' plan and of the re-unwrapped charts'."""
    mesh = load_mesh(entry.path)
    evaluation = product_evaluation(PROTOCOL_EVALUATION)  # the sizes the job ships
    renderer = Renderer(mesh, args.device, evaluation)
    config = loop_config(DEFAULT_CONFIG, MethodOptions(device=args.device), RunContext())
    views = PlanningViews(renderer, config)
    footprint = chart_footprint(np.arange(len(mesh.faces)), views.tri_ids)  # (F,) per face
    charts = int(chart_labels(mesh).max()) + 1
    other, chosen, made, seconds = unwrapped(mesh, args.fill, options)
    other_renderer = Renderer(other, args.device, evaluation)  # the views see the same faces
    rows = []
    for scale in args.scale:
        rule = SizeRule(scale=scale)
        started = time.perf_counter()
        k_unwrap = best_k(mesh, other, rule, other_renderer, config, views, footprint)
        row = {
            "mesh": entry.name,
            "scale": scale,
            "charts": charts,
            "unwrapped": chosen,
            "became": made,
            "unwrap_seconds": round(seconds, 2),
            "plan_seconds": round(time.perf_counter() - started, 2),
            "k_own": round(best_k(mesh, mesh, rule, renderer, config, views, footprint), 3),
            "k_unwrap": round(k_unwrap, 3),
        }
        rows.append(row)
        print(f"# {row}", file=sys.stderr, flush=True)
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| mesh | x | charts | re-unwrapped -> charts | xatlas (s) | k own | k re-unwrapped | "
        "5 log2 (re-unwrapped / own) dB |",
        "| --- |" + " ---: |" * 7,
    ]
    for r in rows:
        change = DB_PER_HALVING * math.log2(r["k_unwrap"] / r["k_own"])
        lines.append(
            f"| {r['mesh']} | {r['scale']} | {r['charts']} | {r['unwrapped']} -> {r['became']} | "
            f"{r['unwrap_seconds']:.1f} | {r['k_own']:.2f} | {r['k_unwrap']:.2f} | {change:+.2f} |"
        )
    for scale in sorted({r["scale"] for r in rows}):
        part = [r for r in rows if r["scale"] == scale]
        changes = [DB_PER_HALVING * math.log2(r["k_unwrap"] / r["k_own"]) for r in part]
        best = max(part, key=lambda r: r["k_unwrap"] / r["k_own"])
        lines.append(
            f"| **mean of {len(part)}** | {scale} | | | | | | {statistics.fmean(changes):+.2f} "
            f"(best {best['mesh']} {max(changes):+.2f}) |"
        )
    return "\n".join(lines)


def chart_options(pairs: list[str]) -> xatlas.ChartOptions:
    """``xatlas.ChartOptions`` with the ``NAME=VALUE`` fields set."""
    options = xatlas.ChartOptions()
    for pair in pairs:
        name, _, value = pair.partition("=")
        setattr(options, name, type(getattr(options, name))(value))
    return options


def main() -> int:
    description = __doc__.splitlines()[0]
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--fill", type=float, default=1.0)
    parser.add_argument("--chart-option", action="append", default=[])
    args, meshes = planning_arguments(description, parser)
    if not meshes:
        return 0
    options = chart_options(args.chart_option)
    rows = [row for entry in meshes for row in mesh_rows(entry, args, options)]
    return emit(rows, table(rows), args.json)


if __name__ == "__main__":
    sys.exit(exit_status(main))
