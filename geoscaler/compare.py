"""Compare downsampling methods on one mesh, per PROTOCOL.md (protocol 1).

Every method in :data:`geoscaler.methods.METHODS` runs once per scale; its 8-bit textures (and
UVs) are then scored on each requested view set (the validation set Q at 2.4, or the near/far
sets at 1.5 and 4.0). Bicubic always runs, listed or not: the gain of every method is its PSNR-fg
minus bicubic's on the same mesh, scale and view set.

:func:`compare_mesh` is the core that ``geoscaler compare``, ``geoscaler bench`` and the
downsample report share. A result row is a flat dict (see :data:`ROW_KEYS`).
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from geoscaler import PROTOCOL
from geoscaler.baselines import BASELINES, target_size
from geoscaler.cameras import (
    VALIDATION_DISTANCE,
    VALIDATION_VIEWS,
    Camera,
    fibonacci_directions,
    validation_cameras,
)
from geoscaler.errors import GeoscalerError
from geoscaler.evaluate import ViewSet, mip_textures
from geoscaler.mesh import TexturedMesh
from geoscaler.methods import (
    METHODS,
    MethodOptions,
    MethodResult,
    known_method,
    known_methods,
    reference_textures,
    remaining_budget,
    run_method,
)
from geoscaler.metrics import METRIC_NAMES, mean_metrics
from geoscaler.nn.network import check_variant
from geoscaler.render import Renderer

GAIN_REFERENCE = "bicubic"
"""The method every gain is measured against (PROTOCOL.md: Gain)."""

BYTES_PER_TEXEL = 4
"""Texture memory is counted as uncompressed RGBA8, 4 bytes per texel (GPUs pad RGB8 to RGBA8),
without the mip chain: ``texture_bytes = sum over materials of w * h * 4``."""

ROW_KEYS = (
    "method",
    "scale",
    "distance",
    "views",
    "texture_size",
    "texture_bytes",
    *METRIC_NAMES,
    "gain_db",
    "seconds",
)
"""Keys of a result row: ``texture_size`` is ``[width, height]`` of the largest texture,
``texture_bytes`` the RGBA8 memory of all textures (:data:`BYTES_PER_TEXEL`), PSNRs and gain in
dB (``+inf`` for a render identical to the reference), ``seconds`` the method's wall time."""

Progress = Callable[[str, int, int], None]
"""Called as ``progress(what, done, total)`` before each unit of work."""


@dataclass
class Comparison:
    """What :func:`compare_mesh` measured.

    Attributes:
        rows: one dict per (distance, scale, listed method), keys :data:`ROW_KEYS`.
        outputs: ``(method, scale)`` -> the method's result (bicubic always included).
        foreground: distance -> ``(N,)`` int64 foreground pixels of each view's reference render.
        view_indices: the protocol view indices scored (0..59), the same at every distance.
        device: the torch device the views were rendered on.
    """

    rows: list[dict[str, Any]]
    outputs: dict[tuple[str, int], MethodResult]
    foreground: dict[float, np.ndarray] = field(default_factory=dict)
    view_indices: list[int] = field(default_factory=list)
    device: str = "cpu"


def parse_methods(text: str | None, variants: str | None = None) -> list[str]:
    """Method names from ``"box,bicubic"`` (None: every registered method), checked.

    ``variants`` (``"base,full"``) replaces ``geoscaler`` in the list by one entry per network
    variant (``geoscaler-base, geoscaler-full``).

    Raises:
        GeoscalerError: an unknown or repeated name, or an empty list.
    """
    names = list(METHODS) if text is None else [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise GeoscalerError(f"--methods {text!r}: name at least one method")
    for name in names:
        if not known_method(name):
            raise GeoscalerError(
                f"--methods: unknown method {name!r}; choose from: {known_methods()}"
            )
    if variants is not None:
        if "geoscaler" not in names:
            raise GeoscalerError("--variant: list geoscaler in --methods to run its variants")
        at = names.index("geoscaler")
        chosen = [check_variant(v.strip()) for v in variants.split(",") if v.strip()]
        names[at : at + 1] = [f"geoscaler-{v}" for v in chosen]
    if len(set(names)) != len(names):
        raise GeoscalerError(f"--methods {text!r}: a method is listed twice")
    return names


def check_scales(scales: Sequence[int]) -> list[int]:
    """Distinct whole scale factors >= 2, in the given order.

    Raises:
        GeoscalerError: an empty list or a scale below 2.
    """
    if not scales:
        raise GeoscalerError("--scale: give at least one scale factor, e.g. --scale 4 8")
    for scale in scales:
        if isinstance(scale, bool) or not isinstance(scale, int) or scale < 2:
            raise GeoscalerError(
                f"--scale {scale}: a scale must be a whole number >= 2 (e.g. 4 or 8)"
            )
    return list(dict.fromkeys(scales))


def check_distances(distances: Sequence[float]) -> list[float]:
    """Distinct camera distances, each over 1 (outside the normalised mesh).

    Raises:
        GeoscalerError: an empty list or a distance <= 1.
    """
    if not distances:
        raise GeoscalerError("--distance: give at least one camera distance, e.g. 2.4")
    for distance in distances:
        if not (math.isfinite(distance) and distance > 1.0):
            raise GeoscalerError(
                f"--distance {distance}: must be over 1 (the mesh fits in the unit sphere); "
                "the protocol sets are 2.4, 1.5 (near) and 4.0 (far)"
            )
    return list(dict.fromkeys(float(d) for d in distances))


def protocol_cameras(distance: float, views: Sequence[int] | None = None) -> list[Camera]:
    """The protocol's validation cameras at ``distance``: all 60, or the listed view indices."""
    cameras = validation_cameras(distance)
    if views is None:
        return cameras
    for index in views:
        if not 0 <= index < VALIDATION_VIEWS:
            raise GeoscalerError(f"view {index}: must be 0 to {VALIDATION_VIEWS - 1}")
    return [cameras[i] for i in views]


def texture_facts(textures: Sequence[np.ndarray | None]) -> tuple[list[int], int]:
    """``([width, height]`` of the largest texture, RGBA8 bytes of them all)``."""
    present = [t for t in textures if t is not None]
    if not present:
        return [0, 0], 0
    largest = max(present, key=lambda t: t.shape[0] * t.shape[1])
    texels = sum(t.shape[0] * t.shape[1] for t in present)
    return [int(largest.shape[1]), int(largest.shape[0])], int(texels * BYTES_PER_TEXEL)


def _check_fits(mesh: TexturedMesh, scales: Sequence[int]) -> None:
    """Raise before any work if a scale is too large for one of the mesh's textures."""
    for material in mesh.materials:
        if material.base_color_texture is not None:
            height, width = material.base_color_texture.shape[:2]
            for scale in scales:
                target_size(height, width, scale)


def run_methods(
    mesh: TexturedMesh,
    scales: Sequence[int],
    methods: Sequence[str],
    options: MethodOptions,
    progress: Callable[[str], None] | None = None,
) -> dict[tuple[str, int], MethodResult]:
    """Run each method once per scale; ``progress(what)`` before each run."""
    outputs = {}
    for scale in scales:
        for name in methods:
            if progress:
                progress(f"{name} x{scale}")
            outputs[name, scale] = run_method(name, mesh, scale, options)
    return outputs


def score_outputs(
    view_set: ViewSet,
    outputs: dict[tuple[str, int], MethodResult],
    distance: float,
    progress: Callable[[str], None] | None = None,
) -> dict[tuple[str, int], dict[str, Any]]:
    """Score every output on one view set: ``(method, scale)`` -> row without ``gain_db``."""
    rows = {}
    for (name, scale), result in outputs.items():
        if progress:
            progress(f"scoring {name} x{scale} at {distance:g}")
        metrics = mean_metrics(view_set.score(result.textures, result.uvs))
        size, nbytes = texture_facts(result.textures)
        rows[name, scale] = {
            "method": name,
            "scale": scale,
            "distance": distance,
            "views": len(view_set),
            "texture_size": size,
            "texture_bytes": nbytes,
            **{key: metrics[key] for key in METRIC_NAMES},
            "seconds": result.seconds,
        }
    return rows


def _add_gains(rows: dict[tuple[str, int], dict[str, Any]]) -> None:
    """Set ``gain_db`` = PSNR-fg minus bicubic's at the same scale (0 for bicubic itself)."""
    for (name, scale), row in rows.items():
        reference = rows[GAIN_REFERENCE, scale]["psnr_fg"]
        row["gain_db"] = 0.0 if name == GAIN_REFERENCE else row["psnr_fg"] - reference


def compare_mesh(
    mesh: TexturedMesh,
    scales: Sequence[int],
    methods: Sequence[str],
    distances: Sequence[float] = (VALIDATION_DISTANCE,),
    options: MethodOptions | None = None,
    views: Sequence[int] | None = None,
    progress: Progress | None = None,
    renderer: Renderer | None = None,
) -> Comparison:
    """Run ``methods`` at every scale and score them on the protocol views at each distance.

    Args:
        mesh: the mesh; its textures are the originals.
        scales: whole reduction factors >= 2 (e.g. ``[4, 8]``).
        methods: registered method names, in the order rows are wanted.
        distances: camera distances of the view sets (2.4 is Q; 1.5 near, 4.0 far).
        options: settings passed to every method; ``options.device`` also renders the views.
        views: protocol view indices to score (None: all 60, the protocol; fewer only for
            quick checks, and the figures are then not protocol-1 means).
        progress: ``progress(what, done, total)`` before each method run, view-set build and
            scoring.
        renderer: a renderer of ``mesh`` to reuse (default: a protocol one on
            ``options.device``); another image size is not protocol 1.

    Returns:
        A :class:`Comparison`; its rows are ordered by distance, scale, then ``methods``.

    Raises:
        GeoscalerError: an unknown method, a bad scale or distance, a scale too large for a
            texture, or a method's own error.
    """
    scales = check_scales(scales)
    distances = check_distances(distances)
    listed = parse_methods(",".join(methods))
    options = options or MethodOptions()
    _check_fits(mesh, scales)
    to_run = listed if GAIN_REFERENCE in listed else [*listed, GAIN_REFERENCE]
    total = len(scales) * len(to_run) * (1 + len(distances)) + len(distances)
    done = 0

    def step(what: str) -> None:
        nonlocal done
        if progress:
            progress(what, done, total)
        done += 1

    renderer = renderer or Renderer(mesh, options.device)
    q, q_seconds = None, 0.0
    if any(name not in BASELINES for name in to_run):  # learned methods validate on Q
        start = time.perf_counter()
        q = ViewSet(renderer, protocol_cameras(VALIDATION_DISTANCE, views))
        q_seconds = time.perf_counter() - start
        options = replace(
            options,
            time_budget=remaining_budget(options.time_budget, q_seconds),  # Q counts too
            extra={**options.extra, "validation_views": q},
        )
    outputs = run_methods(mesh, scales, to_run, options, step)
    for (name, _), result in outputs.items():
        if name not in BASELINES:  # each would have cached Q on its own
            result.seconds += q_seconds
    cameras_by_distance = {d: protocol_cameras(d, views) for d in distances}
    comparison = Comparison([], outputs, device=str(renderer.device))
    comparison.view_indices = list(range(VALIDATION_VIEWS) if views is None else views)
    for distance in distances:
        step(f"rendering the views at {distance:g}")
        if distance == VALIDATION_DISTANCE and q is not None:
            view_set, q = q, None
        else:
            view_set = ViewSet(renderer, cameras_by_distance[distance])
        comparison.foreground[distance] = view_set.foreground.sum(dim=(1, 2)).cpu().numpy()
        rows = score_outputs(view_set, outputs, distance, step)
        del view_set
        _add_gains(rows)
        comparison.rows += [rows[name, scale] for scale in scales for name in listed]
    if progress:
        progress("done", total, total)
    return comparison


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
    """The ``--json`` document: ``{"protocol", "mesh", "device", "results"}``, strict JSON.

    Infinite PSNRs and gains (renders identical to the reference) are written as null.
    """
    return json_safe(
        {
            "protocol": PROTOCOL,
            "mesh": str(mesh_path),
            "device": comparison.device,
            "results": comparison.rows,
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
    ``distance``; see :func:`geoscaler.figures.comparison_sheet` for the layout. ``renderer``
    as in :func:`compare_mesh` (default: a protocol one on the comparison's device).

    Returns:
        ``(H, W, 3)`` uint8 RGB.
    """
    from geoscaler.figures import comparison_sheet
    from geoscaler.metrics import evaluate
    from geoscaler.render import image_to_uint8

    counts = comparison.foreground[distance]
    picked = [comparison.view_indices[i] for i in pick_views(counts, count)]
    renderer = renderer or Renderer(mesh, comparison.device)
    view_set = ViewSet(renderer, protocol_cameras(distance, picked))
    candidates, psnr = {}, {}
    for name in methods:
        result = comparison.outputs[name, scale]
        uvs = None if result.uvs is None else torch.as_tensor(result.uvs, device=renderer.device)
        with torch.no_grad():
            images = view_set.render(mip_textures(renderer, result.textures), uvs)
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


def method_options(args: Any) -> MethodOptions:
    """:class:`MethodOptions` from the shared CLI flags (--device, --seed, --steps, ...)."""
    if args.steps is not None and args.steps < 1:
        raise GeoscalerError(f"--steps {args.steps}: must be at least 1")
    if args.time_budget is not None and not args.time_budget > 0:
        raise GeoscalerError(f"--time-budget {args.time_budget}: must be a positive number of s")
    return MethodOptions(
        device=args.device,
        seed=args.seed,
        steps=args.steps,
        time_budget=args.time_budget,
        extra=network_extra(args),
    )


def run_settings(args: Any) -> tuple[list[int], list[str], list[float], MethodOptions]:
    """The checked scales, methods, distances and method options of ``compare``/``bench``
    arguments: every argument error surfaces here, before any work."""
    scales = check_scales(args.scale)
    methods = parse_methods(args.methods, args.variant)
    return scales, methods, check_distances(args.distance), method_options(args)


def network_extra(args: Any) -> dict[str, Any]:
    """The network's settings from ``--preset`` and ``--vgg19`` (absent flags: none)."""
    extra = {}
    if getattr(args, "preset", None) is not None:
        extra["preset"] = args.preset
    if getattr(args, "vgg19", None) is not None:
        if not Path(args.vgg19).is_file():
            raise GeoscalerError(f"--vgg19 {args.vgg19}: no such file")
        extra["vgg19"] = args.vgg19
    return extra


def tqdm_progress(bar: Any) -> Progress:
    """A :data:`Progress` callback that drives a tqdm bar (total set on first call)."""

    def update(what: str, done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.set_postfix_str(what, refresh=False)
        bar.refresh()

    return update


def prepare_out_dir(out: str | Path, names: Sequence[str], force: bool, inputs: Sequence[Path]):
    """Create ``out`` if needed and check every output file in it before work starts."""
    from geoscaler.files import check_output, prepare_folder

    folder = prepare_folder(out)
    return [check_output(folder / name, force=force, inputs=inputs) for name in names]


def command(args: Any) -> None:
    """``geoscaler compare``: compare methods on one mesh, print a table or JSON, write files."""
    from tqdm import tqdm

    from geoscaler.files import save_png, write_atomically
    from geoscaler.mesh import load_mesh

    scales, methods, distances, options = run_settings(args)
    mesh_path = Path(args.mesh)
    json_name = f"{mesh_path.stem}_compare.json"
    pictures = {scale: f"{mesh_path.stem}_compare_x{scale}.png" for scale in scales}
    if args.out:
        prepare_out_dir(args.out, [json_name, *pictures.values()], args.force, [mesh_path])
    mesh = load_mesh(mesh_path)
    with tqdm(desc=mesh_path.name, unit="step", leave=False) as bar:
        comparison = compare_mesh(
            mesh, scales, methods, distances, options, progress=tqdm_progress(bar)
        )
    document = comparison_json(mesh_path, comparison)
    document["device"] = describe_device(comparison.device)
    text = dumps(document)
    if args.json:
        print(text)
    else:
        print(f"mesh {mesh_path}   protocol {PROTOCOL}   device {document['device']}")
        print(format_table(comparison.rows))
    if args.out:
        out = Path(args.out)
        write_atomically(out / json_name, lambda tmp: tmp.write_text(text + "\n"))
        written = [out / json_name]
        for scale, name in pictures.items():
            picture = comparison_picture(mesh, comparison, scale, methods, distances[0])
            written.append(save_png(out / name, picture))
        for path in written:
            print(f"wrote {path}", file=sys.stderr if args.json else sys.stdout)
