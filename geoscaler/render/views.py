"""Cached views of the original, and candidates rendered and scored on them.

A :class:`ViewSet` rasterises its cameras once and renders the reference images once; every
candidate texture (and, for methods that move them, UVs) is then rendered from the same
G-buffers. A :class:`ViewCache` adds the tap renderer: with the mesh's own UVs a pixel is a
fixed weighted sum of texels, so each view's texture taps are found once and a render is one
gather per material (what training steps, validation and the report's scores use). Candidates are
scored as they would ship: 8-bit textures, compared with :func:`geoscaler.render.metrics.evaluate`.

A view set may also be rendered by the paper's soft rasteriser (:class:`geoscaler.render.soft.
SoftRenderer`, which mirrors the renderer's methods): :func:`training_views` makes a training
pool of either kind.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from geoscaler.color import linear_to_srgb, texture_to_linear
from geoscaler.render.cameras import Camera, view_set_cameras
from geoscaler.render.devices import tensor_bytes
from geoscaler.render.metrics import evaluate
from geoscaler.render.raster import GBuffer
from geoscaler.render.renderer import Renderer
from geoscaler.render.soft import SoftFragments, SoftRenderer, SoftSettings
from geoscaler.render.texture import MipLayout, MipTexture, TapMatrix, UVFootprint

Progress = Callable[[int, int], None]
"""Called as ``progress(done, total)`` while long work runs."""


class ViewSet:
    """G-buffers, reference renders and foreground masks of a list of cameras, cached in order.

    A set caches all its cameras when made, or (``eager=False``) none: then :meth:`cache_next`
    adds them one at a time, so that a loop can build its views while it trains.

    Args:
        renderer: the renderer of the mesh under evaluation, or a soft one (then the
            "G-buffers" are its :class:`~geoscaler.render.soft.SoftFragments` and the references
            are soft renders).
        cameras: the views (e.g. :func:`geoscaler.render.cameras.validation_cameras`).
        progress: optional callback while the set is built.
        eager: cache every camera now.

    Attributes:
        cameras: every camera of the set, cached or not; ``len(self)`` are cached.
        gbuffers: one :class:`GBuffer` per cached camera.
    """

    def __init__(
        self,
        renderer: Renderer | SoftRenderer,
        cameras: Sequence[Camera],
        progress: Progress | None = None,
        eager: bool = True,
    ):
        self.renderer = renderer
        self.cameras = list(cameras)
        self.gbuffers: list[GBuffer] = []
        self._references: list[torch.Tensor] = []
        self._foreground: list[torch.Tensor] = []
        if eager:
            while self.cache_next():
                if progress:
                    progress(len(self), len(self.cameras))

    def __len__(self) -> int:
        return len(self.gbuffers)

    @property
    def complete(self) -> bool:
        """Every camera is cached."""
        return len(self) == len(self.cameras)

    @torch.no_grad()
    def cache_next(self) -> bool:
        """Cache the next camera; False (and nothing done) when all are cached."""
        if self.complete:
            return False
        camera = self.cameras[len(self)]
        if isinstance(self.renderer, Renderer):  # references on the original's own UVs
            gbuffer, reference, foreground = self.renderer.cached_view(camera)
        else:
            gbuffer = self.renderer.rasterize(camera)
            reference = self.renderer.render(gbuffer, self.renderer.reference_textures())
            foreground = self.renderer.foreground(gbuffer)
        self._references.append(reference)
        self._foreground.append(foreground)
        self.gbuffers.append(gbuffer)
        return True

    @property
    def references(self) -> torch.Tensor:
        """``(N, H, W, 3)`` float32 sRGB renders of the cached views with the reference maps
        (stacked anew at each call: :meth:`stacked` takes the first few)."""
        return self.stacked()[0]

    @property
    def foreground(self) -> torch.Tensor:
        """``(N, H, W)`` bool pixels the mesh covers in each cached view (stacked anew)."""
        return self.stacked()[1]

    def stacked(self, count: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``((count, H, W, 3) references, (count, H, W) foreground)`` of the first ``count``
        cached views (all by default), stacked: a copy, not kept, so that a set holds each
        reference once."""
        count = len(self) if count is None else count
        return torch.stack(self._references[:count]), torch.stack(self._foreground[:count])

    @property
    def nbytes(self) -> int:
        """Bytes the cached views hold: G-buffers (or soft fragments), references, masks."""
        images = tensor_bytes(self._references + self._foreground)
        return images + sum(gbuffer.nbytes for gbuffer in self.gbuffers)

    def reference(self, view: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``((H, W, 3) reference, (H, W) foreground)`` of one cached view, without stacking."""
        return self._references[view], self._foreground[view]

    def render(
        self,
        textures: Sequence[MipTexture | None],
        uvs: torch.Tensor | None = None,
        views: Sequence[int] | None = None,
    ) -> torch.Tensor:
        """``(len(views), H, W, 3)`` sRGB renders of a candidate (all cached views by default)."""
        views = range(len(self)) if views is None else views
        return torch.stack([self.renderer.render(self.gbuffers[i], textures, uvs) for i in views])

    def score(
        self,
        textures: Sequence[np.ndarray | None],
        uvs: np.ndarray | None = None,
        count: int | None = None,
    ) -> dict[str, torch.Tensor]:
        """Protocol metrics of 8-bit candidate textures (and UVs), each ``(N,)`` over the first
        ``count`` cached views (all by default)."""
        count = len(self) if count is None else count
        mips = self.renderer.mip_textures(textures)
        uv_tensor = None
        if uvs is not None:
            uv_tensor = torch.as_tensor(uvs, dtype=torch.float32, device=self.renderer.device)
        with torch.no_grad():
            images = self.render(mips, uv_tensor, range(count))
            return evaluate(images, *self.stacked(count))


class ViewCache:
    """A :class:`ViewSet` plus, for models that keep the mesh's UVs, every view's texture taps
    for candidate textures of fixed sizes, so a render is one sparse product per material, over
    the object's pixels only (the background is black).

    Taps are found when a view is first rendered (or :meth:`find_taps` asks), so a cache
    follows its view set as it grows
    (several caches, one per set of sizes, may share one view set).

    Args:
        views: cached G-buffers and reference renders.
        sizes: per material the candidate's texture ``(h, w)`` (None: untextured).
        with_taps: cache the taps (valid only while the UVs stay the mesh's own).
        renderer: renders candidates (default: the view set's); a renderer of the same mesh
            in another UV layout (:meth:`~geoscaler.render.renderer.Renderer.relaid`) renders them
            in that layout on the same G-buffers and references.
    """

    def __init__(
        self,
        views: ViewSet,
        sizes: Sequence[tuple[int, int] | None],
        with_taps: bool,
        renderer: Renderer | None = None,
    ):
        self.views = views
        self.renderer = views.renderer if renderer is None else renderer
        device = self.renderer.device
        self.sizes = list(sizes)
        self.layouts = [None if s is None else MipLayout(*s, device) for s in sizes]
        self.with_taps = with_taps
        self.taps: list[list[TapMatrix | None]] = []
        self.untextured: list[torch.Tensor] = []  # per view (F, 3) at its object's pixels
        self.object_pixels: list[torch.Tensor] = []  # per view (F,) its foreground pixels
        self._object_references: list[torch.Tensor] = []  # per view (F, 3) the reference

    def __len__(self) -> int:
        return len(self.views)

    @property
    def nbytes(self) -> int:
        """Bytes this cache holds beside its view set's: the taps (their transposes once a
        backward pass made them) and each view's object pixels, references and untextured
        colours."""
        taps = sum(t.nbytes for view in self.taps for t in view if t is not None)
        per_view = self.untextured + self.object_pixels + self._object_references
        return taps + tensor_bytes(per_view)

    def drop_taps(self) -> None:
        """Forget every view's taps, object pixels, references and untextured colours: the
        memory they hold goes back, and each view's are found again as it is next rendered."""
        self.taps, self.untextured = [], []
        self.object_pixels, self._object_references = [], []

    @torch.no_grad()
    def find_taps(self, view: int) -> None:
        """Find the taps of every cached view up to ``view`` (nothing without taps)."""
        while self.with_taps and len(self.taps) <= view:
            index = len(self.taps)
            gbuffer = self.views.gbuffers[index]
            reference, foreground = (t.flatten(0, 1) for t in self.views.reference(index))
            pixels = torch.nonzero(foreground).squeeze(1)
            row_of_pixel = torch.full(foreground.shape, -1, dtype=torch.int32, device=pixels.device)
            row_of_pixel[pixels] = torch.arange(
                len(pixels), dtype=torch.int32, device=pixels.device
            )
            self.object_pixels.append(pixels)
            self._object_references.append(reference.index_select(0, pixels))
            self.taps.append(self._taps(gbuffer, row_of_pixel, len(pixels)))
            self.untextured.append(self._untextured(gbuffer, pixels))

    def _taps(
        self, gbuffer: GBuffer | SoftFragments, row_of_pixel: torch.Tensor, rows: int
    ) -> list[TapMatrix | None]:
        """Per material the view's lookups folded into its object's pixels (``row_of_pixel``:
        each pixel's row of the ``rows`` rows): with fixed UVs a rendered pixel (before sRGB
        encoding) is a fixed weighted sum of texels of the candidate's mip chain, its samples'
        trilinear taps each weighted 1 / samples per pixel (a magnified sample taps its finer
        level alone), a pixel's taps of one texel merged into one (:meth:`TapMatrix.merged`:
        often half of them or more, where samples share texels); None: untextured or unseen."""
        if isinstance(gbuffer, SoftFragments):
            found = self.renderer.pixel_taps(gbuffer, self.layouts)
            return [
                None
                if taps is None
                else TapMatrix(row_of_pixel[taps[0]], *taps[1:], (rows, layout.num_texels))
                for taps, layout in zip(found, self.layouts, strict=True)
            ]
        footprint = self.renderer.footprint(gbuffer)
        row_of_sample = row_of_pixel.index_select(0, self.renderer.pixel_of_sample(gbuffer))
        per_material: list[torch.Tensor | None] = [None]  # None: every sample
        if len(self.layouts) > 1:
            material = self.renderer.face_material.index_select(0, gbuffer.tri_ids)
            materials = range(len(self.layouts))
            per_material = [torch.nonzero(material == i).squeeze(1) for i in materials]
        share = 1.0 / self.renderer.supersample**2
        taps: list[TapMatrix | None] = []
        for layout, samples in zip(self.layouts, per_material, strict=True):
            seen_samples = len(row_of_sample) if samples is None else len(samples)
            if layout is None or seen_samples == 0:
                taps.append(None)
                continue
            seen = footprint if samples is None else (t.index_select(0, samples) for t in footprint)
            row = row_of_sample if samples is None else row_of_sample.index_select(0, samples)
            row_of_tap, texel, weight = layout.taps_of_rows(UVFootprint(*seen), row)
            shape = (rows, layout.num_texels)
            taps.append(TapMatrix.merged(row_of_tap, texel, weight * share, shape))
        return taps

    def _untextured(self, gbuffer: GBuffer | SoftFragments, pixels: torch.Tensor) -> torch.Tensor:
        """``(F, 3)`` linear colour contributed by samples of untextured materials at the
        ``(F,)`` flat ``pixels`` (the object's). Every material textured: zeros, made as
        such (gathered from a zero image through its transpose they took 20 ms a view of
        200,000 object pixels)."""
        plain = [layout is None for layout in self.layouts]
        if not any(plain):
            return torch.zeros(len(pixels), 3, device=self.renderer.device)
        if isinstance(gbuffer, SoftFragments):
            image = self.renderer.untextured(gbuffer, plain)
        else:
            image = self._untextured_image(gbuffer, plain)
        return image.index_select(1, pixels).T.contiguous()

    def _untextured_image(self, gbuffer: GBuffer, plain: Sequence[bool]) -> torch.Tensor:
        """``(3, pixels)`` linear colour contributed by samples of the ``plain`` (untextured)
        materials."""
        material = self.renderer.face_material.index_select(0, gbuffer.tri_ids)
        is_plain = torch.tensor(plain, device=material.device)
        hit = torch.nonzero(is_plain[material]).squeeze(1)
        colours = self.renderer.factors.T.index_select(1, material[hit])
        image = colours.new_zeros(3, self.renderer.image_size**2)
        pixels = self.renderer.pixel_of_sample(gbuffer)[hit]
        return image.index_add(1, pixels, colours, alpha=1.0 / self.renderer.supersample**2)

    def render(
        self,
        view: int,
        textures: Sequence[torch.Tensor | MipTexture | None],
        uvs: torch.Tensor | None,
    ) -> torch.Tensor:
        """``(H, W, 3)`` sRGB render of a candidate in cached view ``view`` (differentiable).

        ``textures``: per material a ``(h, w, 3)`` linear texture, its mip chain
        (:func:`mip_chains`: made once for a candidate rendered in many views) or None."""
        mips = mip_chains(textures)
        if uvs is not None or not self.with_taps:
            return self.renderer.render(self.views.gbuffers[view], mips, uvs)
        colours = self.object_colours(view, mips)
        side = self.renderer.image_size
        image = colours.new_zeros(side * side, 3).index_copy(0, self.object_pixels[view], colours)
        return image.view(side, side, 3)

    def object_colours(
        self, view: int, textures: Sequence[torch.Tensor | MipTexture | None]
    ) -> torch.Tensor:
        """``(F, 3)`` sRGB colours of a candidate with the mesh's UVs at the object's pixels in
        cached view ``view`` (:attr:`object_pixels`: its foreground mask's, in order);
        differentiable. Needs the taps (``with_taps``)."""
        return linear_to_srgb(self.object_linear(view, textures))

    def object_reference(self, view: int) -> torch.Tensor:
        """``(F, 3)`` the reference's sRGB colours at the object's pixels of cached view
        ``view``, in :attr:`object_pixels` order (gathered once, with the view's taps)."""
        self.find_taps(view)
        return self._object_references[view]

    def object_linear(
        self,
        view: int,
        textures: Sequence[torch.Tensor | MipTexture | None],
        untextured: bool = True,
    ) -> torch.Tensor:
        """``(F, 3)`` linear colours before the sRGB encoding of :meth:`object_colours`;
        without ``untextured`` only the textured materials' part (linear in ``textures``)."""
        self.find_taps(view)
        linear = self.untextured[view] if untextured else torch.zeros_like(self.untextured[view])
        mips = mip_chains(textures)
        for index, (mip, taps) in enumerate(zip(mips, self.taps[view], strict=True)):
            if mip is not None and taps is not None:
                linear = linear + taps(mip.table) * self.renderer.factors[index]
        return linear

    def score(
        self,
        textures: Sequence[np.ndarray | None],
        uvs: np.ndarray | None = None,
        count: int | None = None,
    ) -> dict[str, torch.Tensor]:
        """Protocol metrics of 8-bit candidate textures (and UVs), each ``(N,)`` over the first
        ``count`` cached views (all by default).

        The same figures as :meth:`ViewSet.score` up to float rounding (about 1e-7 in the
        renders): with the cached taps a candidate is one gather per view. Candidates of other
        sizes or with their own UVs are rendered in full.
        """
        count = len(self) if count is None else count
        sizes = [None if t is None else tuple(t.shape[:2]) for t in textures]
        if uvs is not None or not self.with_taps or sizes != self.sizes:
            return self.views.score(textures, uvs, count)
        device = self.renderer.device
        linear = [None if t is None else texture_to_linear(t, device) for t in textures]
        with torch.no_grad():
            mips = mip_chains(linear)
            images = torch.stack([self.render(i, mips, None) for i in range(count)])
            views = self.views
            return evaluate(images, *views.stacked(count))


def mip_chains(textures: Sequence[torch.Tensor | MipTexture | None]) -> list[MipTexture | None]:
    """Per material the mip chain of a ``(h, w, C)`` linear texture (a chain or None passes as
    it is)."""
    return [t if t is None or isinstance(t, MipTexture) else MipTexture(t) for t in textures]


def cache_view_set(
    renderer: Renderer,
    distance: float,
    sizes: Sequence[tuple[int, int] | None],
    progress: Progress | None = None,
) -> ViewCache:
    """The protocol's view set at ``distance`` (the views of ``renderer.evaluation``), cached
    with the texture taps of candidates of ``sizes``: what validation and scoring read."""
    views = ViewSet(renderer, view_set_cameras(distance, renderer.evaluation), progress)
    return ViewCache(views, sizes, with_taps=True)


def training_views(
    renderer: Renderer,
    cameras: Sequence[Camera],
    sizes: Sequence[tuple[int, int] | None],
    with_taps: bool,
    soft: SoftSettings | None = None,
) -> ViewCache:
    """A training pool over ``cameras``, none cached yet.

    Without ``soft``: views of ``renderer`` (with the taps of ``sizes`` when ``with_taps``).
    With ``soft``: views of a :class:`~geoscaler.render.soft.SoftRenderer` of the same mesh, device
    and evaluation, whose references are soft renders of ``renderer``'s reference maps, so that
    candidate and original are rendered the same way, as the paper trains (with taps too:
    :meth:`~geoscaler.render.soft.SoftRenderer.pixel_taps`).
    """
    if soft is None:
        return ViewCache(ViewSet(renderer, cameras, eager=False), sizes, with_taps)
    training = SoftRenderer(
        renderer.mesh,
        renderer.device,
        renderer.evaluation,
        soft,
        reference=renderer.reference_textures,
    )
    return ViewCache(ViewSet(training, cameras, eager=False), sizes, with_taps)
