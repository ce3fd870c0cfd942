"""The classic filters as methods: each resizes every reference map on its own
(:mod:`geoscaler.filters`: box, bicubic, Lanczos, PBD), with no view of the mesh."""

from __future__ import annotations

from geoscaler.filters import BASELINES, reference_textures
from geoscaler.mesh import TexturedMesh
from geoscaler.methods.registry import MethodOptions, MethodResult, Run, RunContext, register


def filter_method(name: str) -> Run:
    """The method that resizes each reference map with the filter ``name``."""
    resize = BASELINES[name]

    def run(
        mesh: TexturedMesh, scale: int, options: MethodOptions, context: RunContext
    ) -> MethodResult:
        textures = [None if t is None else resize(t, scale) for t in reference_textures(mesh)]
        return MethodResult(textures)

    run.__doc__ = f"The filter {name!r} on each reference map."
    return run


for _name in BASELINES:
    register(_name, filter_method(_name), learned=False)
