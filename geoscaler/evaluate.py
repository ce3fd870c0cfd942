"""Protocol evaluation: cached views of the original, and candidates scored against them.

A :class:`ViewSet` rasterises its cameras once and renders the reference images once; every
candidate texture (and, for methods that move them, UVs) is then rendered from the same
G-buffers and compared with :func:`geoscaler.metrics.evaluate`. Candidates are scored as they
would ship: 8-bit textures.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from geoscaler.cameras import Camera
from geoscaler.metrics import evaluate
from geoscaler.raster import GBuffer
from geoscaler.render import Renderer
from geoscaler.texture import MipTexture, texture_to_linear

Progress = Callable[[int, int], None]
"""Called as ``progress(done, total)`` while long work runs."""


def mip_textures(
    renderer: Renderer, textures: Sequence[np.ndarray | None]
) -> list[MipTexture | None]:
    """Mip chains of uint8 sRGB candidate textures, one per material (None: untextured)."""
    return [
        None if texture is None else MipTexture(texture_to_linear(texture, renderer.device))
        for texture in textures
    ]


class ViewSet:
    """G-buffers, reference renders and foreground masks of a list of cameras.

    Args:
        renderer: the renderer of the mesh under evaluation.
        cameras: the views (e.g. :func:`geoscaler.cameras.validation_cameras`).
        progress: optional callback while the set is built.
        deadline: a ``time.perf_counter()`` value; cameras not cached by then are dropped
            (keeping at least ``min_views``). For training pools under a time budget.

    Attributes:
        gbuffers: one :class:`GBuffer` per camera.
        references: ``(N, H, W, 3)`` float32 sRGB renders with the reference textures.
        foreground: ``(N, H, W)`` bool pixels the mesh covers.
    """

    def __init__(
        self,
        renderer: Renderer,
        cameras: Sequence[Camera],
        progress: Progress | None = None,
        deadline: float | None = None,
        min_views: int = 1,
    ):
        self.renderer = renderer
        self.cameras = list(cameras)
        reference = renderer.reference_textures()
        self.gbuffers: list[GBuffer] = []
        references, foreground = [], []
        with torch.no_grad():
            for index, camera in enumerate(self.cameras):
                if deadline is not None and index >= min_views and time.perf_counter() > deadline:
                    self.cameras = self.cameras[:index]  # out of time: keep what is cached
                    break
                gbuffer = renderer.rasterize(camera)
                self.gbuffers.append(gbuffer)
                references.append(renderer.render(gbuffer, reference))
                foreground.append(renderer.foreground(gbuffer))
                if progress:
                    progress(index + 1, len(self.cameras))
        self.references = torch.stack(references)
        self.foreground = torch.stack(foreground)

    def __len__(self) -> int:
        return len(self.cameras)

    def render(
        self,
        textures: Sequence[MipTexture | None],
        uvs: torch.Tensor | None = None,
        views: Sequence[int] | None = None,
    ) -> torch.Tensor:
        """``(len(views), H, W, 3)`` sRGB renders of a candidate (all views by default)."""
        views = range(len(self)) if views is None else views
        return torch.stack([self.renderer.render(self.gbuffers[i], textures, uvs) for i in views])

    def score(
        self, textures: Sequence[np.ndarray | None], uvs: np.ndarray | None = None
    ) -> dict[str, torch.Tensor]:
        """Protocol metrics of 8-bit candidate textures (and UVs), each ``(N,)`` over views."""
        mips = mip_textures(self.renderer, textures)
        uv_tensor = None
        if uvs is not None:
            uv_tensor = torch.as_tensor(uvs, dtype=torch.float32, device=self.renderer.device)
        with torch.no_grad():
            images = self.render(mips, uv_tensor)
            return evaluate(images, self.references, self.foreground)
