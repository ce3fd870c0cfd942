"""One open mesh in the app: its GL resources, the two looks compared, its outputs.

The *original* look is the protocol's reference texture; the *candidate* look starts as bicubic
at the chosen scale (what artists do today) and is replaced live by the optimiser's textures.
"""

from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from geoscaler.mesh import TexturedMesh
from geoscaler.protocol import IMAGE_SIZE
from geoscaler.resize.filters import bicubic, reference_textures

from .bookmarks import Bookmarks
from .gl_renderer import GLRenderer, Surface

DEMO_NAME = "geoscaler_demo"
POINTS = 50_000
"""Vertices (every n-th) by which the views frame the mesh (:meth:`Orbit.frame`): for the demo
asset at 240,000 vertices, 2 ms instead of 9, and the same distance to 1 part in 10,000."""


class Session:
    """A loaded mesh and what the app draws of it.

    Args:
        ctx: the window's GL context.
        mesh: the mesh.
        mesh_path: its file (None for the built-in demo asset).
        out_dir: where exports and the bookmarks file go.
        scale: the scale of the starting (bicubic) candidate.
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        mesh: TexturedMesh,
        mesh_path: Path | None,
        out_dir: Path,
        scale: int,
        image_size: int = IMAGE_SIZE,
    ):
        self.mesh = mesh
        self.mesh_path = mesh_path
        self.name = DEMO_NAME if mesh_path is None else mesh_path.stem
        self.out_dir = out_dir
        self.renderer = GLRenderer(ctx, mesh, image_size=image_size)
        self.references = reference_textures(mesh)
        self.original = Surface(self.renderer, self.references)
        self.candidate_textures: list[np.ndarray | None] = []
        self.candidate_uvs: np.ndarray | None = None
        self.candidate: Surface | None = None
        self.candidate_label = ""
        self.targets = self.renderer.target_pair()  # (original, candidate)
        self.previews = self.renderer.target_pair(preview=True)
        positions = mesh.normalized_positions()
        self.points = positions[:: max(1, len(positions) // POINTS)]  # to frame the views by
        self.bookmarks = Bookmarks(out_dir / f"{self.name}.bookmarks.json", self.name)
        self.set_bicubic(scale)

    @property
    def display_path(self) -> str:
        return "built-in demo asset" if self.mesh_path is None else str(self.mesh_path)

    @property
    def view_shape(self) -> tuple[int, int]:
        """``(width, height)`` in pixels of each of the two views."""
        return self.targets.targets[0].shape

    def set_view_shape(self, shape: tuple[int, int]) -> bool:
        """Make the views (and their previews) ``shape`` pixels; True if that changed them."""
        if shape == self.view_shape:
            return False
        for pair in (self.targets, self.previews):
            pair.release()
        self.targets = self.renderer.target_pair(shape=shape)
        self.previews = self.renderer.target_pair(preview=True, shape=shape)
        return True

    def set_bicubic(self, scale: int) -> None:
        """The candidate becomes bicubic at ``scale`` (raises GeoscalerError if too small)."""
        textures = [None if t is None else bicubic(t, scale) for t in self.references]
        self.set_candidate(textures, None, f"bicubic x{scale}")

    def set_candidate(
        self,
        textures: list[np.ndarray | None],
        uvs: np.ndarray | None,
        label: str,
        chains: list[list[np.ndarray] | None] | None = None,
    ) -> None:
        """Show ``textures`` (8-bit sRGB, one per material) with ``uvs`` as the candidate
        (``chains``: their mip chains, if already built)."""
        surface = Surface(self.renderer, textures, uvs, chains)
        if self.candidate is not None:
            self.candidate.release()
        self.candidate, self.candidate_textures = surface, textures
        self.candidate_uvs, self.candidate_label = uvs, label

    def release(self) -> None:
        for thing in (self.original, self.candidate, self.targets, self.previews):
            if thing is not None:
                thing.release()
