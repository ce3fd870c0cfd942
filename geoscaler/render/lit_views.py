"""Cached lit views of an original, and candidates of fixed map sizes rendered on them.

Protocol 2's shading is not linear in the texels, so unlike protocol 1's
:class:`~geoscaler.render.views.ViewCache` a lit pixel is not a fixed sum of texels. What is
fixed, for candidates that keep the mesh's UVs, is every *sample*'s lookup: each sample reads a
fixed weighted sum of texels of any map of a given size. A :class:`LitViews` therefore keeps,
per view and material, a sample-level :class:`~geoscaler.render.texture.TapMatrix` for each map
size the candidates have, the samples' tangent frames and view vectors, and the reference's
colours at the object's pixels; a candidate's render is then one sparse product per map size,
the BRDF per sample (:func:`~geoscaler.render.lit.shade`) and a box average per pixel, with
gradients in every map's texels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from geoscaler.color import linear_to_srgb
from geoscaler.render.cameras import Camera
from geoscaler.render.devices import tensor_bytes
from geoscaler.render.lit import (
    Light,
    LitMaterial,
    LitScene,
    material_surface,
    shade,
    shading_frame,
)
from geoscaler.render.metrics import psnr_fg
from geoscaler.render.texture import MipLayout, TapMatrix, UVFootprint


@dataclass
class _Part:
    """The samples of one material in one view.

    Attributes:
        material: the material's index.
        rows: ``(n,)`` int64 object-pixel row of each sample.
        frame: ``(3, 3, n)`` the samples' tangent frames (:func:`shading_frame`).
        view: ``(3, n)`` unit vectors from each sample to the eye.
        taps: map ``(h, w)`` -> the ``(n, texels)`` lookups of a mip chain of that size.
    """

    material: int
    rows: torch.Tensor
    frame: torch.Tensor
    view: torch.Tensor
    taps: dict[tuple[int, int], TapMatrix]


@dataclass
class LitTapView:
    """One cached camera: its object's pixels, the reference there, its samples by material.

    Attributes:
        pixels: ``(F,)`` flat indices of the pixels the mesh covers.
        reference: ``(F, 3)`` the original's sRGB lit colours there.
        parts: the samples of each material seen.
        lights: the camera's lights.
    """

    pixels: torch.Tensor
    reference: torch.Tensor
    parts: list[_Part]
    lights: list[Light]


def map_sizes(materials: Sequence[LitMaterial]) -> list[set[tuple[int, int]]]:
    """Per material the sizes ``(h, w)`` of its maps."""
    return [{chain.size for chain in m.maps.values() if chain is not None} for m in materials]


class _TapReader:
    """slot -> ``(3, n)`` a material's map read at a part's samples through its taps, each
    chain read once (a packed map serves two slots)."""

    def __init__(self, part: _Part, material: LitMaterial):
        self.part, self.material = part, material
        self.read: dict[int, torch.Tensor] = {}

    def __call__(self, slot: str) -> torch.Tensor | None:
        chain = self.material.maps.get(slot)
        if chain is None:
            return None
        if id(chain) not in self.read:
            self.read[id(chain)] = self.part.taps[chain.size](chain.table).T
        return self.read[id(chain)]


class LitViews:
    """Lit views of an original for candidates with its UVs and maps of fixed sizes, cached
    one camera at a time.

    Args:
        scene: the original's geometry (its renderer's image size and supersampling).
        reference: the original's materials (:func:`~geoscaler.render.lit.lit_materials`).
        sizes: per material the sizes of the candidates' maps (:func:`map_sizes`).
        cameras: the views, cached in order by :meth:`cache_next`.
    """

    def __init__(
        self,
        scene: LitScene,
        reference: Sequence[LitMaterial],
        sizes: Sequence[set[tuple[int, int]]],
        cameras: Sequence[Camera],
    ):
        self.scene, self.reference = scene, list(reference)
        device = scene.renderer.device
        self.layouts = [{size: MipLayout(*size, device) for size in s} for s in sizes]
        self.cameras = list(cameras)
        self.views: list[LitTapView] = []

    def __len__(self) -> int:
        return len(self.views)

    @property
    def complete(self) -> bool:
        return len(self.views) == len(self.cameras)

    @property
    def nbytes(self) -> int:
        """Bytes the cached views hold: taps (and their transposes once a backward pass made
        them), frames, view vectors, rows, pixels and references."""
        total = 0
        for view in self.views:
            total += tensor_bytes([view.pixels, view.reference])
            for part in view.parts:
                total += tensor_bytes([part.rows, part.frame, part.view])
                total += sum(taps.nbytes for taps in part.taps.values())
        return total

    @torch.no_grad()
    def cache_next(self) -> bool:
        """Cache the next camera; False (and nothing done) when all are cached."""
        if self.complete:
            return False
        scene, renderer = self.scene, self.scene.renderer
        lit = scene.view(self.cameras[len(self.views)])
        image = scene.render(lit, self.reference).reshape(-1, 3)
        pixel_of_sample = renderer.pixel_of_sample(lit.gbuffer).long()
        pixels = torch.unique(pixel_of_sample)
        row_of_pixel = torch.full(
            (renderer.image_size**2,), -1, dtype=torch.long, device=pixels.device
        )
        row_of_pixel[pixels] = torch.arange(len(pixels), device=pixels.device)
        frame = shading_frame(lit.geometric, lit.tangent, lit.handedness, lit.view)
        parts = []
        for index, layouts in enumerate(self.layouts):
            hit = torch.nonzero(lit.material == index).squeeze(1)
            if len(hit) == 0:
                continue
            footprint = UVFootprint(*(t.index_select(0, hit) for t in lit.footprint))
            taps = {}
            for size, layout in layouts.items():
                count, texel, weight = layout.taps(footprint)
                taps[size] = TapMatrix.by_rows(count, texel, weight, (len(hit), layout.num_texels))
            rows = row_of_pixel.index_select(0, pixel_of_sample.index_select(0, hit))
            parts.append(
                _Part(index, rows, frame.index_select(2, hit), lit.view.index_select(1, hit), taps)
            )
        self.views.append(LitTapView(pixels, image.index_select(0, pixels), parts, lit.lights))
        return True

    def colours(self, index: int, materials: Sequence[LitMaterial]) -> torch.Tensor:
        """``(F, 3)`` sRGB lit colours of a candidate at the object's pixels of cached view
        ``index`` (:attr:`LitTapView.pixels` order), differentiable in its float chains'
        texels; ``materials`` one per material of the mesh, maps of the cached sizes."""
        view = self.views[index]
        linear = view.reference.new_zeros(3, len(view.pixels))
        share = 1.0 / self.scene.renderer.supersample**2
        for part in view.parts:
            material = materials[part.material]
            surface = material_surface(material, part.frame, _TapReader(part, material))
            radiance = shade(surface, part.view, view.lights)
            sums = zip(linear, radiance, strict=True)
            linear = torch.stack([row.index_add(0, part.rows, values) for row, values in sums])
        return linear_to_srgb(linear.T * share)

    def loss(self, index: int, materials: Sequence[LitMaterial]) -> torch.Tensor:
        """The mean squared error of a candidate's sRGB colours against the reference's over
        the object's pixels and channels of cached view ``index`` (differentiable)."""
        return (self.colours(index, materials) - self.views[index].reference).square().mean()

    @torch.no_grad()
    def psnr(self, materials: Sequence[LitMaterial], count: int | None = None) -> np.ndarray:
        """``(count,)`` PSNR-fg (dB) of a candidate on the first ``count`` cached views (all
        by default): :func:`~geoscaler.render.metrics.psnr_fg` of its lit render, over the
        object's pixels (the foreground) as a ``1 x F`` image."""
        count = len(self.views) if count is None else count
        values = []
        for index in range(count):
            reference = self.views[index].reference[None, None]  # (1, 1, F, 3)
            image = self.colours(index, materials)[None, None]
            foreground = torch.ones(reference.shape[:3], dtype=torch.bool, device=image.device)
            values.append(float(psnr_fg(image, reference, foreground)[0]))
        return np.asarray(values)
