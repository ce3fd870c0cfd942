"""Bookmarked viewpoints, saved as JSON beside the mesh's output.

The file holds ``{"mesh": ..., "bookmarks": [{"name": ..., "orbit": {...}}, ...]}`` and is
written atomically each time the list changes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from geoscaler.errors import GeoscalerError
from geoscaler.io import write_atomically

from .orbit import Orbit


@dataclass
class Bookmark:
    """A named camera."""

    name: str
    orbit: Orbit


class Bookmarks:
    """The bookmarks of one mesh, kept in sync with ``path``.

    Args:
        path: the JSON file (read when it exists, created on the first change).
        mesh_name: recorded in the file, for people who open it.
    """

    def __init__(self, path: Path, mesh_name: str):
        self.path = Path(path)
        self.mesh_name = mesh_name
        self.items: list[Bookmark] = []
        if self.path.exists():
            self.items = self._read()

    def _read(self) -> list[Bookmark]:
        try:
            document = json.loads(self.path.read_text())
            return [
                Bookmark(str(item["name"]), Orbit.from_dict(item["orbit"]))
                for item in document["bookmarks"]
            ]
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise GeoscalerError(f"{self.path}: not a bookmarks file ({error})") from error

    def add(self, orbit: Orbit, name: str | None = None) -> Bookmark:
        """Bookmark a copy of ``orbit`` (default name ``view N``) and save."""
        bookmark = Bookmark(name or f"view {len(self.items) + 1}", Orbit(*orbit.to_tuple()))
        self.items.append(bookmark)
        self.save()
        return bookmark

    def rename(self, index: int, name: str) -> None:
        self.items[index].name = name
        self.save()

    def remove(self, index: int) -> None:
        del self.items[index]
        self.save()

    def save(self) -> None:
        """Write the file atomically (its folder must exist)."""
        document = {
            "mesh": self.mesh_name,
            "bookmarks": [{"name": b.name, "orbit": b.orbit.to_dict()} for b in self.items],
        }
        text = json.dumps(document, indent=2) + "\n"
        write_atomically(self.path, lambda tmp: tmp.write_text(text))
