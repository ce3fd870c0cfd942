"""Shared fixtures: the development meshes in ../shared/data, used by path, skipped when absent."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from geoscaler.protocol import Evaluation

DATA_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def development_meshes() -> list[Path]:
    """Entry files of every development mesh (empty when ../shared/data is absent)."""
    if not DATA_DIR.is_dir():
        return []
    entries = []
    for meta in sorted(DATA_DIR.glob("*/meta.json")):
        entry = json.loads(meta.read_text())["entry"]
        entries.append(meta.parent / entry)
    return entries


def mesh_params():
    """pytest params over the development meshes, or one skipped param when there are none."""
    meshes = development_meshes()
    if not meshes:
        return [pytest.param(None, marks=pytest.mark.skip(reason=f"no meshes in {DATA_DIR}"))]
    return [pytest.param(path, id=path.parent.name) for path in meshes]


ONE_VIEW = Evaluation.quick((0,))
"""What CLI runs in tests evaluate on: view 0 only, 128 pixels square (``main(...,
evaluation=ONE_VIEW)``; the real command: 60 views, 512 pixels)."""


def small_renderer(mesh, views=(0,), device=None):
    """A renderer of protocol ``views`` at 128 pixels: the quick checks' evaluation (the
    protocol renders all 60 views at 512 pixels, 16 times the pixels of each)."""
    from geoscaler.render.renderer import Renderer

    return Renderer(mesh, device, Evaluation.quick(views))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the app's window tests first, whatever order the files were given in: once a
    headless EGL context has been current in the process, Mesa refuses the window's GLX context
    (``X_GLXMakeCurrent``: BadAccess) and Xlib's default handler exits the interpreter."""
    items.sort(key=lambda item: item.path.name != "test_app_gui.py")
