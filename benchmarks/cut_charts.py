"""An experiment for issue 17, not a feature: does cutting the charts whose side binds the
layout pay? (`benchmarks/layout_bounds.py`: on the lego, the mug and the peach one chart spans
the whole square, so no whole-chart packing raises their density.)

Every chart whose longer UV side exceeds ``--side`` is cut into a grid of pieces at most that
long (each face goes to the cell of its UV centroid); the vertices on the cuts are duplicated
and their copies get new point ids, so the pieces are separate charts for the planner. Every
face keeps its corners' positions and UVs, so the cut mesh renders exactly as the original
(its bicubic row equals the original's) and only gains vertices (dV). Then bicubic, the bake
and repack + `direct` run on it through the job's comparison, as `benchmarks/repack.py` runs
them.

Usage:
    python benchmarks/cut_charts.py PATH ... [--side 0.5] [--scale 4] [--time-budget 60]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from repack import register_methods

from geoscaler.atlas import chart_boxes
from geoscaler.bench import find_meshes
from geoscaler.io import load_mesh
from geoscaler.job import compare_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.methods import MethodOptions
from geoscaler.render import Renderer
from geoscaler.uvmaps import chart_labels


def cut_charts(mesh: TexturedMesh, side: float) -> tuple[TexturedMesh, int]:
    """``(the cut mesh, charts cut)``: charts longer than ``side`` (UV units) cut into grid
    pieces; faces keep their order, corners their positions and UVs."""
    charts = chart_labels(mesh)
    low, extent = chart_boxes(mesh, charts, int(charts.max()) + 1)
    cells = np.ceil(np.maximum(extent, 1e-9) / side).astype(np.int64)  # (C, 2)
    cell_size = extent / cells
    centroids = mesh.uvs[mesh.faces].astype(np.float64).mean(axis=1)  # (F, 2)
    relative = (centroids - low[charts]) / np.maximum(cell_size[charts], 1e-12)
    cell = np.clip(np.floor(relative).astype(np.int64), 0, cells[charts] - 1)
    piece = (charts * cells[:, 0].max() + cell[:, 0]) * cells[:, 1].max() + cell[:, 1]
    pairs = np.stack([mesh.faces.reshape(-1), np.repeat(piece, 3)], axis=1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    old = unique[:, 0]
    points = np.stack([mesh.vertex_to_point[old], unique[:, 1]], axis=1)
    _, point_ids = np.unique(points, axis=0, return_inverse=True)
    cut = replace(
        mesh,
        positions=mesh.positions[old],
        faces=inverse.reshape(-1, 3).astype(np.int64),
        uvs=mesh.uvs[old],
        normals=mesh.normals[old],
        vertex_to_point=point_ids.reshape(-1).astype(np.int64),
        attributes={name: values[old] for name, values in mesh.attributes.items()},
    )
    return cut, int((cells > 1).any(axis=1).sum())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", type=Path)
    parser.add_argument("--side", type=float, default=0.5)
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--time-budget", type=float, default=60.0)
    args = parser.parse_args()
    register_methods()
    options = MethodOptions(device="cpu", time_budget=args.time_budget)
    for entry in find_meshes(args.paths):
        mesh = load_mesh(entry.path)
        cut, count = cut_charts(mesh, args.side)
        started = time.perf_counter()
        methods = ["bicubic", "bake", "repack"]
        comparison = compare_mesh(cut, [args.scale], methods, [2.4], options, Renderer(cut, "cpu"))
        rows = {r["method"]: r for r in comparison.rows}
        layout = comparison.outputs["repack", args.scale].details.get("layout", {})
        print(
            f"{entry.name} x{args.scale}, side {args.side}: {count} charts cut, "
            f"dV {len(cut.uvs) - len(mesh.uvs):+d}, bicubic {rows['bicubic']['psnr_fg']:.2f} dB, "
            f"gain over it: bake {rows['bake']['gain_db']:+.2f}, repack + direct "
            f"{rows['repack']['gain_db']:+.2f} (shipped {rows['repack']['shipped']}), "
            f"k {layout.get('k')}, {layout.get('charts')} charts, "
            f"{time.perf_counter() - started:.0f} s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
