"""``direct`` in a new UV layout (``--uv repack`` and ``--uv auto``, issue 17).

The charts are repacked by the texels the training views ask of them
(:func:`geoscaler.atlas.repack`, planned on the G-buffers of the first training views), the
reference maps are baked into the new layout (:func:`geoscaler.bake.bake`), and the texels are
optimised through the renderer as ``direct`` does. References are always the original maps on
the original UVs: the new layout has the same vertices, faces and 3D positions, so every
G-buffer (and foreground mask) is the original's, and the job's validation views are shared
(:class:`LayoutValidation`). The result carries the new UVs and the :class:`Atlas`, which the
export needs to bake every other map of the repacked materials.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import torch

from geoscaler.atlas import Atlas, repack
from geoscaler.bake import ChartMaps, bake
from geoscaler.cameras import sample_training_cameras
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh
from geoscaler.methods.learned import fit, loop_config
from geoscaler.methods.registry import MethodOptions, MethodResult, RunContext, output_sizes_for
from geoscaler.metrics import psnr_fg
from geoscaler.render import Renderer
from geoscaler.sizes import COLOR, SizeRule
from geoscaler.texture import texture_to_linear
from geoscaler.uvmodes import check_uv_mode
from geoscaler.validation import Validation, validation_view_sets
from geoscaler.views import ViewCache, ViewSet, mip_chains

FOOTPRINT_VIEWS = 8
"""Training views whose G-buffers plan the chart scales (cached once, reused by the loop)."""
MAX_OVERSAMPLE = 4
"""Most samples per side of a new texel when baking (the original's density at 4x)."""


class LayoutValidation(Validation):
    """The job's validation (its views, frozen counts and baselines) with candidates rendered
    in a new UV layout: the same G-buffers and references, the taps of ``renderer``'s UVs.

    Baselines (filters on the mesh's own UVs) are scored by the job's validation, on the same
    frozen views; freezing either freezes both at the same counts."""

    def __init__(self, base: Validation, renderer: Renderer):
        views = {name: cache.views for name, cache in base.sets.items()}
        super().__init__(views, base.sizes, {}, base.scorings_after)
        self.sets = {n: ViewCache(v, base.sizes, True, renderer) for n, v in views.items()}
        self.base = base
        if base.frozen:
            self.counts = dict(base.counts)

    def cache_next(self) -> bool:
        if self.base.frozen:
            self.freeze()
            return False
        return super().cache_next()

    def freeze(self) -> None:
        if self.base.frozen:
            self.counts = dict(self.base.counts)
            return
        super().freeze()
        self.base.freeze()

    def baseline_scores(self) -> dict[str, dict[str, float]]:
        self.freeze()
        return self.base.baseline_scores()


def plan_layout(
    mesh: TexturedMesh, rule: SizeRule, renderer: Renderer, config: Any, memo: dict
) -> tuple[Atlas, ViewSet]:
    """The new layout for ``rule``'s sizes, planned on the first :data:`FOOTPRINT_VIEWS`
    training cameras (cached into ``memo`` for the loop), and those views."""
    cameras = sample_training_cameras(config.pool_views, config.seed, config.distances)
    views = ViewSet(renderer.relaid(mesh.uvs, memo), cameras[:FOOTPRINT_VIEWS])
    sizes = output_sizes_for(mesh, rule, renderer)
    references = renderer.reference_maps()
    caps = [
        None if s is None or r is None else r.shape[0] / s[0]
        for s, r in zip(sizes, references, strict=True)
    ]
    cap = max((c for c in caps if c is not None), default=None)
    tri_ids = [gbuffer.tri_ids for gbuffer in views.gbuffers]
    return repack(mesh, sizes, tri_ids, renderer.resolution, cap), views


def baked_maps(
    mesh: TexturedMesh, atlas: Atlas, references: list[np.ndarray | None], sizes: list
) -> list[np.ndarray | None]:
    """Per material its reference map baked into the new layout (materials of one group share
    one array), or None for a material that keeps its layout or has no map."""
    out: list[np.ndarray | None] = [None] * len(mesh.materials)
    for group, padding in zip(atlas.groups, atlas.paddings, strict=True):
        faces = np.isin(mesh.face_material, group) & (atlas.chart_of_face >= 0)
        layout = ChartMaps(
            atlas.uvs, mesh.faces[faces], atlas.chart_of_face[faces], atlas.linear, atlas.offset
        )
        size = sizes[group[0]][0]
        reference = references[group[0]]
        oversample = int(np.clip(reference.shape[0] // size, 1, MAX_OVERSAMPLE))
        pixels, _ = bake(reference, COLOR, layout, size, 2 * padding, oversample)
        for material in group:
            out[material] = pixels
    return out


def repacked_direct(
    mesh: TexturedMesh,
    rule: SizeRule,
    options: MethodOptions,
    context: RunContext,
    started: float,
    start_model: Any,
    defaults: dict,
) -> MethodResult:
    """``direct`` in a new layout (``--uv repack``), or ``--uv auto``'s choice of layouts:
    the new one where its start (the bake) renders better than the own layout's (Lanczos) on
    the planning training views, on all of them and on their farther half (far views read
    coarse mip levels across charts; the job's floor guards them too).

    Args:
        start_model: ``(mesh, rule, renderer, starts) -> TexelModel`` making free texels from
            per-material linear starts (None: ``direct``'s Lanczos start).
        defaults: ``direct``'s loop settings.
    """
    renderer = context.renderer or Renderer(mesh, options.device)
    config = loop_config(defaults, options, context)
    if config.training_renderer != "exact":
        raise GeoscalerError("--uv repack and auto train through the exact renderer only")
    mode = check_uv_mode(options.settings.get("uv", "keep"))
    memo: dict = {}
    atlas, footprint_views = plan_layout(mesh, rule, renderer, config, memo)
    sizes = output_sizes_for(mesh, rule, renderer)
    references = renderer.reference_maps()
    baked = baked_maps(mesh, atlas, references, sizes) if atlas.moved else []
    relaid = renderer.relaid(atlas.uvs, memo)
    keep_start = start_model(mesh, rule, renderer, None)
    layout_start = None
    if atlas.moved:
        linear = {id(b): texture_to_linear(b, renderer.device) for b in baked if b is not None}
        starts = [None if b is None else linear[id(b)] for b in baked]  # groups share one
        layout_start = start_model(mesh, rule, renderer, starts)
    choice = "repack" if atlas.moved else "keep"
    facts: dict[str, Any] = {"uv": mode, "layout": atlas.facts, "auto_choice": "keep"}
    if atlas.moved:  # what auto decides on (repack records it too, for comparison)
        keep = _training_psnr(footprint_views, renderer, keep_start, sizes)
        layout = _training_psnr(footprint_views, relaid, layout_start, sizes)
        distances = np.array([camera.distance for camera in footprint_views.cameras])
        far = distances >= np.median(distances)
        scores = {"keep": float(keep.mean()), "repack": float(layout.mean())}
        far_scores = {"keep": float(keep[far].mean()), "repack": float(layout[far].mean())}
        facts["start_psnr_training_views"] = {k: round(v, 4) for k, v in scores.items()}
        facts["start_psnr_farther_half"] = {k: round(v, 4) for k, v in far_scores.items()}
        better = all(s["repack"] > s["keep"] for s in (scores, far_scores))
        facts["auto_choice"] = "repack" if better else "keep"
        if mode == "auto":
            choice = facts["auto_choice"]
    facts["layout_used"] = choice
    validation = context.validation
    if validation is None:
        validation = Validation(validation_view_sets(renderer), sizes)
    if choice == "keep":  # the planning views' G-buffers serve the training pool too
        context = replace(context, validation=validation)
        own = renderer.relaid(mesh.uvs, memo)
        return fit(mesh, rule, own, keep_start, config, context, started, details=facts)
    context = replace(
        context,
        validation=LayoutValidation(validation, relaid),
        on_event=_with_layout_uvs(context.on_event, relaid.uvs),
    )
    result = fit(mesh, rule, relaid, layout_start, config, context, started, details=facts)
    result.uvs = atlas.uvs.copy()
    result.layout = atlas
    result.textures = _with_alpha(result.textures, baked)
    return result


def _with_layout_uvs(on_event: Any, uvs: torch.Tensor) -> Any:
    """``on_event`` whose events' live candidates carry the new layout's UVs (the loop's model
    renders on its renderer's own UVs and says None), so an observer such as the app shows
    them as they are."""
    if on_event is None:
        return None

    def forward(event: Any) -> None:
        if event.candidate is not None:
            inner = event.candidate
            event = replace(event, candidate=lambda: (inner()[0], uvs.detach().clone()))
        on_event(event)

    return forward


def _training_psnr(views: ViewSet, renderer: Renderer, model: Any, sizes: list) -> np.ndarray:
    """``(N,)`` PSNR-fg of a model's start in each of some training views (never the
    validation's)."""
    cache = ViewCache(views, sizes, True, renderer)
    textures, _ = model.candidate()
    with torch.no_grad():
        textures = mip_chains(textures)
        values = [
            psnr_fg(cache.render(i, textures, None)[None], *[t[None] for t in views.reference(i)])
            for i in range(len(views))
        ]
    return torch.cat(values).cpu().numpy().astype(np.float64)


def _with_alpha(
    textures: list[np.ndarray | None], baked: list[np.ndarray | None]
) -> list[np.ndarray | None]:
    """Each optimised RGB texture with the baked map's alpha (in the new layout) appended
    where the baked map has one: the job re-attaches the original's alpha only to textures
    without one, and that alpha is in the old layout."""
    out = []
    for texture, source in zip(textures, baked, strict=True):
        if texture is not None and source is not None and source.shape[2] in (2, 4):
            texture = np.concatenate([texture[..., :3], source[..., -1:]], axis=2)
        out.append(texture)
    return out
