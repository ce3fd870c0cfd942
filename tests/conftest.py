"""Shared fixtures: the development meshes in ../shared/data, used by path, skipped when absent."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

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


def small_renderer(mesh, device=None):
    """A renderer with 128-pixel images: 16 times cheaper than the protocol's 512."""
    from geoscaler.render import Renderer

    return Renderer(mesh, device, image_size=128)


@pytest.fixture
def one_view(monkeypatch):
    """CLI runs on view 0 only, 128 pixels square (the real command: 60 views, 512 pixels)."""
    from geoscaler import compare
    from geoscaler.cameras import validation_cameras

    def cameras(distance, views=None):
        all_views = validation_cameras(distance)
        return [all_views[i] for i in views] if views is not None else all_views[:1]

    monkeypatch.setattr(compare, "protocol_cameras", cameras)
    monkeypatch.setattr(compare, "Renderer", small_renderer)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the app's window tests first, whatever order the files were given in: once a
    headless EGL context has been current in the process, Mesa refuses the window's GLX context
    (``X_GLXMakeCurrent``: BadAccess) and Xlib's default handler exits the interpreter."""
    items.sort(key=lambda item: item.path.name != "test_app_gui.py")
