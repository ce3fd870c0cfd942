"""What the app's tests need: a headless GL context, or a clean skip where there is none.

``make test`` sets ``GEOSCALER_REQUIRE_GL=1``: there a missing context fails the test instead of
skipping it, so CI cannot pass without running the app's tests.
"""

from __future__ import annotations

import os

import pytest

REQUIRED = os.environ.get("GEOSCALER_REQUIRE_GL") == "1"


def unavailable(reason: str):
    """Skip (or, under ``GEOSCALER_REQUIRE_GL=1``, fail) with ``reason``."""
    if REQUIRED:
        pytest.fail(f"GEOSCALER_REQUIRE_GL=1 but {reason}")
    pytest.skip(reason)


def import_app_module(name: str):
    """``geoscaler.app.<name>``, or skip when moderngl (the ``app`` extra) is missing."""
    try:
        import moderngl  # noqa: F401
    except ImportError:
        unavailable("moderngl is not installed (pip install 'geoscaler[app]')")
    import importlib

    return importlib.import_module(f"geoscaler.app.{name}")


def gl_context():
    """A headless EGL context, or skip when this machine has none."""
    gl_renderer = import_app_module("gl_renderer")
    from geoscaler.errors import GeoscalerError

    try:
        return gl_renderer.headless_context()
    except GeoscalerError as error:
        unavailable(str(error))
