"""One open mesh in the app: its GL resources, the two looks compared, its outputs.

The *original* look is the protocol's reference texture; the *candidate* look starts as bicubic
at the chosen scale (what artists do today) and is replaced live by the optimiser's textures.
Lit (protocol 2), the original shows every map at full resolution and the candidate the asset
as it ships: its base colour with every other map resized by its class.
"""

from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from geoscaler.mesh import TexturedMesh
from geoscaler.pipeline.shipping import ship_asset
from geoscaler.protocol import IMAGE_SIZE
from geoscaler.resize.filters import bicubic, reference_textures
from geoscaler.resize.sizes import SizePlan, SizeRule

from .bookmarks import Bookmarks
from .gl_renderer import GLRenderer, LitSurface, Surface

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
        self.lit_original: LitSurface | None = None
        self.lit_candidate: LitSurface | None = None
        self._other_maps: dict[int, TexturedMesh] = {}  # scale -> the mesh, maps resized
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
        if self.lit_candidate is not None:
            self.lit_candidate.release()
            self.lit_candidate = None
        self.candidate, self.candidate_textures = surface, textures
        self.candidate_uvs, self.candidate_label = uvs, label

    def lit_surfaces(self) -> tuple[LitSurface, LitSurface | None]:
        """``(original, candidate)`` lit, made when first asked; the candidate is None where it
        has UVs of its own (its other maps would need re-baking into them: it is drawn unlit)."""
        if self.lit_original is None:
            self.lit_original = LitSurface(self.renderer)
        if self.lit_candidate is None and self.candidate_uvs is None:
            self.lit_candidate = LitSurface(self.renderer, self.candidate_asset())
        return self.lit_original, self.lit_candidate

    def candidate_asset(self) -> TexturedMesh:
        """The mesh as the candidate would ship: its base colours, every other map resized by
        its class at the candidate's scale (resized once per scale)."""
        scale = self.candidate_scale()
        if scale not in self._other_maps:
            rule = SizeRule(scale=scale)
            kept = [m.base_color_texture for m in self.mesh.materials]
            self._other_maps[scale], _ = ship_asset(
                self.mesh, SizePlan(rule, rule, rule), kept, "kept"
            )
        asset = self._other_maps[scale]
        originals = [m.base_color_texture for m in asset.materials]
        pairs = zip(originals, self.candidate_textures, strict=True)
        return asset.with_images({id(o): t for o, t in pairs if o is not None and t is not None})

    def candidate_scale(self) -> int:
        """The reduction factor of the candidate's first texture against its reference."""
        for reference, texture in zip(self.references, self.candidate_textures, strict=True):
            if reference is not None and texture is not None:
                return max(2, round(reference.shape[1] / texture.shape[1]))
        return 2

    def release(self) -> None:
        things = (self.original, self.candidate, self.targets, self.previews)
        for thing in (*things, self.lit_original, self.lit_candidate):
            if thing is not None:
                thing.release()
