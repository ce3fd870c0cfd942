"""``--uv``: what ``direct`` does with the mesh's UV layout. Import-light: the command
line builds its parser from it without importing torch."""

from __future__ import annotations

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


def add_uv_argument(parser: Any) -> None:
    """``--uv keep|repack|auto`` on an argparse parser (``downsample``, ``compare``, ``bench``)."""
    parser.add_argument(
        "--uv",
        choices=list(UV_MODES),
        default="keep",
        help="with the direct method: keep the mesh's UV layout (default), repack its charts "
        "by the texels the views ask of them (every map re-baked, new UVs written), or auto "
        "(a short trial in each layout, then the one that validates better goes on)",
    )
