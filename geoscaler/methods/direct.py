"""Method ``direct``: the texels of the small texture are the parameters.

Initialised from Lanczos, held as sRGB values in [0, 1] and optimised through the protocol
renderer, which decodes them and filters in linear light; the mesh's UVs stay as they are,
unless ``--uv repack`` or ``auto`` moves the charts first (:mod:`geoscaler.methods.repacked`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from geoscaler.filters import lanczos
from geoscaler.mesh import TexturedMesh
from geoscaler.methods.learned import fit, loop_config, method_renderer
from geoscaler.methods.registry import (
    MethodOptions,
    MethodResult,
    RunContext,
    output_sizes_for,
    register,
)
from geoscaler.methods.repacked import repacked_direct
from geoscaler.render import Renderer
from geoscaler.sizes import SizeRule
from geoscaler.texture import (
    linear_to_srgb,
    srgb_to_linear,
    srgb_to_linear_slope,
    texture_to_linear,
)

# Texels are optimised as sRGB values (see TexelModel). Measured at 4x, 300 steps, no SSIM term:
# learning rate 0.003 / 0.01 gained +2.84 / +2.82 dB PSNR-fg over bicubic on Q on the lego scan
# and +1.86 / +1.88 dB on spot. (Parameterised in linear light, lr 0.05 sent the lego to 30 dB
# before it recovered and 0.002 was needed for +2.79 dB.) The SSIM term gained less at equal time.
# Budgets cut runs short (15 s: 6-47 steps): on bob at 4x, 20 steps gained +0.44 / +0.57 / +0.72
# / +0.77 dB at lr 0.005 (10 warm-up steps) / 0.01 / 0.02 / 0.04 (3), 150 steps +1.00 / +1.06 /
# +1.07 at 0.005 / 0.01 / 0.02; hence 0.02, doubled at most for runs cut short. That rate wrecks
# a near-lossless start (4096 scans at 1024: Q fell from 59 to 49 dB on the banana), so a
# candidate that validates worse sends the loop back to its best at a quarter of the rate
# (60 s at 4x: chain +1.49 dB over bicubic instead of Lanczos's +0.92, banana +1.34 instead of
# +0.69; bob +1.07 with, +1.05 without: it never backtracked).
# Adam's first steps move every texel by about the rate: the loop now starts with 5
# majorise-minimise steps (geoscaler.majorize), then Adam at 0.01 without a boost. Gains over
# bicubic on 20 Q views after 5 / 20 / 80 steps, 48 training views
# (`python benchmarks/first_steps.py`, 4x), Adam at 0.02 from Lanczos -> the majorised start:
# bob +0.51 / +0.92 / +1.06 -> +0.87 / +0.96 / +1.05, sofa +0.40 / +1.00 / +1.42 -> +1.24 /
# +1.29 / +1.43, frypan +0.90 / +1.35 / +1.74 -> +1.38 / +1.59 / +1.75, spot (not tuned on)
# +1.18 / +1.65 / +1.86 -> +1.73 / +1.80 / +1.86.
DEFAULT_CONFIG = {
    "steps": 300,
    "lr": 0.01,
    "warmup_steps": 3,
    "majorized_steps": 5,
    "backtrack": 0.25,
    "ssim_weight": 0.0,
    "validate_every": 100,
}


class TexelModel:
    """Free texels, one ``(h, w, 3)`` texture per textured material.

    The parameters are the texels' sRGB-encoded values in [0, 1], the values that ship;
    :meth:`candidate` decodes them to linear light for the renderer. A step of the optimiser
    then changes dark and bright texels by similar visible amounts (in linear light the same
    step is ~13 times more visible on a dark texel than on a bright one).

    Args:
        textures: per material a ``(h, w, 3)`` linear start, or None (untextured); materials
            given the same tensor share one set of texels (one image shown by both).
    """

    def __init__(self, textures: list[torch.Tensor | None]):
        encoded: dict[int, torch.Tensor] = {}  # materials given one tensor share its texels
        for t in textures:
            if t is not None and id(t) not in encoded:
                encoded[id(t)] = linear_to_srgb(t).detach().requires_grad_(True)
        self.encoded = [None if t is None else encoded[id(t)] for t in textures]

    def parameters(self) -> list[torch.Tensor]:
        return list({id(t): t for t in self.encoded if t is not None}.values())

    def candidate(self) -> tuple[list[torch.Tensor | None], None]:
        return [None if t is None else srgb_to_linear(t) for t in self.encoded], None

    @torch.no_grad()
    def slopes(self) -> list[torch.Tensor | None]:
        """Per material d(linear texel) / d(parameter), ``(h, w, 3)`` (None: untextured)."""
        return [None if t is None else srgb_to_linear_slope(t) for t in self.encoded]

    @torch.no_grad()
    def project(self) -> None:
        for texture in self.parameters():
            texture.clamp_(0.0, 1.0)

    @torch.no_grad()
    def restore(self, textures: Sequence[torch.Tensor | None]) -> None:
        """Set the texels to the ``(h, w, 3)`` linear ``textures`` (a validated candidate)."""
        for encoded, texture in zip(self.encoded, textures, strict=True):
            if encoded is not None:
                encoded.copy_(linear_to_srgb(texture))


def lanczos_starts(
    mesh: TexturedMesh, rule: SizeRule, renderer: Renderer
) -> list[torch.Tensor | None]:
    """Per material the ``(h, w, 3)`` linear start: ``renderer``'s reference map resized with
    Lanczos to the size ``rule`` gives, on ``renderer``'s device (materials showing one map
    share one tensor; None: untextured)."""
    sizes = output_sizes_for(mesh, rule, renderer)
    starts: dict[int, torch.Tensor] = {}  # one start per distinct map: shared maps stay shared
    for texture, size in zip(renderer.reference_maps(), sizes, strict=True):
        if texture is not None and id(texture) not in starts:
            starts[id(texture)] = texture_to_linear(lanczos(texture, size), renderer.device)
    return [None if t is None else starts[id(t)] for t in renderer.reference_maps()]


def lanczos_texel_model(mesh: TexturedMesh, rule: SizeRule, renderer: Renderer) -> TexelModel:
    """Free texels started from ``renderer``'s reference maps resized with Lanczos to the
    sizes ``rule`` gives, on ``renderer``'s device."""
    return TexelModel(lanczos_starts(mesh, rule, renderer))


def start_model(
    mesh: TexturedMesh,
    rule: SizeRule,
    renderer: Renderer,
    starts: list[torch.Tensor | None] | None = None,
) -> TexelModel:
    """Free texels from per-material linear ``starts`` (a new layout's bake), Lanczos where a
    start is None (a material that keeps its layout) or without ``starts``."""
    lanczos_start = lanczos_starts(mesh, rule, renderer)
    if starts is None:
        return TexelModel(lanczos_start)
    return TexelModel(
        [s if s is not None else t for s, t in zip(starts, lanczos_start, strict=True)]
    )


def direct(
    mesh: TexturedMesh, rule: SizeRule, options: MethodOptions, context: RunContext
) -> MethodResult:
    """Optimise the texels of Lanczos-initialised textures at the sizes ``rule`` gives; with
    ``options.settings["uv"]`` ``"repack"`` or ``"auto"``, in a new UV layout
    (:func:`geoscaler.methods.repacked.repacked_direct`)."""
    started = context.clock.now()  # the time budget covers the set-up too
    if options.settings.get("uv", "keep") != "keep":
        return repacked_direct(mesh, rule, options, context, started, start_model, DEFAULT_CONFIG)
    renderer = method_renderer(mesh, options, context)
    model = lanczos_texel_model(mesh, rule, renderer)
    config = loop_config(DEFAULT_CONFIG, options, context)
    return fit(mesh, rule, renderer, model, config, context, started)


register("direct", direct, learned=True, steps=lambda settings: DEFAULT_CONFIG["steps"])
