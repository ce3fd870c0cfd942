"""What the views from far away ask of a texture: why a sharpened texture can fall below the
filters there.

The renderer shows far views from coarser mip levels, 2 x 2 box averages of the texture in
linear light; a texture box-filtered from the original in linear light has exactly the
original's levels there. This scores, on the protocol's sets (gain in dB over bicubic, at the
sizes `geoscaler downsample` ships, references from the full-resolution original):

- ``box (linear)``, ``bicubic``, ``lanczos``;
- ``direct``: free texels trained from the Lanczos start for ``--steps`` steps on the loop's
  training views, without a budget and without a floor (its best on Q), ``--loop`` overriding
  the loop's settings (e.g. ``'{"distances": [[1.8, 3.0], [1.5, 4.2], [3.5, 4.2]]}'``);
- ``direct`` blended with each filter (``w`` of direct), and ``direct`` with its 2 x 2 box
  averages set to the original's (its first mip level made exact).

Usage:
    python benchmarks/far_floor.py MESH [--scale 4] [--steps 200] [--loop JSON]
        [--sets 2.4 1.5 4.0]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from geoscaler.color import linear_to_texture, texture_to_linear
from geoscaler.io import load_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.methods.direct import DEFAULT_CONFIG, lanczos_texel_model
from geoscaler.optim.loop import OptimizeConfig, optimize
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.pipeline.downsampling import product_evaluation
from geoscaler.process import configure_process
from geoscaler.protocol import PROTOCOL_EVALUATION
from geoscaler.render.cameras import view_set_cameras
from geoscaler.render.metrics import mean_metrics
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import build_mip_chain
from geoscaler.render.views import ViewCache, ViewSet
from geoscaler.resize.filters import bicubic, lanczos, output_sizes, reference_textures


def exact_first_level(codes: np.ndarray, original: list[torch.Tensor], scale: int) -> np.ndarray:
    """8-bit ``codes`` moved so that their first mip level (2 x 2 means in linear light) is the
    level of the ``original`` chain at that size, up to clamping to [0, 1] and 8-bit rounding;
    ``scale`` a power of two."""
    linear = texture_to_linear(codes)
    fix = original[scale.bit_length()] - build_mip_chain(linear)[1]
    fixed = linear + fix.repeat_interleave(2, 0).repeat_interleave(2, 1)
    return linear_to_texture(fixed.clamp(0, 1))


def blend(a: np.ndarray, b: np.ndarray, weight: float) -> np.ndarray:
    """``weight * a + (1 - weight) * b`` of 8-bit codes, rounded."""
    mixed = weight * a.astype(np.float32) + (1 - weight) * b[..., : a.shape[-1]]
    return np.clip(np.rint(mixed), 0, 255).astype(np.uint8)


def direct_candidate(
    mesh: TexturedMesh, renderer: Renderer, scale: int, steps: int, loop: dict
) -> np.ndarray:
    """The textured material's texture after ``steps`` unbudgeted steps, best on Q, no floor."""
    settings = {**DEFAULT_CONFIG, "steps": steps, "backtrack": None, "validate_every": steps}
    config = OptimizeConfig(**{**settings, **loop})
    sizes = output_sizes(mesh, scale, None)
    validation = Validation(validation_view_sets(renderer), sizes)  # no baselines: no floor
    result = optimize(renderer, lanczos_texel_model(mesh, scale, renderer), config, validation)
    (texture,) = [t for t in result.textures if t is not None]
    return linear_to_texture(texture)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("mesh")
    parser.add_argument("--scale", type=int, default=4)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--loop", default="{}", help="JSON overrides of the loop's settings")
    parser.add_argument("--sets", type=float, nargs="+", default=[2.4, 1.5, 4.0])
    args = parser.parse_args()
    if args.scale < 2 or args.scale & (args.scale - 1):
        parser.error(f"--scale {args.scale}: a power of two, so that mip levels are the sizes")
    configure_process()
    mesh = load_mesh(args.mesh)
    renderer = Renderer(mesh, "cpu", product_evaluation(PROTOCOL_EVALUATION))
    sizes = output_sizes(mesh, args.scale, None)
    originals = reference_textures(mesh, None)
    textured = [i for i, texture in enumerate(originals) if texture is not None]
    if len(textured) != 1:
        parser.error(f"{args.mesh}: one textured material expected, found {len(textured)}")
    original = originals[textured[0]]
    levels = build_mip_chain(texture_to_linear(original[..., :3]))  # what the renderer shows
    filters = {"bicubic": bicubic(original, args.scale), "lanczos": lanczos(original, args.scale)}
    direct = direct_candidate(mesh, renderer, args.scale, args.steps, json.loads(args.loop))
    textures = {
        "box (linear)": linear_to_texture(levels[args.scale.bit_length() - 1]),
        **filters,
        "direct": direct,
        "direct, first level exact": exact_first_level(direct, levels, args.scale),
    }
    for name, codes in filters.items():
        for weight in (0.75, 0.5):
            textures[f"{weight:g} direct + {1 - weight:g} {name}"] = blend(direct, codes, weight)
    psnr: dict[str, dict[float, float]] = {name: {} for name in textures}
    for distance in args.sets:
        views = ViewSet(renderer, view_set_cameras(distance, PROTOCOL_EVALUATION))
        cache = ViewCache(views, sizes, with_taps=True)
        for name, codes in textures.items():
            shipped = [codes if i in textured else None for i in range(len(sizes))]
            psnr[name][distance] = mean_metrics(cache.score(shipped))["psnr_fg"]
        del cache, views
    print(f"{'texture':32}", " ".join(f"{d:>6g}" for d in args.sets))
    for name, row in psnr.items():
        gains = " ".join(f"{row[d] - psnr['bicubic'][d]:+6.2f}" for d in args.sets)
        print(f"{name:32}", gains)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
