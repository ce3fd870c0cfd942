"""Method ``direct``: the texels of the small texture are the parameters.

Initialised from Lanczos, held as sRGB values in [0, 1] and optimised through the protocol
renderer, which decodes them and filters in linear light; the mesh's UVs stay as they are,
unless ``--uv repack`` or ``auto`` moves the charts first (:mod:`geoscaler.methods.repacked`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from geoscaler.color import linear_to_srgb, srgb_to_linear, srgb_to_linear_slope, texture_to_linear
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
from geoscaler.render.renderer import Renderer
from geoscaler.resize.filters import lanczos
from geoscaler.resize.sizes import SizeRule

# Texels are optimised as sRGB values (see TexelModel): in linear light the same rate is far
# too large for dark texels. The first steps are majorise-minimise steps (geoscaler.optim.majorize),
# since Adam's first steps move every texel by about the rate; then AdamW at 0.01 with a short
# warm-up. A candidate that validates worse sends the loop back to its best at a quarter of the
# rate, so a near-lossless start is not wrecked. No SSIM term: it gained less at equal time
# (benchmarks/first_steps.py; see docs/decisions/direct-step-schedule.md).
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
