"""The classic filters as methods: each resizes every reference map on its own
(:mod:`geoscaler.resize.filters`: box, bicubic, Lanczos, PBD), with no view of the mesh."""

from __future__ import annotations

from geoscaler.mesh import TexturedMesh
from geoscaler.methods.registry import (
    MethodOptions,
    MethodResult,
    Run,
    RunContext,
    output_sizes_for,
    reference_maps,
    register,
)
from geoscaler.resize.filters import BASELINES
from geoscaler.resize.sizes import SizeRule


def filter_method(name: str) -> Run:
    """The method that resizes each reference map with the filter ``name``."""
    resize = BASELINES[name]

    def run(
        mesh: TexturedMesh, rule: SizeRule, options: MethodOptions, context: RunContext
    ) -> MethodResult:
        sizes = output_sizes_for(mesh, rule, context.renderer)
        maps = reference_maps(mesh, context.renderer)
        textures = [
            None if t is None else resize(t, size) for t, size in zip(maps, sizes, strict=True)
        ]
        return MethodResult(textures)

    run.__doc__ = f"The filter {name!r} on each reference map."
    return run


for _name in BASELINES:
    register(_name, filter_method(_name), learned=False)
