"""What a job shows people: tables, strict JSON, reports and comparison pictures.

Rows come from :func:`geoscaler.pipeline.job.compare_mesh` (keys
:data:`geoscaler.pipeline.job.ROW_KEYS`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from geoscaler.mesh import TexturedMesh
from geoscaler.methods import LayoutFacts, LoopFacts, MethodResult, Shipping
from geoscaler.optim.loop import INVISIBLE_PSNR_FG, NOTHING_TO_GAIN
from geoscaler.pipeline.downsampling import Job
from geoscaler.pipeline.job import Comparison, Downsampled
from geoscaler.pipeline.lit import LIT_METHODS
from geoscaler.pipeline.rows import texture_facts
from geoscaler.pipeline.shipping import ShippedMap
from geoscaler.protocol import PROTOCOL, VALIDATION_DISTANCE
from geoscaler.render.cameras import fibonacci_directions, validation_cameras
from geoscaler.render.metrics import evaluate
from geoscaler.render.renderer import Renderer, image_to_uint8
from geoscaler.render.views import ViewSet
from geoscaler.report.figures import comparison_sheet
from geoscaler.resize.filters import reference_textures
from geoscaler.resize.sizes import TEXTURE_CLASSES


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (strict JSON has no inf/nan)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(item) for item in value]
    return value


def comparison_json(mesh_path: str | Path, comparison: Comparison) -> dict[str, Any]:
    """The ``--json`` document: ``{"protocol", "mesh", "device", "results", "runs"}``, strict
    JSON. ``runs`` holds, per learned method and scale, what its loop did and which UV layout
    it shipped and why (:func:`method_details`, as a report's ``details``).

    Infinite PSNRs and gains (renders identical to the reference) are written as null.
    """
    runs = [
        {"method": method, "scale": scale, **method_details(result)}
        for (method, scale), result in comparison.outputs.items()
        if result.loop is not None or result.shipping is not None  # learned: filters have neither
    ]
    return json_safe(
        {
            "protocol": comparison.protocol,
            "mesh": str(mesh_path),
            "device": comparison.device,
            "results": comparison.rows,
            "runs": runs,
        }
    )


def dumps(document: dict[str, Any]) -> str:
    """Strict JSON text, 2-space indented (raises on any inf/nan left)."""
    return json.dumps(document, indent=2, allow_nan=False)


def format_size(size: Sequence[int]) -> str:
    """``[w, h]`` -> ``"512x512"``."""
    return f"{size[0]}x{size[1]}"


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """The human table of :func:`compare_mesh` rows, one block per distance."""
    header = (
        f"{'method':<12} {'scale':>5} {'texture':>10} {'PSNR-fg':>8} {'PSNR-full':>9} "
        f"{'SSIM-full':>9} {'SSIM-fg':>8} {'gain dB':>8} {'seconds':>8}"
    )
    lines = []
    for distance in dict.fromkeys(row["distance"] for row in rows):
        block = [row for row in rows if row["distance"] == distance]
        lines += [f"distance {distance:g} ({block[0]['views']} views)", header]
        lines += [_format_row(row) for row in block]
        lines.append("")
    return "\n".join(lines).rstrip()


def _format_row(row: dict[str, Any]) -> str:
    return (
        f"{row['method']:<12} {'x' + str(row['scale']):>5} {format_size(row['texture_size']):>10} "
        f"{row['psnr_fg']:>8.2f} {row['psnr_full']:>9.2f} {row['ssim_full']:>9.4f} "
        f"{row['ssim_fg']:>8.4f} {row['gain_db']:>+8.2f} {row['seconds']:>8.2f}"
    )


def describe_device(device: str) -> str:
    """``"cpu (2 threads)"`` or ``"cuda:0 (NVIDIA H100 80GB HBM3)"``: where views were rendered."""
    if device.startswith("cuda"):
        return f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
    threads = torch.get_num_threads()
    return f"{device} ({threads} thread{'s' if threads > 1 else ''})"


def pick_views(foreground: np.ndarray, count: int = 3) -> list[int]:
    """Indices of ``count`` views that show the mesh large and from different sides.

    Greedy: the view with the most foreground pixels first, then repeatedly the view farthest
    (in direction) from those chosen, among views with at least half the largest foreground.

    Args:
        foreground: ``(N,)`` foreground pixel counts of protocol views ``0..N-1``.
    """
    directions = fibonacci_directions()[: len(foreground)]
    candidates = np.flatnonzero(foreground >= 0.5 * foreground.max())
    chosen = [int(np.argmax(foreground))]
    while len(chosen) < min(count, len(candidates)):
        closeness = (directions[candidates] @ directions[chosen].T).max(axis=1)
        closeness[np.isin(candidates, chosen)] = np.inf
        chosen.append(int(candidates[np.argmin(closeness)]))
    return chosen


def comparison_picture(
    mesh: TexturedMesh,
    comparison: Comparison,
    scale: int,
    methods: Sequence[str],
    distance: float = VALIDATION_DISTANCE,
    count: int = 3,
    renderer: Renderer | None = None,
) -> np.ndarray:
    """The labelled comparison sheet of ``methods`` at ``scale``, on ``count`` protocol views.

    Views are picked with :func:`pick_views` from the foreground counts measured at
    ``distance``; see :func:`geoscaler.report.figures.comparison_sheet` for the layout. ``renderer``
    as in :func:`geoscaler.pipeline.job.compare_mesh` (default: a protocol one on the comparison's
    device).

    Returns:
        ``(H, W, 3)`` uint8 RGB.
    """
    counts = comparison.foreground[distance]
    picked = [comparison.view_indices[i] for i in pick_views(counts, count)]
    renderer = renderer or Renderer(mesh, comparison.device)
    cameras = validation_cameras(distance)
    view_set = ViewSet(renderer, [cameras[i] for i in picked])
    candidates, psnr = {}, {}
    for name in methods:
        result = comparison.outputs[name, scale]
        uvs = None if result.uvs is None else torch.as_tensor(result.uvs, device=renderer.device)
        with torch.no_grad():
            images = view_set.render(renderer.mip_textures(result.textures), uvs)
        psnr[name] = evaluate(images, view_set.references, view_set.foreground)["psnr_fg"].tolist()
        candidates[name] = [image_to_uint8(image) for image in images]
    size = format_size(texture_facts(comparison.outputs[methods[0], scale].textures)[0])
    original = format_size(texture_facts(reference_textures(mesh))[0])
    return comparison_sheet(
        references=[image_to_uint8(image) for image in view_set.references],
        candidates=candidates,
        psnr_fg=psnr,
        foreground=list(view_set.foreground.cpu().numpy()),
        view_titles=[f"view {i} at distance {distance:g}" for i in picked],
        column_titles=[f"original {original}"] + [f"{n} {size}" for n in methods],
        title=f"x{scale}: renders, zoom on the largest errors, |error| heatmap (protocol 1)",
    )


def report_document(
    job: Job, done: Downsampled, seconds: float, written: Sequence[Path] = ()
) -> dict[str, Any]:
    """The JSON report: protocol, files, settings, result rows, the method's details, and
    every texture's size, memory and bytes before and after (``written``: the output files,
    for the total on disk)."""
    size, _ = texture_facts(done.result.textures)
    return json_safe(
        {
            "protocol": PROTOCOL,
            "mesh": str(job.mesh_path),
            "output": str(job.output),
            "method": job.method,
            "scale": job.plan.color.label,
            "sizes": {kind: job.plan.rule(kind).label for kind in TEXTURE_CLASSES},
            "texture_size": size,
            "device": describe_device(done.comparison.device),
            "seconds": round(seconds, 3),
            "results": done.rows,
            "details": {**downsample_details(done), **lit_skipped(job, done)},
            "maps": [map_facts(shipped) for shipped in done.maps],
            "totals": asset_totals(job.mesh.source_files, written, done.maps),
        }
    )


def method_details(result: MethodResult) -> dict[str, Any]:
    """A method's facts as the report's ``details`` holds them: where and how it trained,
    the network's facts, what ``--uv`` did, what its loop did, what shipped."""
    details: dict[str, Any] = {}
    if result.device is not None:
        details["device"] = result.device
    if result.training_renderer is not None:
        details["training_renderer"] = result.training_renderer
    if result.network is not None:
        network = asdict(result.network)
        details.update({k: v for k, v in network.items() if v is not None})
    if result.layout_facts is not None:
        details.update(_layout_details(result.layout_facts))
    if result.loop is not None:
        details.update(_loop_details(result.loop))
    if result.shipping is not None:
        details.update(_shipping_details(result.shipping))
    if result.first_step_after_start is not None:
        details["first_step_after_start"] = result.first_step_after_start
    if result.lit is not None:
        details["lit"] = asdict(result.lit)
    return details


def lit_skipped(job: Job, done: Downsampled) -> dict[str, str]:
    """``{"lit_skipped": why}`` where a protocol-2 job's lit stage did not follow its method
    (:mod:`geoscaler.pipeline.lit`); empty where it did, or under protocol 1."""
    if job.protocol != 2 or done.result.lit is not None:
        return {}
    if job.method not in LIT_METHODS:
        methods = ", ".join(LIT_METHODS)
        return {"lit_skipped": f"the lit stage follows {methods} only; {job.method}'s normal "
                "and data maps ship by their class"}  # fmt: skip
    if done.result.uvs is not None:
        return {"lit_skipped": "the result is in a new UV layout: its maps are re-baked into it, "
                "not trained lit"}  # fmt: skip
    return {}


def downsample_details(done: Downsampled) -> dict[str, Any]:
    """:func:`method_details` of a downsampling job's result, with a learned method's budget
    and step limit."""
    details = method_details(done.result)
    if done.learned:
        details.update(time_budget=done.time_budget, steps_limit=done.steps_limit)
    return details


def _loop_details(loop: LoopFacts) -> dict[str, Any]:
    return {**asdict(loop), "validation_psnr_fg": loop.validation_psnr_fg}


def _layout_details(facts: LayoutFacts) -> dict[str, Any]:
    details: dict[str, Any] = {"uv": facts.uv}
    if facts.planned is not None:
        planned = asdict(facts.planned)
        details["layout"] = {key: value for key, value in planned.items() if value is not None}
    if facts.skipped is not None:
        details["layout_skipped"] = facts.skipped
    details["layout_used"] = facts.used
    if facts.race is not None:
        details["race"] = {name: asdict(trial) for name, trial in facts.race.items()}
    return details


def _shipping_details(shipping: Shipping) -> dict[str, Any]:
    details: dict[str, Any] = {"shipped": shipping.shipped}
    if shipping.shortfall_db is not None:
        details["shortfall_db"] = shipping.shortfall_db
    if shipping.not_run is not None:
        details.update(not_run=shipping.not_run, time_budget=shipping.seconds_left)
    return details


def map_facts(shipped: ShippedMap) -> dict[str, Any]:
    """One texture in the report: where it is shown, how it was made, before and after."""
    return {
        "slots": shipped.slots,
        "class": shipped.kind,
        "method": shipped.method,
        "size_before": list(shipped.size_before),
        "size_after": list(shipped.size_after),
        "memory_before": shipped.memory_before,
        "memory_after": shipped.memory_after,
        "bytes_before": shipped.bytes_before,
        "bytes_after": shipped.bytes_after,
        "format_before": shipped.format_before,
        "format_after": shipped.format_after,
    }


def asset_totals(
    inputs: Sequence[Path], outputs: Sequence[Path], maps: Sequence[ShippedMap]
) -> dict[str, int]:
    """Texture memory (4 bytes a texel, no mips) and bytes on disk of the whole asset, before
    and after (the files read, the files written)."""

    def on_disk(paths: Sequence[Path]) -> int:
        return sum(Path(p).stat().st_size for p in dict.fromkeys(paths) if Path(p).is_file())

    return {
        "memory_before": sum(m.memory_before for m in maps),
        "memory_after": sum(m.memory_after for m in maps),
        "bytes_before": on_disk(inputs),
        "bytes_after": on_disk(outputs),
    }


def _maps_lines(document: dict[str, Any]) -> list[str]:
    """One line per texture and a total: class, method, size, memory and bytes."""
    lines = []
    for facts in document.get("maps", []):
        (h0, w0), (h1, w1) = facts["size_before"], facts["size_after"]
        lines.append(
            f"  {', '.join(facts['slots'])}: {facts['class']}, {facts['method']}; "
            f"{w0} x {h0} -> {w1} x {h1}; memory {_mb(facts['memory_before'])} -> "
            f"{_mb(facts['memory_after'])}; file {_mb(facts['bytes_before'])}"
            f"{_format_name(facts.get('format_before'))} -> {_mb(facts['bytes_after'])}"
            f"{_format_name(facts.get('format_after'))}"
        )
    totals = document.get("totals")
    if totals and lines:
        memory = totals["memory_after"] / max(totals["memory_before"], 1)
        disk = totals["bytes_after"] / max(totals["bytes_before"], 1)
        lines.insert(0, "textures:")
        lines.append(
            f"  total: texture memory {_mb(totals['memory_before'])} -> "
            f"{_mb(totals['memory_after'])} ({memory:.1%}); on disk "
            f"{_mb(totals['bytes_before'])} -> {_mb(totals['bytes_after'])} ({disk:.1%})"
        )
        if totals["bytes_after"] > totals["bytes_before"]:
            lines.append(
                "note: the output is larger on disk than the input (its images are encoded "
                "less tightly than the input's); --image-format jpeg or webp makes them smaller"
            )
    return lines


_FORMAT_NAMES = {"image/png": "PNG", "image/jpeg": "JPEG", "image/webp": "WebP"}


def _format_name(mime: str | None) -> str:
    """`` PNG``, `` JPEG``... for a MIME type the report names; "" for none."""
    name = _FORMAT_NAMES.get(mime or "", mime or "")
    return f" {name}" if name else ""


def _mb(count: int) -> str:
    return f"{count / 1e6:.2f} MB" if count >= 100_000 else f"{count / 1e3:.1f} kB"


def _validation_lines(method: str, details: dict[str, Any]) -> list[str]:
    """What the learned method was validated on, against the best filter, and what shipped."""
    counts, scores = details.get("validation_views"), details.get("validation_scores")
    baselines = details.get("baseline_scores") or {}
    if not counts or not scores:
        return []
    sets = list(scores)
    views = ", ".join(f"{name} {counts.get(name, 0)}" for name in sets)
    own = " / ".join(_decibels(scores[name]) for name in sets)
    lines = [f"validated on {views} views; PSNR-fg ({' / '.join(sets)}): {method} {own}"]
    if baselines:
        best = [[b[name] for b in baselines.values() if b[name] is not None] for name in sets]
        lines[0] += ", best filter " + " / ".join(_decibels(max(b, default=None)) for b in best)
    shipped = details.get("shipped", method)
    if shipped != method:
        lines.append(
            f"shipped {shipped}: {method}'s own result fell {-details['shortfall_db']:.2f} dB "
            f"short of clearing the best filter on its worst validation set (its mean gain "
            f"view by view, less a standard error or more, by the views' count) and {shipped} "
            f"fell less, so the output is {shipped}'s texture"
            + (
                ""
                if details.get("stopped_by") == NOTHING_TO_GAIN
                else "; give the method more steps or time"
            )
        )
    return lines


def _lit_lines(lit: dict[str, Any] | None) -> list[str]:
    """What the lit stage (protocol 2) did: its steps, and lit PSNR-fg of what shipped beside
    the start and the baselines it was chosen among."""
    if not lit:
        return []
    if not lit["validation_scores"]:
        return [
            f"lit (protocol 2): not run ({lit['stopped_by']}); the normal and data maps ship "
            "by their class; give a larger --time-budget"
        ]
    sets = list(lit["validation_scores"])

    def scores(values: dict[str, float]) -> str:
        return " / ".join(_decibels(values.get(name)) for name in sets)

    chosen = scores(lit["validation_scores"])
    others = "; ".join(f"{name} {scores(v)}" for name, v in lit["baseline_scores"].items())
    start, started = lit.get("start_maps"), ""
    if start:
        started = f", from every other map by {start} (it validated above its class's filter)"
    elif lit.get("other_starts_left_out"):
        started = ", from its class's maps (the time left held no scoring of other starts)"
    return [
        f"lit (protocol 2): normal and data maps trained through lit views{started}, "
        f"{lit['steps']} steps (best at step {lit['best_step']}), stopped by "
        f"{lit['stopped_by']}; shipped {lit['shipped']}",
        f"  lit PSNR-fg on {lit['validation_views']} views a set ({' / '.join(sets)}): shipped "
        f"{chosen}; {others}",
    ]


def _decibels(value: float | None) -> str:
    """A PSNR for the report; None (a set whose views saw none of the mesh): n/a."""
    return "n/a" if value is None else f"{value:.2f}"


def format_report(document: dict[str, Any]) -> str:
    """The printed report: a header, the protocol table and one line on how the method ran."""
    lines = [
        f"mesh {document['mesh']} -> {document['output']}   protocol {document['protocol']}   "
        f"device {document['device']}",
        format_table(document["results"]),
    ]
    details = document["details"]
    if "steps" in details:
        lines.append(
            f"{document['method']}: {details['steps']} steps (best at step "
            f"{details.get('best_step')}), stopped by {details.get('stopped_by')}; "
            f"{document['seconds']:.1f} s for the whole job"
        )
        if details.get("backtracks"):
            lines.append(
                f"{details['backtracks']} validation(s) ranked the candidate below the best so "
                "far: each sent the texels back to the best and lowered the learning rate"
            )
        if details.get("stopped_by") == NOTHING_TO_GAIN:
            lines.append(
                f"note: a filter already validates at {INVISIBLE_PSNR_FG:g} dB PSNR-fg or more "
                "on every validation view (differences smaller than one 8-bit step), so the "
                "method stopped there; --full-budget spends the whole budget anyway"
            )
        if details["steps"] == 0 and details.get("stopped_by") == "time budget":
            lines.append(
                f"note: the time budget ({details.get('time_budget')} s) left no time for a "
                "first step after loading and caching the views, so no optimisation step ran "
                "and the result is the method's Lanczos start; give a larger --time-budget"
            )
    else:
        lines.append(f"{document['seconds']:.1f} s for the whole job")
    if "not_run" in details:
        lines.append(
            f"{document['method']} not run: {details['not_run']}; shipped "
            f"{details['shipped']}, unvalidated; give a larger --time-budget"
        )
    lines.extend(_validation_lines(document["method"], details))
    lines.extend(_lit_lines(details.get("lit")))
    if "lit_skipped" in details:
        lines.append(f"lit (protocol 2): not run: {details['lit_skipped']}")
    lines.extend(_layout_lines(document["method"], details))
    lines.extend(_maps_lines(document))
    return "\n".join(lines)


LAYOUT_NAMES = {"keep": "own layout", "repack": "repacked", "unaligned": "repacked unaligned"}


def _layout_lines(method: str, details: dict[str, Any]) -> list[str]:
    """What ``--uv repack`` / ``auto`` did with the UV layout (nothing for ``keep``)."""
    layout = details.get("layout")
    line = f"UV layout ({details.get('uv')}): "
    if "layout_skipped" in details:
        return [line + f"the mesh's own layout kept: {details['layout_skipped']}"]
    if not layout:
        return []
    used = details.get("layout_used", "keep")
    shipped = used != "keep" and details.get("shipped", method) == method
    if shipped:
        aligned = layout.get("alignment_texels", 1)
        line += (
            f"{layout['charts']} charts repacked, texel density x{layout['k']:.2f} where the "
            f"views look (x{layout['k_area']:.2f} by UV area), padding {layout['padding_texels']} "
            "texels"
            + (f", aligned to {aligned}-texel blocks of the original" if aligned > 1 else "")
            + "; new UVs written, every map of those materials re-baked"
        )
    elif used != "keep":
        line += f"the repacked result did not ship ({details.get('shipped')} did, on the own UVs)"
    else:
        line += "the mesh's own layout kept"
    lines = [line]
    if shipped and layout.get("charts_cut"):
        lines.append(_cut_line(layout))
    if details.get("race"):
        trials = [_trial_words(name, trial) for name, trial in details["race"].items()]
        rule = "the best on Q not below the own layout" if "keep" in details["race"] else "the best"
        lines.append(f"  trials (validation PSNR-fg): {'; '.join(trials)}; {rule} went on")
    lines += [f"  {name}: layout kept, {reason}" for name, reason in layout["kept"].items()]
    return lines


def _trial_words(name: str, trial: dict[str, Any]) -> str:
    """One layout's trial in the race: its validation, steps, training views and why it was
    out, if it was."""
    sets = trial.get("validation_sets", {})
    others = "".join(f", {n} {sets[n]:.2f}" for n in ("near", "far") if n in sets)
    below = trial.get("start_below") or {}
    gaps = " and ".join(f"{gap:.2f} dB on {name}" for name, gap in below.items())
    if trial.get("gated"):
        return (
            f"{LAYOUT_NAMES[name]} started Q {trial['validation_psnr_fg']:.2f} dB{others}, "
            f"below a filter by {gaps}: no trial"
        )
    words = (
        f"{LAYOUT_NAMES[name]} Q {trial['validation_psnr_fg']:.2f} dB{others} after "
        f"{trial['steps']} step{'' if trial['steps'] == 1 else 's'}"
    )
    views = trial.get("training_views")
    if views:
        words += f" on {views} training view{'' if views == 1 else 's'}"
    if trial["shortfall_db"] != 0:
        words += f" ({trial['shortfall_db']:+.2f} dB below a filter)"
    if trial.get("below_own_on"):
        words += f" (below the own layout on {' and '.join(trial['below_own_on'])})"
    if trial.get("unfinished"):
        words += " (short of the first trial's steps: ranked only above it)"
    if below:
        words += f" (its start below a filter by {gaps})"
    return words


def _cut_line(layout: dict[str, Any]) -> str:
    """What became of the charts longer than half the atlas (:func:`geoscaler.uv.atlas.repack`)."""
    count = layout["charts_cut"]
    charts = f"{count} chart{'' if count == 1 else 's'} longer than half the atlas"
    if layout["cut"]:
        return (
            f"  {charts} cut along face edges (x{layout['k_whole']:.2f} whole): "
            f"{layout['vertices_added']} vertices added on the cuts"
        )
    if "cut_skipped" in layout:
        return f"  {charts} kept whole: {layout['cut_skipped']}"
    return (
        f"  {charts} kept whole: cut, x{layout['k_cut']:.2f}, not 1.1 times "
        f"x{layout['k_whole']:.2f}"
    )
