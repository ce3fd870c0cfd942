"""Capture the desktop app showing mesh files, as a user who runs ``geoscaler view MESH`` sees it.

Each mesh is opened in the app (the same window, the imgui test engine drives it under Xvfb)
and the window is saved as a PNG once it is loaded (with ``--steps N``: once Optimise/Start has
run N steps, through ``--renderer``); with ``--sheet`` the captures are stacked into one
picture with their file names.

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python benchmarks/app_capture.py \\
        STOOL.gltf STOOL_x4.glb --out docs/stool --sheet docs/stool.png
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from app_support import import_app_module  # noqa: E402


def capture(
    mesh: Path, picture: Path, renderer: str = "exact", steps: int = 0, seconds: float = 300.0
) -> None:
    """Open ``mesh`` in the app and save the window once it shows the mesh; with ``steps``,
    first press Optimise/Start (``direct`` trained through ``renderer``) and wait for that
    many steps."""
    main = import_app_module("main")
    training = import_app_module("training")
    from imgui_bundle.immapp import testing

    app = main.App(mesh, picture.parent, training.TrainingSettings(renderer=renderer))

    def wait(ctx, condition) -> None:
        end = time.perf_counter() + seconds
        while not condition() and time.perf_counter() < end:
            time.sleep(0.05)
            ctx.yield_()

    def session(ctx) -> None:
        wait(ctx, lambda: app.session is not None)
        if steps:
            ctx.item_click("//Optimise/Start")
            wait(ctx, lambda: app.progress is not None and app.progress.step >= steps)
        ctx.yield_(5)
        testing.capture(ctx, str(picture))

    params = app.runner_params(None)
    testing.run(test_function=session, runner_params=params, add_ons_params=main.add_ons())


def sheet(pictures: list[Path], names: list[str], out: Path) -> None:
    """The captures one above the other, each with its name."""
    images = [Image.open(p).convert("RGB") for p in pictures]
    width = max(i.width for i in images)
    rows = []
    for image, name in zip(images, names, strict=True):
        canvas = Image.new("RGB", (width, image.height + 24), (20, 20, 20))
        canvas.paste(image, (0, 24))
        ImageDraw.Draw(canvas).text((8, 6), name, fill=(230, 230, 230))
        rows.append(np.asarray(canvas))
    Image.fromarray(np.concatenate(rows)).save(out, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("meshes", type=Path, nargs="+")
    parser.add_argument("--out", type=Path, required=True, help="folder for the captures")
    parser.add_argument("--sheet", type=Path, help="also stack them into this PNG")
    parser.add_argument("--renderer", default="exact", help="what Optimise trains through")
    parser.add_argument("--steps", type=int, default=0, help="press Start, wait for N steps")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    pictures = []
    for mesh in args.meshes:
        picture = args.out / f"{mesh.stem}.png"
        capture(mesh, picture, args.renderer, args.steps)
        pictures.append(picture)
        print(f"wrote {picture}")
    if args.sheet:
        sheet(pictures, [m.name for m in args.meshes], args.sheet)
        print(f"wrote {args.sheet}")


if __name__ == "__main__":
    main()
