"""Every map of a PBR material under protocol 2 (lit renders): the filters users have, the
project's class filters with and without Toksvig roughness, and what `geoscaler downsample` ships.

Usage:
    python benchmarks/lit_maps.py [MESH ...] [--scale 4 8] [--views 60] [--time-budget 60]
        [--no-product] [--split] [--json out.json] [--figure DIR]

Per mesh and scale, each candidate is scored against the full-resolution original under
protocol 2 (PSNR-fg and SSIM-fg on Q, near and far) and under protocol 1 (unlit base colour,
PSNR-fg on Q), all from the same cameras:

- ``bicubic-every-map``, ``lanczos-every-map``: every map resized by that Pillow filter on its
  stored 8-bit values, as ``gltf-transform resize`` does;
- ``maps``: the class filters (``geoscaler.resize.maps``: colour in linear light, normals as
  unit vectors, data per channel), the base colour by Lanczos in linear light;
- ``maps+toksvig``: ``maps`` with roughness widened by what the normal maps lost (what
  ``ship_asset`` does by default);
- ``maps as JPEG``: ``maps`` with its normal and data maps written as a JPEG input's
  were before they shipped lossless (quality 90, the input's chroma subsampling);
- ``downsample --protocol 1``: ``geoscaler downsample MESH --scale S --time-budget T
  --protocol 1`` (the default method, 60 s: the base colour optimised through unlit views, the
  other maps by their class with Toksvig roughness), read back from the GLB it wrote;
- ``downsample``: the same command as a user runs it (protocol 2 on these meshes: ``direct``,
  then every map trained through lit views, :mod:`geoscaler.pipeline.lit`), in the same run.

With ``--split``, two more candidates say where ``maps+toksvig``'s lit error lives:
``base colour at full size`` (the original's base colours, every other map by its class) and
``maps at full size`` (the class base colours, every other map the original's). What one of
them gains over ``maps+toksvig`` bounds what optimising that part alone could gain.

With ``--figure DIR``: a lit picture per mesh and scale, ``DIR/lit_MESH_xS.png``: two near
views of the original beside Lanczos-every-map and what ``downsample`` ships (zooms, error
heatmaps; :func:`geoscaler.report.figures.comparison_sheet`).

Without MESH: the PBR development meshes in ../shared/data (skipped cleanly when absent).
``--views`` takes the first N of the protocol's 60 directions in its spread order
(:func:`geoscaler.render.cameras.spread_order`); 60 is the protocol.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from geoscaler.io import load_mesh
from geoscaler.io.images import encoded_image, open_image_bytes
from geoscaler.mesh import BASE_COLOR, SourceImage, TexturedMesh
from geoscaler.pipeline.shipping import ship_asset
from geoscaler.protocol import FAR_DISTANCE, NEAR_DISTANCE, VALIDATION_DISTANCE, Evaluation
from geoscaler.render.cameras import Camera, spread_order, validation_cameras
from geoscaler.render.lit import lit_scores
from geoscaler.render.metrics import evaluate
from geoscaler.render.renderer import Renderer
from geoscaler.resize.filters import resize_channels
from geoscaler.resize.maps import COLOR, resize_map, texture_class
from geoscaler.resize.sizes import SizePlan, SizeRule

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
PBR_MESHES = [
    "ph_painted_wooden_stool/painted_wooden_stool_1k.gltf",
    "ph_sofa_03/sofa_03_1k.gltf",
    "ph_wooden_bookshelf_worn/wooden_bookshelf_worn_1k.gltf",
    "ph_wooden_table_02/wooden_table_02_1k.gltf",
]
SETS = {"Q": VALIDATION_DISTANCE, "near": NEAR_DISTANCE, "far": FAR_DISTANCE}
PRODUCTS = {"downsample --protocol 1": ("--protocol", "1"), "downsample": ()}
"""The product's runs, in this order: unlit optimisation alone, then what a user gets."""


@dataclass
class Scores:
    """Mean metrics of one candidate: protocol 2 per set, protocol 1 on Q; for a `downsample`
    run, what its lit stage did (from its report)."""

    lit_psnr_fg: dict[str, float] = field(default_factory=dict)
    lit_ssim_fg: dict[str, float] = field(default_factory=dict)
    unlit_psnr_fg_q: float = float("nan")
    texture_bytes: int = 0
    seconds: float = float("nan")
    lit_stage: str = ""


def every_map(mesh: TexturedMesh, scale: int, resample: Image.Resampling) -> TexturedMesh:
    """Every map resized by one Pillow filter on its stored values (``round(side / scale)``)."""
    return mesh.with_images(
        {id(px): resize_channels(px, _size(px, scale), resample) for px, _ in mesh.images()}
    )


def _size(pixels: np.ndarray, scale: int) -> tuple[int, int]:
    return tuple(max(1, int(np.floor(side / scale + 0.5))) for side in pixels.shape[:2])


def class_maps(mesh: TexturedMesh, scale: int, toksvig: bool = False) -> TexturedMesh:
    """The class filters of ``geoscaler.resize.maps``, the base colour by Lanczos (linear),
    with or without Toksvig roughness."""
    rule = SizeRule(scale=scale)
    bases = [
        None
        if m.base_color_texture is None
        else resize_map(m.base_color_texture, rule.size(*m.base_color_texture.shape[:2]), COLOR)
        for m in mesh.materials
    ]
    shipped, _ = ship_asset(mesh, SizePlan(rule, rule, rule), bases, "lanczos", toksvig=toksvig)
    return shipped


def full_size(original: TexturedMesh, mesh: TexturedMesh, base_colour: bool) -> TexturedMesh:
    """``mesh`` with its base colours (``base_colour``) or its other maps as the original's."""
    replacements = {}
    for (before, places), (after, _) in zip(original.images(), mesh.images(), strict=True):
        if (places[0][1] == BASE_COLOR) == base_colour:
            replacements[id(after)] = before
    return mesh.with_images(replacements)


def as_jpeg(original: TexturedMesh, mesh: TexturedMesh) -> TexturedMesh:
    """``mesh`` with every normal and data map round-tripped through the JPEG encoding a JPEG
    input's maps were written with (its source's subsampling, quality 90)."""
    replacements = {}
    for (before, places), (after, _) in zip(original.images(), mesh.images(), strict=True):
        material, slot = places[0]
        source = original.materials[material].sources.get(slot)
        if slot == BASE_COLOR or texture_class(slot) == COLOR or source is None:
            continue
        jpeg = SourceImage(before, "image/jpeg", source.data, source.name)
        data, _ = encoded_image(after, jpeg, "jpeg")
        decoded = np.asarray(open_image_bytes(data).convert("RGB"))
        replacements[id(after)] = decoded[..., : after.shape[2]] if after.ndim == 3 else decoded
    return mesh.with_images(replacements)


def downsampled(
    mesh_path: Path, scale: int, budget: float, folder: Path, extra: tuple[str, ...] = ()
) -> tuple[TexturedMesh, float, str]:
    """What ``geoscaler downsample`` (with ``extra`` flags) ships, read back from the GLB it
    wrote, the command's wall-clock seconds and what its lit stage did (:func:`lit_stage`)."""
    out = folder / f"out_x{scale}{''.join(extra)}.glb"
    report = out.with_suffix(".json")
    command = [str(Path(sys.executable).parent / "geoscaler"), "downsample", str(mesh_path)]
    command += ["--scale", str(scale), "--time-budget", str(budget), "-o", str(out), "--force"]
    command += ["--report", str(report)]
    started = time.perf_counter()
    run = subprocess.run([*command, *extra], capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if run.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{run.stderr[-2000:]}")
    return load_mesh(out), seconds, lit_stage(json.loads(report.read_text()))


def lit_stage(report: dict) -> str:
    """What a report's lit stage shipped and from which start, or why it did not run."""
    lit = report["details"].get("lit")
    if not lit:
        return "no lit stage"
    if not lit["validation_scores"]:
        return f"lit stage not run ({lit['stopped_by']})"
    start = lit.get("start_maps") or "class"
    weighed = " (other starts left out)" if lit.get("other_starts_left_out") else ""
    return (
        f"lit stage shipped {lit['shipped']}, from {start} maps{weighed}, {lit['steps']} steps"
    )


def unlit_psnr(original: TexturedMesh, candidate: TexturedMesh, cameras: list[Camera]) -> float:
    """Protocol 1 PSNR-fg (unlit base colour, references at full size) over ``cameras``."""
    evaluation = Evaluation(reference_max_size=None)
    reference, own = Renderer(original, "cpu", evaluation), Renderer(candidate, "cpu", evaluation)
    scores = []
    with torch.no_grad():
        for camera in cameras:
            gbuffer = reference.rasterize(camera)
            target = reference.render_reference(gbuffer)[None]
            mask = reference.foreground(gbuffer)[None]
            same = candidate.faces is original.faces and candidate.positions is original.positions
            own_gbuffer = gbuffer if same else own.rasterize(camera)
            image = own.render(own_gbuffer, own.mip_textures(_base_colors(candidate)))[None]
            scores.append(float(evaluate(image, target, mask)["psnr_fg"][0]))
    return float(np.mean(scores))


def _base_colors(mesh: TexturedMesh) -> list[np.ndarray | None]:
    return [m.base_color_texture for m in mesh.materials]


def texture_bytes(mesh: TexturedMesh) -> int:
    """Bytes of every image as the writer would encode it (its source's format, or PNG)."""
    total = 0
    for pixels, places in mesh.images():
        material, slot = places[0]
        total += len(encoded_image(pixels, mesh.materials[material].sources.get(slot))[0])
    return total


def lit_figure(mesh: TexturedMesh, candidates: dict[str, TexturedMesh], title: str) -> np.ndarray:
    """The comparison sheet of ``candidates`` lit on two near views (protocol 2)."""
    from geoscaler.render.lit import LitScene, lit_materials
    from geoscaler.render.renderer import image_to_uint8
    from geoscaler.report.figures import comparison_sheet

    picked = [3, 40]
    cameras = [validation_cameras(NEAR_DISTANCE)[i] for i in picked]
    scene = LitScene(Renderer(mesh, "cpu", Evaluation(reference_max_size=None)))
    scores, _ = lit_scores(mesh, list(candidates.values()), cameras, "cpu")
    original = lit_materials(mesh, "cpu")
    shown = {
        name: (LitScene(Renderer(c, "cpu", scene.renderer.evaluation)), lit_materials(c, "cpu"))
        for name, c in candidates.items()
    }
    references, foreground, renders = [], [], {name: [] for name in candidates}
    with torch.no_grad():
        for camera in cameras:
            view = scene.view(camera)
            references.append(image_to_uint8(scene.render(view, original)))
            foreground.append(scene.renderer.foreground(view.gbuffer).numpy())
            for name, (own, maps) in shown.items():
                renders[name].append(image_to_uint8(own.render(own.view(camera), maps)))
    return comparison_sheet(
        references=references,
        candidates=renders,
        psnr_fg={n: s["psnr_fg"].tolist() for n, s in zip(candidates, scores, strict=True)},
        foreground=foreground,
        view_titles=[f"view {i} at distance {NEAR_DISTANCE:g}, lit" for i in picked],
        column_titles=["original", *candidates],
        title=title,
    )


def score_mesh(
    path: Path,
    scale: int,
    views: int,
    budget: float | None,
    figure: Path | None = None,
    split: bool = False,
) -> dict[str, Scores]:
    mesh = load_mesh(path)
    candidates = {
        "bicubic-every-map": every_map(mesh, scale, Image.Resampling.BICUBIC),
        "lanczos-every-map": every_map(mesh, scale, Image.Resampling.LANCZOS),
    }
    maps = class_maps(mesh, scale)
    candidates["maps"] = maps
    candidates["maps+toksvig"] = class_maps(mesh, scale, toksvig=True)
    if split:
        for name, base_colour in (("base colour at full size", True), ("maps at full size", False)):
            candidates[name] = full_size(mesh, candidates["maps+toksvig"], base_colour)
    candidates["maps as JPEG"] = as_jpeg(mesh, maps)
    walls, stages = {}, {}
    with tempfile.TemporaryDirectory() as folder:
        if budget is not None:
            for name, flags in PRODUCTS.items():
                candidates[name], walls[name], stages[name] = downsampled(
                    path, scale, budget, Path(folder), flags
                )
        if figure is not None:
            shown = {
                k: v
                for k, v in candidates.items()
                if k in ("lanczos-every-map", "downsample --protocol 1", "downsample")
            }
            title = f"{path.parent.name} x{scale}, protocol 2 (lit)"
            Image.fromarray(lit_figure(mesh, shown, title)).save(
                figure / f"lit_{path.parent.name}_x{scale}.png"
            )
        order = spread_order(60)[:views]
        results = {name: Scores() for name in candidates}
        for set_name, distance in SETS.items():
            cameras = [validation_cameras(distance)[i] for i in order]
            scores, _ = lit_scores(mesh, list(candidates.values()), cameras, "cpu")
            for name, per_view in zip(candidates, scores, strict=True):
                results[name].lit_psnr_fg[set_name] = float(per_view["psnr_fg"].mean())
                results[name].lit_ssim_fg[set_name] = float(per_view["ssim_fg"].mean())
        cameras = [validation_cameras(VALIDATION_DISTANCE)[i] for i in order]
        for name, candidate in candidates.items():
            results[name].unlit_psnr_fg_q = unlit_psnr(mesh, candidate, cameras)
            results[name].texture_bytes = texture_bytes(candidate)
            results[name].seconds = walls.get(name, float("nan"))
            results[name].lit_stage = stages.get(name, "")
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("meshes", type=Path, nargs="*")
    parser.add_argument("--scale", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--views", type=int, default=60)
    parser.add_argument("--time-budget", type=float, default=60.0)
    parser.add_argument("--no-product", action="store_true", help="skip `geoscaler downsample`")
    parser.add_argument("--split", action="store_true", help="where the lit error lives")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--figure", type=Path, help="folder for a lit picture per mesh")
    args = parser.parse_args()
    paths = args.meshes or [DATA / entry for entry in PBR_MESHES]
    if args.figure is not None:  # made first: a missing folder must not end a long run late
        args.figure.mkdir(parents=True, exist_ok=True)
    table = []
    for path in paths:
        if not path.exists():
            print(f"no mesh at {path}: skipped", file=sys.stderr)
            continue
        for scale in args.scale:
            start = time.perf_counter()
            budget = None if args.no_product else args.time_budget
            results = score_mesh(path, scale, args.views, budget, args.figure, args.split)
            for name, scores in results.items():
                table.append(
                    {"mesh": path.parent.name, "scale": scale, "candidate": name, **scores.__dict__}
                )
                lit = "  ".join(f"{s} {scores.lit_psnr_fg[s]:6.2f}" for s in SETS)
                print(
                    f"{path.parent.name:28s} x{scale} {name:24s} lit {lit}  "
                    f"ssim Q {scores.lit_ssim_fg['Q']:.4f}  unlit Q "
                    f"{scores.unlit_psnr_fg_q:6.2f}  {scores.texture_bytes / 1e3:8.1f} kB"
                    + ("" if scores.seconds != scores.seconds else f"  {scores.seconds:.1f} s")
                    + (f"  ({scores.lit_stage})" if scores.lit_stage else ""),
                    flush=True,
                )
            print(f"  ({time.perf_counter() - start:.0f} s)", flush=True)
            if args.json:  # after every mesh and scale, so that a long run keeps what it made
                args.json.write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
