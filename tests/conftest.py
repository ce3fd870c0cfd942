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
