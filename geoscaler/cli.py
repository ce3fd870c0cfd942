"""The ``geoscaler`` command line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from geoscaler import __version__
from geoscaler.clock import WALL_CLOCK
from geoscaler.errors import GeoscalerError
from geoscaler.process import configure_process, exit_status_kept
from geoscaler.protocol import PROTOCOL, PROTOCOL_EVALUATION, Evaluation
from geoscaler.uv.uvmodes import JOB_UV_MODE, add_uv_argument

DEFAULT_DEMO_DIR = Path("assets")


def mesh_info(path: Path) -> dict:
    """Facts about a mesh file: sizes, materials, textures, UV charts and texture coverage."""
    from geoscaler.io import load_mesh
    from geoscaler.uv.uvmaps import chart_labels, uv_coverage

    mesh = load_mesh(path)
    materials = []
    for index, material in enumerate(mesh.materials):
        texture = material.base_color_texture
        coverage = None if texture is None else uv_coverage(mesh, index)
        materials.append(
            {
                "name": material.name,
                "faces": int((mesh.face_material == index).sum()),
                "texture_size": None if texture is None else [texture.shape[1], texture.shape[0]],
                "channels": None if texture is None else int(texture.shape[2]),
                "base_color_factor": [round(float(x), 6) for x in material.base_color_factor],
                "uv_coverage": None if coverage is None else round(coverage, 4),
            }
        )
    return {
        "path": str(path),
        "vertices": len(mesh.positions),
        "points": mesh.num_points,
        "faces": len(mesh.faces),
        "uv_charts": int(chart_labels(mesh).max()) + 1 if len(mesh.faces) else 0,
        "uv_range": [
            np.round(mesh.uvs.min(0).astype(float), 4).tolist(),
            np.round(mesh.uvs.max(0).astype(float), 4).tolist(),
        ],
        "bounds": [mesh.positions.min(axis=0).tolist(), mesh.positions.max(axis=0).tolist()],
        "materials": materials,
    }


def _print_info(info: dict) -> None:
    print(f"mesh       {info['path']}")
    print(f"vertices   {info['vertices']:,} ({info['points']:,} 3D points after welding UV seams)")
    print(f"faces      {info['faces']:,}")
    (u0, v0), (u1, v1) = info["uv_range"]
    print(f"UV charts  {info['uv_charts']:,}   UV range u [{u0}, {u1}]  v [{v0}, {v1}]")
    for index, material in enumerate(info["materials"]):
        factor = ", ".join(f"{x:g}" for x in material["base_color_factor"])
        if material["texture_size"] is None:
            texture = "no base-colour texture"
        else:
            width, height = material["texture_size"]
            coverage = material["uv_coverage"]
            measured = "not measured" if coverage is None else f"{100 * coverage:.1f}%"
            texture = f"{width} x {height} x {material['channels']}, UV coverage {measured}"
        print(
            f"material {index} {material['name']!r}: {material['faces']:,} faces, {texture}, "
            f"factor ({factor})"
        )


def cmd_info(args: argparse.Namespace) -> None:
    info = mesh_info(Path(args.mesh))
    if args.json:
        print(json.dumps({"protocol": PROTOCOL, **info}, indent=2, allow_nan=False))
    else:
        _print_info(info)


def cmd_render(args: argparse.Namespace) -> None:
    from geoscaler.io import check_output, load_mesh, save_png
    from geoscaler.pipeline.arguments import check_distance, check_view
    from geoscaler.protocol import VALIDATION_DISTANCE
    from geoscaler.render.cameras import validation_cameras
    from geoscaler.render.renderer import Renderer, image_to_uint8

    view = check_view(args.view)
    distance = VALIDATION_DISTANCE if args.distance is None else check_distance(args.distance)
    mesh_path = Path(args.mesh)
    out = check_output(args.output, force=args.force, inputs=[mesh_path])
    if out.suffix.lower() != ".png":
        raise GeoscalerError(f"{out}: renders are written as PNG; use a .png name")
    mesh = load_mesh(mesh_path)
    check_output(out, force=args.force, inputs=mesh.source_files)  # its textures, .bin, .mtl
    camera = validation_cameras(distance)[view]
    renderer = Renderer(mesh, args.device, args.evaluation)
    render = renderer.render(renderer.rasterize(camera), renderer.reference_textures())
    image = image_to_uint8(render)
    save_png(out, image)
    print(f"wrote {out} (view {view} at distance {camera.distance}, {image.shape[1]} px)")


def job_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The checked settings of a downsampling job from :func:`add_job_arguments`' options: the
    keyword arguments of :func:`geoscaler.pipeline.downsampling.prepare` but the mesh and output."""
    from geoscaler.pipeline.arguments import (
        DEFAULT_TIME_BUDGET,
        check_image_format,
        check_method,
        check_protocol,
        check_size_plan,
        check_variant,
        method_options,
        method_settings,
    )

    method = check_method(args.method)
    settings = method_settings(args, [method], JOB_UV_MODE)
    if args.variant is not None:
        if method != "geoscaler":
            raise GeoscalerError("--variant: only --method geoscaler has variants")
        settings["variant"] = check_variant(args.variant)
    options = method_options(
        [method],
        args.device,
        args.seed,
        args.steps,
        args.time_budget,
        settings,
        default_budget=DEFAULT_TIME_BUDGET,
    )
    return {
        "sizes": check_size_plan(args.scale, args.max_size, args.power_of_two),
        "method": method,
        "options": options,
        "force": args.force,
        "image_format": check_image_format(args.image_format),
        "protocol": None if args.protocol is None else check_protocol(args.protocol),
    }


def cmd_downsample(args: argparse.Namespace) -> None:
    from geoscaler.pipeline.downsampling import prepare
    from geoscaler.report.console import command_started_at

    settings = job_settings(args)
    job = prepare(
        args.mesh,
        args.output,
        report=args.report,
        started_at=command_started_at(args.called_at),  # the whole command's wall clock
        **settings,
    )
    from geoscaler.report.runner import downsample_and_report

    downsample_and_report(job, args.evaluation)


def cmd_demo(args: argparse.Namespace) -> None:
    from geoscaler.report.console import command_started_at
    from geoscaler.report.runner import demo

    demo(
        args.out,
        args.device,
        evaluation=args.evaluation,
        optimize=args.optimize,
        started_at=command_started_at(args.called_at),
    )


def cmd_view(args: argparse.Namespace) -> None:
    try:  # the app's dependencies are an extra: geoscaler works without them
        from geoscaler.app.main import run
    except ImportError as error:
        raise GeoscalerError(
            f"the desktop app needs its extra dependencies ({error}); "
            "install them with: pip install 'geoscaler[app]'"
        ) from None
    mesh = None if args.mesh is None else Path(args.mesh)
    if mesh is not None and not mesh.is_file():
        raise GeoscalerError(f"{mesh}: no such file")
    run(mesh, Path(args.out), method=args.method, scale=args.scale)


def cmd_compare(args: argparse.Namespace) -> None:
    """``geoscaler compare``: compare methods on one mesh, print a table or JSON, write files."""
    from tqdm import tqdm

    from geoscaler.io import load_mesh, save_png, write_atomically
    from geoscaler.pipeline.arguments import check_protocol, comparison_settings
    from geoscaler.pipeline.job import compare_mesh, prepare_out_dir
    from geoscaler.render.renderer import Renderer
    from geoscaler.report.console import CompareProgress
    from geoscaler.report.documents import (
        comparison_json,
        comparison_picture,
        describe_device,
        dumps,
        format_table,
    )

    scales, methods, distances, options = comparison_settings(args)
    protocol = None if args.protocol is None else check_protocol(args.protocol)
    mesh_path = Path(args.mesh)
    json_name = f"{mesh_path.stem}_compare.json"
    pictures = {scale: f"{mesh_path.stem}_compare_x{scale}.png" for scale in scales}
    names = [json_name, *pictures.values()]
    if args.out:
        prepare_out_dir(args.out, names, args.force, [mesh_path], probe=False)
    mesh = load_mesh(mesh_path)
    if args.out:  # again, now that every file the mesh was read from is known
        prepare_out_dir(args.out, names, args.force, mesh.source_files)
    renderer = Renderer(mesh, options.device, args.evaluation)
    with tqdm(desc=mesh_path.name, unit="step", leave=False) as bar:
        comparison = compare_mesh(
            mesh, scales, methods, distances, options, renderer, CompareProgress(bar),
            protocol=protocol,
        )  # fmt: skip
    document = comparison_json(mesh_path, comparison)
    document["device"] = describe_device(comparison.device)
    text = dumps(document)
    if args.json:
        print(text)
    else:
        print(f"mesh {mesh_path}   protocol {comparison.protocol}   device {document['device']}")
        print(format_table(comparison.rows))
    if args.out:
        out = Path(args.out)
        write_atomically(out / json_name, lambda tmp: tmp.write_text(text + "\n"))
        written = [out / json_name]
        for scale, name in pictures.items():
            picture = comparison_picture(
                mesh, comparison, scale, methods, distances[0], renderer=renderer
            )
            written.append(save_png(out / name, picture))
        for path in written:
            print(f"wrote {path}", file=sys.stderr if args.json else sys.stdout)


def cmd_bench(args: argparse.Namespace) -> None:
    from geoscaler.report.bench import command

    command(args)


def cmd_batch(args: argparse.Namespace) -> int:
    """``geoscaler batch``: the main job over every asset under IN_DIR; the exit status is the
    number of assets that failed (at most 125)."""
    from dataclasses import replace

    from geoscaler.batch import command

    # With Ray the GPUs are the workers': --device cuda is checked where the job runs.
    on_workers = args.engine == "ray" and args.device == "cuda"
    checked = argparse.Namespace(**{**vars(args), "device": "auto"}) if on_workers else args
    settings = job_settings(checked)
    if on_workers:
        settings["options"] = replace(settings["options"], device="cuda")
    return command(args, settings)


def _add_network_arguments(
    parser: argparse.ArgumentParser, variants: str, uv_default: str
) -> None:
    """Flags of the learned methods: what they train through, ``direct``'s UV layout (unset:
    ``uv_default``); the GeoScaler network's variant(s), preset, VGG-19 weights."""
    parser.add_argument(
        "--renderer",
        choices=["exact", "soft"],
        default="exact",
        help="what learned methods train through: exact (default: the renderer a GPU is) or "
        "soft (the paper's soft rasteriser, geoscaler.render.soft); validation and scores are "
        "exact",
    )
    add_uv_argument(parser, uv_default)
    parser.add_argument("--variant", help=variants)
    parser.add_argument(
        "--preset",
        choices=["cpu", "paper"],
        help="network settings: cpu (default; measured on 2 cores) or paper (the paper's, "
        "for a GPU: 15,000 steps)",
    )
    parser.add_argument(
        "--vgg19",
        metavar="PATH",
        help="VGG-19 weights (torchvision's vgg19-dcbb9e9d.pth) for the paper preset's "
        "perceptual loss; default: torchvision's cache if it has them, else the term is off",
    )


def _add_method_arguments(
    parser: argparse.ArgumentParser, scales: list[int], protocol_default: str
) -> None:
    """Flags shared by compare and bench: scales, methods, view sets, device, method settings."""
    default = " ".join(map(str, scales))
    parser.add_argument(
        "--scale",
        type=int,
        nargs="+",
        default=scales,
        help=f"reduction factors (default {default})",
    )
    parser.add_argument(
        "--methods", help="comma-separated, e.g. box,bicubic,lanczos,pbd (default: all registered)"
    )
    parser.add_argument(
        "--distance",
        type=float,
        nargs="+",
        default=[2.4],
        help="view-set distances: 2.4 is the validation set, 1.5 near, 4.0 far (default 2.4)",
    )
    parser.add_argument(
        "--protocol",
        type=int,
        help="1: the unlit base colour (the paper's); 2: every map of a material lit, each "
        f"method's asset as it ships (default: {protocol_default}; see docs/protocol.md)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of tables")
    parser.add_argument("--out", help="folder to write results and pictures into")
    parser.add_argument("--force", action="store_true", help="replace existing files in --out")
    _add_device_argument(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of learned methods (default 0)")
    parser.add_argument("--steps", type=int, help="optimisation steps of learned methods")
    parser.add_argument(
        "--time-budget", type=float, help="seconds a learned method may spend per mesh and scale"
    )
    _add_network_arguments(
        parser,
        "with geoscaler in --methods: comma-separated network variants to run, each a row "
        "of its own, e.g. base,gcm,uvw,full (default: full)",
        "keep",
    )


def add_job_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a downsampling job: sizes, image format, method, budget, device, seed,
    force (``downsample`` and ``batch`` take the same)."""
    parser.add_argument(
        "--scale",
        action="append",
        type=_class_value,
        metavar="[CLASS=]S",
        help="reduction factor per side, a whole number >= 2, for every texture or, as "
        "CLASS=S, for one class: color, normal or data (repeatable; default 4 when neither "
        "--scale nor --max-size is given: 4096 -> 1024)",
    )
    parser.add_argument(
        "--max-size",
        action="append",
        type=_class_value,
        metavar="[CLASS=]N",
        help="longest side of a texture at most N texels, aspect kept (repeatable, per class "
        "as --scale)",
    )
    parser.add_argument(
        "--power-of-two",
        action="store_true",
        help="round each side to the nearest power of two (never above --max-size)",
    )
    parser.add_argument(
        "--image-format",
        help="png, jpeg or webp for every image written (default: each in its input's "
        "format; webp through EXT_texture_webp)",
    )
    parser.add_argument(
        "--method",
        default="direct",
        help="direct (default: optimised through the renderer), geoscaler (the network), "
        "lanczos, bicubic, box or pbd",
    )
    _add_network_arguments(
        parser,
        "with --method geoscaler: base, gcm (GeoCoding), uvw (UVWarper) or full (default)",
        JOB_UV_MODE,
    )
    parser.add_argument(
        "--time-budget",
        type=float,
        help="wall-clock seconds the whole command may take with a learned method: loading, "
        "view caching, optimisation, scoring and export (default 60)",
    )
    parser.add_argument(
        "--full-budget",
        action="store_true",
        help="optimise for the whole budget even where a filter already validates at 50 dB "
        "PSNR-fg or more on every view (by default the method stops there)",
    )
    parser.add_argument(
        "--steps", type=int, help="maximum optimisation steps (default: the method's, 300)"
    )
    parser.add_argument(
        "--protocol",
        type=int,
        help="what direct optimises for: 1, the base colour through unlit views; 2, then "
        "the normal and data maps through lit views (default: 2 where a material has a "
        "normal or metallic-roughness map, else 1; see docs/protocol.md)",
    )
    _add_device_argument(parser)
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--force", action="store_true", help="replace existing outputs (never the input)"
    )


def _class_value(text: str) -> str:
    """argparse type of ``--scale`` and ``--max-size``: ``N`` or ``CLASS=N`` (the values are
    checked with the other errors, :func:`geoscaler.pipeline.arguments.check_size_plan`)."""
    from geoscaler.resize.sizes import parse_class_value

    try:
        parse_class_value(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def _scale_factor(text: str) -> int:
    """argparse type of ``--scale``: a whole number (>= 2 is checked with the other errors)."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a whole number; a scale is a whole reduction factor >= 2, "
            "e.g. 4 (2048 -> 512) or 8"
        ) from None


def _add_device_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--device",
        choices=["auto", "cpu", "cuda"],
        default="auto",
        help="auto: CUDA when torch sees a GPU",
    )


def build_parser() -> argparse.ArgumentParser:
    """The command line: ``--version`` and one sub-command per ``_add_*_command``."""
    parser = argparse.ArgumentParser(
        prog="geoscaler",
        description="Downsample the textures of 3D meshes for the views people will see.",
    )
    parser.add_argument("--version", action="version", version=f"geoscaler {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_info_command(commands)
    _add_render_command(commands)
    _add_downsample_command(commands)
    _add_demo_command(commands)
    _add_view_command(commands)
    _add_compare_command(commands)
    _add_bench_command(commands)
    _add_batch_command(commands)
    return parser


def _add_info_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler info MESH``: sizes, textures and UV charts of a mesh."""
    info = commands.add_parser("info", help="describe a mesh: sizes, textures, UV charts")
    info.add_argument("mesh", help="OBJ, glTF or GLB file")
    info.add_argument("--json", action="store_true", help="print JSON instead of text")
    info.set_defaults(run=cmd_info)


def _add_render_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler render MESH -o PNG``: one protocol view of a mesh."""
    render = commands.add_parser("render", help="render one protocol view of a mesh to PNG")
    render.add_argument("mesh", help="OBJ, glTF or GLB file")
    render.add_argument("--view", type=int, default=0, help="validation view index 0-59")
    render.add_argument("--distance", type=float, help="camera distance (default 2.4)")
    render.add_argument("-o", "--output", required=True, help="PNG file to write")
    render.add_argument("--force", action="store_true", help="replace an existing output")
    _add_device_argument(render)
    render.set_defaults(run=cmd_render)


def _add_downsample_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler downsample MESH -o OUT``: the main job on one mesh."""
    downsample = commands.add_parser(
        "downsample",
        help="the main job: every texture smaller, the base colour rendering like the original",
        description="Write MESH with every texture of every material smaller (base colour by "
        "the method, other maps by what they hold) in the format OUT's suffix names, and "
        "report protocol-1 metrics on the validation views for the result, bicubic and "
        "Lanczos, and each texture's size, memory and bytes. Ctrl-C stops the optimisation "
        "and still writes the best result so far; a second Ctrl-C aborts.",
    )
    downsample.add_argument("mesh", metavar="MESH", help="OBJ, glTF or GLB file (never modified)")
    downsample.add_argument(
        "-o", "--output", required=True, metavar="OUT", help="mesh to write: .glb, .gltf or .obj"
    )
    add_job_arguments(downsample)
    downsample.add_argument("--report", help="also write the report as JSON to this file")
    downsample.set_defaults(run=cmd_downsample)


def _add_demo_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler demo``: the built-in demo asset, downsampled 4x."""
    demo = commands.add_parser(
        "demo",
        help="build the built-in demo asset and downsample it 4x (under 2 minutes on 2 cores)",
        description="Build (or reuse) DIR/geoscaler_pebble.glb, run `downsample --scale 4` on it "
        "with method direct (at most 120 steps and 75 s), print the report, and write "
        "DIR/geoscaler_pebble_x4.glb, DIR/geoscaler_pebble_x4.json and DIR/demo_comparison.png "
        "(earlier demo outputs in DIR are replaced).",
    )
    demo.add_argument("--out", default=str(DEFAULT_DEMO_DIR), help="folder (default assets/)")
    _add_device_argument(demo)
    demo.set_defaults(run=cmd_demo)


def _add_view_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler view [MESH]``: the desktop app."""
    view = commands.add_parser(
        "view",
        help="the desktop app: original and downsampled views side by side, live optimisation",
        description="Open MESH (the built-in demo asset when none is given) in the desktop app. "
        "Exports, screenshots and bookmarks are written to --out.",
    )
    view.add_argument("mesh", nargs="?", metavar="MESH", help="OBJ, glTF or GLB file")
    view.add_argument("--out", default=".", help="folder for exports and bookmarks (default .)")
    view.add_argument("--method", default="direct", help="method at start (default direct)")
    view.add_argument("--scale", type=_scale_factor, default=4, help="scale at start (default 4)")
    view.set_defaults(run=cmd_view)


def _add_compare_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler compare MESH``: the methods compared on one mesh."""
    compare = commands.add_parser(
        "compare", help="compare downsampling methods on one mesh (protocol metrics, pictures)"
    )
    compare.add_argument("mesh", help="OBJ, glTF or GLB file")
    _add_method_arguments(
        compare, [4], "2 for a mesh with normal or metallic-roughness maps, else 1"
    )
    compare.set_defaults(run=cmd_compare)


def _add_bench_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler bench PATH...``: the methods compared over many meshes."""
    bench = commands.add_parser(
        "bench", help="compare methods over many meshes: tables, CSV/JSON/Markdown, plot"
    )
    bench.add_argument("paths", nargs="+", metavar="PATH", help="mesh files or folders")
    _add_method_arguments(bench, [4, 8], "1, for every mesh, so that means average like with like")
    bench.set_defaults(run=cmd_bench)


def _add_batch_command(commands: argparse._SubParsersAction) -> None:
    """``geoscaler batch IN_DIR -o OUT_DIR``: the main job over a library."""
    batch = commands.add_parser(
        "batch",
        help="the main job over a library: every asset under IN_DIR, written under OUT_DIR",
        description="Find the assets under IN_DIR (the file a folder's meta.json names as "
        "its entry, else every .glb, .gltf and .obj file), downsample each as `downsample` "
        "does with the options below, write it and its report (NAME.report.json) at the same "
        "relative path under OUT_DIR, and summary.csv, summary.json and summary.md into "
        "OUT_DIR. A bad asset is reported and the rest is done; the exit status is the number "
        "that failed (at most 125). Ctrl-C: no new asset starts and running jobs keep their "
        "best result; Ctrl-C again aborts them. No partial output is left either way.",
    )
    batch.add_argument("in_dir", metavar="IN_DIR", help="folder of assets (never modified)")
    batch.add_argument(
        "-o", "--output", required=True, metavar="OUT_DIR", help="folder to write (created)"
    )
    add_job_arguments(batch)
    batch.add_argument(
        "--format", choices=["glb", "gltf", "obj"], help="output format (default: the input's)"
    )
    batch.add_argument(
        "--resume",
        action="store_true",
        help="skip the assets whose outputs and report an earlier batch wrote with the same "
        "options and that are newer than their inputs",
    )
    batch.add_argument(
        "--engine",
        choices=["local", "ray"],
        default="local",
        help="local: --jobs processes on this machine (default); ray: one Ray task per asset "
        "on a Ray cluster (pip install 'geoscaler[ray]'; IN_DIR and OUT_DIR must be shared)",
    )
    batch.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="local: assets run at once, each in a process with cores / N torch threads "
        "(default 1)",
    )
    batch.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="ray: the cluster's head, e.g. HEAD_IP:6379, or auto; local starts a Ray "
        "instance on this machine (default: Ray's: RAY_ADDRESS, else a running local cluster, "
        "else a new local instance)",
    )
    batch.add_argument(
        "--cpus-per-task",
        type=float,
        default=1.0,
        help="ray: CPUs each task asks for, and its torch threads (default 1)",
    )
    batch.add_argument(
        "--gpus-per-task",
        type=float,
        default=1.0,
        help="ray: GPUs each task asks for when the device is CUDA (default 1; 0.5: two tasks "
        "share a GPU)",
    )
    batch.set_defaults(run=cmd_batch)


def printable(text: str) -> str:
    """``text`` with control characters escaped (``\\x1b``), so that a file name cannot
    drive the user's terminal through an error message."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def main(
    argv: list[str] | None = None,
    *,
    evaluation: Evaluation = PROTOCOL_EVALUATION,
    optimize: dict | None = None,
) -> int:
    """Run the command line; returns the exit status.

    ``evaluation`` and ``optimize`` are for callers that are not users (tests, quick checks):
    fewer or smaller views, and overrides of the learned methods' loop settings. The command
    line itself always runs protocol 1 with each method's own settings.

    With ``argv`` None the command line is the process: a job's time budget counts from its
    start, not this call's, and a late Ctrl-C cannot change its exit status (exit_status_kept).
    """
    if argv is None:
        return exit_status_kept(lambda: _run(None, evaluation, optimize, None))
    return _run(argv, evaluation, optimize, WALL_CLOCK.now())


def _run(
    argv: list[str] | None, evaluation: Evaluation, optimize: dict | None, called_at: float | None
) -> int:
    configure_process()  # before the commands below first import torch
    args = build_parser().parse_args(argv)
    args.evaluation, args.optimize, args.called_at = evaluation, optimize, called_at
    try:
        status = args.run(args) or 0  # a command returns nothing, or its exit status
    except GeoscalerError as error:
        print(f"geoscaler: error: {printable(str(error))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("geoscaler: interrupted", file=sys.stderr)
        return 130
    return status


if __name__ == "__main__":
    sys.exit(main())
