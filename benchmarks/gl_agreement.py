"""How closely the app's OpenGL renderer matches the torch renderer (PROTOCOL.md views).

For every development mesh (../shared/data) and the demo asset, renders protocol views both
ways (headless EGL, no window) and prints PSNR-fg of the GL image against the torch image, and
the share of pixels whose foreground differs. ``tests/test_gl_renderer.py`` asserts >= 40 dB.

    .venv/bin/python benchmarks/gl_agreement.py [--views 0 7 30] [--distance 2.4]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--views", type=int, nargs="+", default=[0, 7, 30])
    parser.add_argument("--distance", type=float, default=2.4)
    args = parser.parse_args()

    from conftest import development_meshes

    from geoscaler.app.gl_renderer import GLRenderer, headless_context
    from geoscaler.io import load_mesh
    from geoscaler.procedural import demo_mesh
    from geoscaler.render.cameras import validation_cameras
    from geoscaler.render.metrics import psnr_fg
    from geoscaler.render.renderer import Renderer

    ctx = headless_context()
    print(f"GL: {ctx.info['GL_RENDERER']}; views {args.views} at distance {args.distance}")
    cameras = validation_cameras(args.distance)
    meshes = [(path.parent.name, path) for path in development_meshes()] + [("demo", None)]
    for name, path in meshes:
        mesh = demo_mesh() if path is None else load_mesh(path)
        gl = GLRenderer(ctx, mesh)
        surface = gl.reference_surface()
        renderer = Renderer(mesh, "cpu")
        textures = renderer.reference_textures()
        row = {}
        for view in args.views:
            image, foreground = gl.render_image(cameras[view], surface)
            gbuffer = renderer.rasterize(cameras[view])
            reference = renderer.render(gbuffer, textures)
            mask = renderer.foreground(gbuffer)
            gl_image = torch.from_numpy(image).float()[None] / 255
            psnr = float(psnr_fg(gl_image, reference[None], mask[None]))
            differ = float((torch.from_numpy(foreground) != mask).float().mean())
            row[f"view {view}"] = {"psnr_fg": round(psnr, 2), "foreground_differs": differ}
        surface.release()
        print(name, json.dumps(row))


if __name__ == "__main__":
    main()
