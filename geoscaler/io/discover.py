"""Finding the assets of a folder tree: what ``bench`` scores and ``batch`` downsamples.

A folder whose ``meta.json`` names an ``"entry"`` holds one asset, that file (its subfolders
belong to it); elsewhere every mesh file (:data:`~geoscaler.io.paths.SUPPORTED_SUFFIXES`) is
one, and the side files (.bin, .mtl, images) are not assets. Hidden folders and files are not
searched, nor the folders the caller skips.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

from .paths import SUPPORTED_SUFFIXES


class FoundAsset(NamedTuple):
    """One asset of a tree: its file, its path relative to the root (posix), and whether a
    ``meta.json`` named it."""

    path: Path
    relative: str
    from_meta: bool


def meta_entry(folder: Path) -> str | None:
    """The ``"entry"`` that ``folder/meta.json`` names, or None (no file, no key, bad JSON)."""
    try:
        entry = json.loads((folder / "meta.json").read_text(encoding="utf-8")).get("entry")
    except (OSError, ValueError, AttributeError):
        return None
    return entry if isinstance(entry, str) and entry else None


def find_assets(root: Path, skip: Sequence[Path] = ()) -> list[FoundAsset]:
    """Every asset under ``root``, in sorted order (folders depth first)."""
    skipped = {Path(p).resolve() for p in skip}
    found = []
    for folder, subfolders, files in os.walk(root):
        here = Path(folder)
        subfolders[:] = sorted(
            d for d in subfolders if not d.startswith(".") and (here / d).resolve() not in skipped
        )
        entry = meta_entry(here)
        if entry is not None:
            subfolders[:] = []
            found.append(
                FoundAsset(here / entry, (here.relative_to(root) / entry).as_posix(), True)
            )
            continue
        for name in sorted(files):
            if not name.startswith(".") and Path(name).suffix.lower() in SUPPORTED_SUFFIXES:
                path = here / name
                found.append(FoundAsset(path, path.relative_to(root).as_posix(), False))
    return found
