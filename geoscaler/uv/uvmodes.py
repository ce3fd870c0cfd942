"""``--uv``: what ``direct`` does with the mesh's UV layout. Import-light: the command
line builds its parser from it without importing torch."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from geoscaler.errors import GeoscalerError

UV_MODES = ("keep", "repack", "auto")
"""Keep the mesh's UV layout, repack its charts (:mod:`geoscaler.uv.atlas`), or choose per mesh
(:func:`geoscaler.methods.repacked.raced`)."""


def check_uv_mode(mode: str) -> str:
    """``--uv``: one of :data:`UV_MODES`."""
    if mode not in UV_MODES:
        raise GeoscalerError(f"--uv {mode!r}: choose keep, repack or auto")
    return mode


JOB_UV_MODE = "auto"
"""``direct``'s layout in the jobs that make assets (``downsample``, ``batch``, the app) where
``--uv`` is not given: the race keeps the mesh's own layout unless a new one ranks better on
the validation and is below it on no view set (docs/decisions/auto-by-default.md)."""


def add_uv_argument(parser: Any, default: str) -> None:
    """``--uv keep|repack|auto`` on an argparse parser; ``default``: what it means unset (the
    parsed value is None then: :func:`uv_mode` resolves it, knowing the method)."""
    parser.add_argument(
        "--uv",
        choices=list(UV_MODES),
        help="with the direct method: keep the mesh's UV layout, repack its charts by the "
        "texels the views ask of them (every map re-baked, new UVs written), or auto (a short "
        "trial in each layout, then the one that validates better goes on; a new layout "
        f"below the own one on any view set stays out) (default: {default})",
    )


def uv_mode(given: str | None, default: str, methods: Sequence[str], renderer: str) -> str:
    """``--uv`` as ``given``, checked; unset, ``default`` where ``direct`` is among ``methods``
    and trains through the exact ``renderer`` (the only one a new layout trains through),
    ``keep`` otherwise."""
    if given is not None:
        return check_uv_mode(given)
    return default if "direct" in methods and renderer == "exact" else "keep"
