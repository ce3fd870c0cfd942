"""Seconds to plan and bake `--uv auto`'s new layouts at product size, per mesh and scale.

What a race pays before a new layout's trial can start: the planning views (every training
camera's faces, :class:`~geoscaler.methods.repacked.PlanningViews`), each plan
(:func:`~geoscaler.methods.repacked.plan_layout`: charts, scales, cuts, xatlas packing, the
guards), and each bake of the base colour into the plan (:func:`baked_maps`), without a time
budget, as the job's :func:`offered_layouts` makes them, with the sizes and references
`geoscaler downsample` has (the originals at full resolution). Also each plan's density gain ``k``
(the report's), so that a faster planner can be checked not to plan sparser layouts.

Usage:
    python benchmarks/planning.py [PATH ...] [--scale 4 8] [--device cpu] [--json OUT]

PATH: mesh files or folders (default: ../shared/data; a missing folder skips cleanly). Run it
alone on the machine: the figures are wall-clock seconds.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from entry import exit_status  # beside this script
from layout_bounds import planning_arguments  # beside this script

from geoscaler.io import load_mesh
from geoscaler.methods import MethodOptions, RunContext
from geoscaler.methods.direct import DEFAULT_CONFIG
from geoscaler.methods.learned import loop_config
from geoscaler.methods.registry import output_sizes_for
from geoscaler.methods.repacked import PlanningViews, baked_maps, plan_layout
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.renderer import Renderer
from geoscaler.resize.sizes import SizeRule


@dataclass
class PlanTiming:
    """One plan of one mesh at one scale: its seconds, its bake's, its ``k``."""

    aligned: bool
    plan_s: float
    bake_s: float
    k: float
    moved: bool


@dataclass
class MeshTiming:
    mesh: str
    scale: int
    size: int
    views_s: float
    plans: list[PlanTiming] = field(default_factory=list)

    @property
    def planning_s(self) -> float:
        """Views and every plan, without the bakes."""
        return self.views_s + sum(p.plan_s for p in self.plans)


def time_mesh(path: Path, name: str, scale: int, device: str) -> MeshTiming:
    """The planning views, then the aligned plan and (where that aligned its charts) the
    unaligned one, each baked, as :func:`offered_layouts` orders them."""
    mesh = load_mesh(path)
    renderer = Renderer(mesh, device, product_evaluation(PROTOCOL_EVALUATION))
    config = loop_config(DEFAULT_CONFIG, MethodOptions(device=device), RunContext())
    rule = SizeRule(scale=scale)
    sizes = output_sizes_for(mesh, rule, renderer)
    references = renderer.reference_maps()
    views = PlanningViews(renderer, config)
    start = time.perf_counter()
    views.render_by()
    timing = MeshTiming(name, scale, max((s[0] for s in sizes if s), default=0),
                        time.perf_counter() - start)  # fmt: skip
    for align in (True, False):
        start = time.perf_counter()
        atlas = plan_layout(mesh, rule, renderer, config, None, align, views)
        planned = time.perf_counter() - start
        baked = 0.0
        if atlas.moved:
            start = time.perf_counter()
            baked_maps(mesh, atlas, references, sizes)
            baked = time.perf_counter() - start
        k = atlas.facts.k if atlas.facts else float("nan")
        timing.plans.append(PlanTiming(align, planned, baked, k, atlas.moved))
        if not atlas.moved or not atlas.aligned:
            break
    return timing


def table(rows: list[MeshTiming]) -> str:
    lines = [
        "| mesh | x | size | views (s) | aligned plan (s) | k | unaligned plan (s) | k | "
        "planning (s) | bakes (s) |",
        "| --- | ---: |" + " ---: |" * 8,
    ]
    for row in rows:
        cells = []
        for aligned in (True, False):
            plan = next((p for p in row.plans if p.aligned == aligned), None)
            cells += ["-", "-"] if plan is None else [f"{plan.plan_s:.2f}", f"{plan.k:.2f}"]
        bakes = sum(p.bake_s for p in row.plans)
        lines.append(
            f"| {row.mesh} | {row.scale} | {row.size} | {row.views_s:.2f} | {' | '.join(cells)} | "
            f"{row.planning_s:.2f} | {bakes:.2f} |"
        )
    if rows:
        worst = max(rows, key=lambda r: r.planning_s)
        lines.append(
            f"\nWorst planning: {worst.mesh} at {worst.scale}x, {worst.planning_s:.2f} s "
            f"(views and plans, without the bakes)."
        )
    return "\n".join(lines)


def main() -> int:
    args, meshes = planning_arguments(__doc__.splitlines()[0])
    rows = []
    for entry in meshes:
        for scale in args.scale:
            rows.append(time_mesh(entry.path, entry.name, scale, args.device))
            print(f"# {rows[-1]}", file=sys.stderr)
    if rows:
        print(table(rows))
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(exit_status(main))
