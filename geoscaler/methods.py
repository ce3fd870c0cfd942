"""The registry of downsampling methods that `compare`, `bench` and `downsample` share.

A method takes a mesh and an integer scale and returns 8-bit textures ``s`` times smaller
(one per textured material) and, if it moves them, new UVs. Every method starts from the
protocol's reference maps (originals above 2048 texels reduced to 2048 with Lanczos).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from geoscaler.baselines import BASELINES, reference_texture
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh


@dataclass
class MethodOptions:
    """Settings a learned method may use; the baselines ignore them.

    Attributes:
        device: ``"auto"``, ``"cpu"`` or ``"cuda"``.
        seed: random seed; on the CPU the same seed gives the same result (on CUDA, atomic
            additions may change the last bits).
        steps: optimisation steps (None: the method's default).
        time_budget: wall-clock seconds the method may spend (None: no limit).
        on_event: receives progress events from long-running methods.
        extra: further settings: ``"optimize"`` (OptimizeConfig fields), ``"controller"``
            (pause/stop from another thread), ``"validation_views"`` (a ViewSet of Q to reuse),
            or method-specific ones such as a network variant.
    """

    device: str = "auto"
    seed: int = 0
    steps: int | None = None
    time_budget: float | None = None
    on_event: Callable[[Any], None] | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class MethodResult:
    """What a method produced.

    Attributes:
        textures: per material, the ``(h, w, C)`` uint8 sRGB texture (None if untextured).
        uvs: ``(V, 2)`` float32 new UVs, or None when the method keeps the mesh's own.
        seconds: wall-clock time of the whole method.
        details: method-specific facts for the report (steps run, device, ...).
    """

    textures: list[np.ndarray | None]
    uvs: np.ndarray | None = None
    seconds: float = 0.0
    details: dict[str, Any] = field(default_factory=dict)


Method = Callable[[TexturedMesh, int, MethodOptions], MethodResult]


def remaining_budget(budget: float | None, spent: float) -> float | None:
    """What is left of a time budget (None: no budget) after ``spent`` seconds of work done for
    the method, such as caching the validation views it is handed; kept positive."""
    return None if budget is None else max(budget - spent, 1e-3)


def reference_textures(mesh: TexturedMesh) -> list[np.ndarray | None]:
    """The protocol's reference map of every material (None where untextured)."""
    return [
        None if m.base_color_texture is None else reference_texture(m.base_color_texture)
        for m in mesh.materials
    ]


def _baseline(name: str) -> Method:
    resize = BASELINES[name]

    def run(mesh: TexturedMesh, scale: int, options: MethodOptions) -> MethodResult:
        textures = [None if t is None else resize(t, scale) for t in reference_textures(mesh)]
        return MethodResult(textures)

    run.__doc__ = f"Pillow/closed-form baseline {name!r} on each reference map."
    return run


METHODS: dict[str, Method] = {name: _baseline(name) for name in BASELINES}
# Names that run a registered method with fixed settings, e.g. "geoscaler-base" is "geoscaler"
# with extra {"variant": "base"}; tables list them as methods of their own.
ALIASES: dict[str, tuple[str, dict[str, Any]]] = {}


def register(name: str, method: Method) -> None:
    """Add a method to the registry (learned methods register themselves on import)."""
    METHODS[name] = method


def register_alias(name: str, method: str, extra: dict[str, Any]) -> None:
    """Make ``name`` run ``method`` with ``extra`` merged into its options."""
    ALIASES[name] = (method, extra)


def known_method(name: str) -> bool:
    """Whether ``name`` is a registered method or an alias of one."""
    return name in METHODS or name in ALIASES


def known_methods() -> str:
    """Every name :func:`run_method` accepts, for error messages."""
    return ", ".join([*METHODS, *ALIASES])


def run_method(
    name: str, mesh: TexturedMesh, scale: int, options: MethodOptions | None = None
) -> MethodResult:
    """Run a registered method (or alias) and time it, wall clock, set-up included."""
    if not known_method(name):
        raise GeoscalerError(f"unknown method {name!r}; choose one of: {known_methods()}")
    options = options or MethodOptions()
    if name in ALIASES:
        name, extra = ALIASES[name]
        options = replace(options, extra={**options.extra, **extra})
    start = time.perf_counter()
    result = METHODS[name](mesh, scale, options)
    result.seconds = time.perf_counter() - start
    return result


# Learned methods register themselves; imported last because they build on this module.
from geoscaler import direct as _direct  # noqa: E402, F401
from geoscaler.nn import method as _network  # noqa: E402, F401
