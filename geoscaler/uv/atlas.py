"""Re-allocating a texture atlas to the texels the views ask of each chart.

With its own UVs a scan's texture spends most of its texels on nothing (UV coverage of 8 to
50 %) and the rest evenly, whatever the views show of each chart. :func:`repack` finds the
charts of the mesh's UV layout (:func:`geoscaler.uv.uvmaps.chart_labels`), scales each by the
screen footprint the training cameras give it per unit of its UV area and by the detail its
texels lose at the output size (:func:`planned_scales`), and packs the scaled charts into one
``R x R`` atlas with ``xatlas``, as large as one atlas still holds them all, with padding
enough for the mip levels the far views read. A chart longer than half the atlas bounds how
dense any packing of whole charts can be: such charts are cut along face edges into pieces,
packed as charts of their own, where that measures denser (:data:`CUT_GAIN`).

Every chart is moved by a similarity only: a uniform scale and a translation, plus a rotation
by a multiple of 90 degrees (or a transpose, a mirror) where the material has no normal map.
So each vertex keeps one UV unless a cut runs through it (its corners on each side then get
their piece's UV: the layout gives UVs per face corner): faces and 3D positions are kept, and
tangent frames keep their directions where charts do not turn.

Materials showing one base-colour image are packed together; a material keeps its layout,
with the reason, where the new layout cannot be right for it (:func:`layout_groups`).
:func:`group_problems` holds each group's layout to the guards as it is packed (a group that
breaks one keeps its layout): no overlap of charts, no flipped face, each chart's scale as
planned, padding as planned.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np
import torch

from geoscaler.clock import Budget, unlimited
from geoscaler.io.slots import slot_info
from geoscaler.mesh import TexturedMesh
from geoscaler.protocol import FAR_DISTANCE
from geoscaler.render.cameras import sample_extent
from geoscaler.uv.detail import LostDetail
from geoscaler.uv.packing import (
    SCALE_TOLERANCE,
    Charts,
    PackingError,
    chart_texels,
    corner_areas,
    label_boxes,
    overlapping_texels,
    pack,
    padding_violations,
    scales_at,
    signed_areas,
)
from geoscaler.uv.uvmaps import (
    GRAZING_STRETCH,
    chart_labels,
    cut_charts,
    face_lod_bounds,
    face_max_levels,
    uv_corner_ids,
)

HIDDEN_SHARE = 0.25
"""Smallest planned scale of a chart, relative to the median chart's: charts no training view
shows (inside, underneath) or of flat colour keep a quarter of the median density rather than
none."""
DB_PER_HALVING = 5.0
"""The error's rise, in dB, where the texel density halves: bicubic's on the development set."""
ALLOCATION_EXPONENT = 1.0 / (2.0 + math.log2(10.0 ** (DB_PER_HALVING / 10.0)))
"""Exponent of the planned scales (:func:`planned_scales`), 0.27: where a chart's squared
error falls as ``density ^ -g`` (``g = log2 10^(DB_PER_HALVING / 10)``, 1.66) and its texels
cost ``area * density^2``, the density that minimises ``sum(samples * detail * density^-g)``
for the same texels is ``(samples * detail / area) ^ (1 / (2 + g))`` (docs/decisions/
chart-allocation.md)."""
PACKER_MARGIN = 1
"""Texels of padding asked of xatlas beyond the plan: its own padding is measured on its
conservative raster of the charts it stretched, and can leave charts one texel closer than
asked by the guard's measure, :func:`padding_violations`."""
MIN_PADDING, MAX_PADDING = 4, 16
"""Bounds of the texels kept empty between charts (:func:`padding_for`): at least 4, as far
views read coarse mip levels across charts and 2 texels let neighbours mix there; at most 16,
as padding is taken from the charts' density (``benchmarks/far_views.py``; see
docs/decisions/atlas-padding.md)."""
ALIGNMENT = int(2 * GRAZING_STRETCH)
"""Texels charts are aligned to where far views minify (:func:`alignment_for`): a frontal
lookup reads level 0 and 1, a grazing one (GRAZING_STRETCH) 3 levels coarser: 16-texel blocks
keep the mip blocks those views read the original's (``benchmarks/far_views.py``; see
docs/decisions/atlas-chart-alignment.md)."""
CUT_SIDE = 0.5
"""Longest side, as a share of the atlas's side, of a chart left whole: a longer one bounds
the density of any whole-chart packing (``benchmarks/layout_bounds.py`` measures that bound: on
scans one chart can span the whole square at 4x)."""
SEPARATION = 1e-3
"""UV units between the shifts of a cut chart's pieces as xatlas sees them
(:func:`group_charts`)."""
LEAST_GAIN = 0.5
"""The sparsest layout worth a packing, as its ``k`` would be at its relative scales (half the
own layout's texels a side where the views look: 5 dB below it by bicubic's loss per halving,
more than a race's start margin accepts): the packing's search starts there and gives up where
that does not fit (:func:`~geoscaler.uv.packing.pack`'s ``sparsest``)."""
CUT_GAIN = 1.1
"""Least gain in ``k`` for which a layout with cut charts is taken over the whole charts'
(5 log2 1.1 = 0.7 dB by bicubic's 5 dB per halving): cuts add seams and vertices."""


class AtlasError(PackingError):
    """A new layout that breaks a guard (overlap, flip, scale, padding) or does not fit."""


@dataclass(frozen=True)
class PlanTerms:
    """What a plan of one group's charts must meet (:func:`plan_charts`).

    Attributes:
        align: charts aligned to the original's mip blocks where the far views minify the
            texture (:func:`alignment_for`); False: never.
        least_gain: the least ``k`` worth a packing (the search looks no sparser).
        fall_back: where aligned charts do not fit, pack them unaligned (False: the group
            keeps its layout).
        checked: each packed group's guards checked (:func:`group_problems`) as it is laid
            out, a group that breaks one keeping its layout; False: the caller checks the
            layout it takes.
    """

    align: bool = True
    least_gain: float = LEAST_GAIN
    fall_back: bool = True
    checked: bool = True


@dataclass
class AtlasFacts:
    """What the report says of a new layout.

    Attributes:
        charts: charts moved.
        k: gain in linear texel density (new texels per old texel at the same texture size),
            averaged geometrically over the moved charts weighted by their screen footprint;
            ``k_area``: weighted by UV area instead.
        padding_texels: texels kept empty between charts; ``alignment_texels``: the block
            size chart offsets are multiples of (1: not aligned).
        mirrored_by_packer: charts the packer transposed; ``tiling_charts``: charts spanning
            more than one texture repeat; ``mirrored_charts_in_original``: charts mirrored in
            the original layout.
        kept: material name -> why its layout is kept.
        charts_cut, k_whole, cut, vertices_added, cut_skipped, k_cut: what cutting long charts
            did (:func:`repack`; None where the layout was planned without it): charts too
            long to leave whole, the whole charts' ``k``, whether the cut layout is the one
            taken, vertices it added, why it was not planned, its ``k``.
    """

    charts: int
    k: float
    k_area: float
    padding_texels: int
    alignment_texels: int
    mirrored_by_packer: int
    tiling_charts: int
    mirrored_charts_in_original: int
    kept: dict[str, str]
    charts_cut: int | None = None
    k_whole: float | None = None
    cut: bool | None = None
    vertices_added: int | None = None
    cut_skipped: str | None = None
    k_cut: float | None = None


@dataclass
class Atlas:
    """A mesh's new UV layout.

    Attributes:
        uvs: ``(F, 3, 2)`` float32 new UV of every face corner (a kept material's faces keep
            their own); :meth:`TexturedMesh.with_uvs` makes the mesh in this layout.
        chart_of_face: ``(F,)`` int64 chart of every face (a cut chart's pieces are charts of
            their own), -1 where the layout is kept.
        planned: ``(C,)`` float64 planned scale of each chart: new UV units per old one.
        linear: ``(C, 2, 2)`` float64 the map of each chart, ``new = linear @ old + offset``.
        offset: ``(C, 2)`` float64.
        mirrored: ``(C,)`` bool, the chart was transposed by the packer (colour only).
        paddings: per group, texels kept empty between charts.
        sizes: per material the texture ``(h, w)`` the layout was packed for (None: none).
        groups: the material indices packed together into each atlas.
        kept: material name -> why its layout is kept.
        footprint: ``(C,)`` float64 screen samples of each chart over the training cameras.
        facts: what the report says (charts, density gain ``k``, original layout's quirks).
        alignments: per group, texels each chart's offset is a multiple of (alignment_for).
    """

    uvs: np.ndarray
    chart_of_face: np.ndarray
    planned: np.ndarray
    linear: np.ndarray
    offset: np.ndarray
    mirrored: np.ndarray
    paddings: list[int]
    sizes: list[tuple[int, int] | None]
    groups: list[list[int]]
    kept: dict[str, str] = field(default_factory=dict)
    footprint: np.ndarray = field(default_factory=lambda: np.zeros(0))
    facts: AtlasFacts | None = None
    alignments: list[int] = field(default_factory=list)

    @property
    def scales(self) -> np.ndarray:
        """``(C,)`` packed scale of each chart: ``sqrt(|det linear|)``."""
        return np.sqrt(np.abs(np.linalg.det(self.linear))) if len(self.linear) else np.zeros(0)

    @property
    def padding(self) -> int:
        """The least padding of any group (texels)."""
        return min(self.paddings, default=MIN_PADDING)

    @property
    def aligned(self) -> bool:
        """Some group's charts are aligned to the original's mip blocks."""
        return any(align > 1 for align in self.alignments)

    @property
    def moved(self) -> bool:
        """Some material's layout changed."""
        return bool((self.chart_of_face >= 0).any())

    def repacked_materials(self) -> list[int]:
        """Material indices whose layout changed."""
        return sorted({m for group in self.groups for m in group})


# ------------------------------------------------------------------------------ which materials


def layout_groups(
    mesh: TexturedMesh, sizes: Sequence[tuple[int, int] | None], charts: np.ndarray
) -> tuple[list[list[int]], dict[int, str]]:
    """Materials packed together (one base-colour image each group) and those that keep their
    layout, with the reason.

    A material keeps its layout when it has no base-colour map or faces, its output or a map
    on its UVs is not square, a map on its UVs has a ``KHR_texture_transform``, a chart joins
    it to a material of another image, or a map of it is shared with a material of another
    image (one map cannot follow two layouts).

    Returns:
        ``(groups, kept)``: lists of material indices; material index -> reason.
    """
    kept: dict[int, str] = {}
    by_image: dict[int, list[int]] = {}
    for index, material in enumerate(mesh.materials):
        reason = _material_reason(mesh, index, sizes[index])
        if reason:
            kept[index] = reason
        else:
            by_image.setdefault(id(material.base_color_texture), []).append(index)
    group_of = {m: g for g, members in enumerate(by_image.values()) for m in members}
    face_group = np.array([group_of.get(int(m), -1) for m in mesh.face_material])
    for chart in np.unique(charts):
        touched = np.unique(face_group[charts == chart])
        if len(touched) > 1:
            for material in np.unique(mesh.face_material[charts == chart]):
                kept.setdefault(int(material), "a UV chart joins it to another material's image")
    map_groups: dict[int, set[int]] = {}
    for index, material in enumerate(mesh.materials):
        for pixels in material.maps.values():
            map_groups.setdefault(id(pixels), set()).add(group_of.get(index, -1 - index))
    for index, material in enumerate(mesh.materials):
        if any(len(map_groups[id(p)]) > 1 for p in material.maps.values()):
            kept.setdefault(index, "a map of it is shared with a material of another image")
    groups = [[m for m in members if m not in kept] for members in by_image.values()]
    return [g for g in groups if g], kept


def _material_reason(mesh: TexturedMesh, index: int, size: tuple[int, int] | None) -> str:
    material = mesh.materials[index]
    if material.base_color_texture is None or size is None:
        return "no base-colour texture"
    if not (mesh.face_material == index).any():
        return "no faces"
    if size[0] != size[1]:
        return f"its texture is not square ({size[1]}x{size[0]})"
    for slot, pixels in material.textures().items():
        info = slot_info(material.properties, slot)
        if info.get("texCoord", 0) != 0:
            continue  # another UV set: the map keeps its layout
        if "KHR_texture_transform" in info.get("extensions", {}):
            return f"{slot} has a KHR_texture_transform"
        if pixels.shape[0] != pixels.shape[1]:
            return f"{slot} is not square ({pixels.shape[1]}x{pixels.shape[0]})"
    return ""


def has_normal_map(mesh: TexturedMesh, materials: Sequence[int]) -> bool:
    """Some material of ``materials`` has a tangent-space normal map on its first UV set."""
    for index in materials:
        material = mesh.materials[index]
        for slot in material.maps:
            if slot.rpartition("/")[2].endswith("ormalTexture") or slot == "mtl:bump":
                if slot_info(material.properties, slot).get("texCoord", 0) == 0:
                    return True
    return False


# ------------------------------------------------------------------------------- what views ask


def chart_footprint(charts: np.ndarray, tri_ids: Sequence[torch.Tensor]) -> np.ndarray:
    """``(C,)`` float64 screen samples of each chart over some views: ``tri_ids`` holds per view
    the ``(N,)`` face each covered sample sees (:attr:`geoscaler.render.raster.GBuffer.tri_ids`,
    occlusion included); ``charts`` is ``(F,)`` (:func:`geoscaler.uv.uvmaps.chart_labels`)."""
    samples = np.zeros(len(charts))
    for ids in tri_ids:
        samples += np.bincount(ids.long().cpu().numpy(), minlength=len(charts))
    return np.bincount(charts, weights=samples, minlength=int(charts.max(initial=-1)) + 1)


uv_areas = signed_areas
"""``(F,)`` signed UV area of each face (:func:`geoscaler.uv.packing.signed_areas`)."""


def planned_scales(
    footprint: np.ndarray, chart_area: np.ndarray, detail: np.ndarray | None = None
) -> np.ndarray:
    """``(C,)`` relative linear scale of each chart: ``(footprint * detail / UV area) ^``
    :data:`ALLOCATION_EXPONENT`, the scales that minimise the error the views see, summed
    over their samples, for the same total texels (``detail``: ``(C,)`` what each chart's
    texels lose, :meth:`~geoscaler.uv.detail.LostDetail.per_chart`; None: the same for every
    chart); at least :data:`HIDDEN_SHARE` of the median (charts no view shows, charts of flat
    colour, degenerate charts). Normalised so the scaled charts have the original total UV
    area."""
    live = chart_area > 0
    weight = footprint if detail is None else footprint * detail
    scales = np.zeros(len(chart_area))
    scales[live] = (weight[live] / chart_area[live]) ** ALLOCATION_EXPONENT
    seen = scales[live & (weight > 0)]
    median = float(np.median(seen)) if len(seen) else 1.0
    scales = np.maximum(np.where(live, scales, median), HIDDEN_SHARE * median)
    total = float((scales**2 * chart_area).sum())
    return scales * math.sqrt(chart_area.sum() / total) if total > 0 else np.ones(len(scales))


def padding_for(mesh: TexturedMesh, faces: np.ndarray, size: tuple[int, int], samples: int) -> int:
    """Texels kept empty between charts: enough that a lookup at the level most faces read at
    the far distance (a surface facing the camera at the far view's farthest depth, 90 % of
    the faces) never mixes two charts: ``2^(level + 1)``, within
    [:data:`MIN_PADDING`, :data:`MAX_PADDING`]."""
    extent = sample_extent(FAR_DISTANCE + 1.0, samples) / GRAZING_STRETCH
    levels = face_max_levels(mesh, faces, size, extent)
    levels = levels[levels >= 0]
    level = int(np.percentile(levels, 90)) if len(levels) else 0
    return int(np.clip(2 ** (level + 1), MIN_PADDING, MAX_PADDING))


def alignment_for(mesh: TexturedMesh, faces: np.ndarray, size: int, samples: int) -> int:
    """Texels every chart's offset is a multiple of (1: none), its scale then a power of two
    times the original's texels per output texel (:func:`~geoscaler.uv.packing.scales_at`):
    :data:`ALIGNMENT` where the far views minify the new texture (a surface facing the camera
    at the far view's farthest depth reads level 0 or coarser on 90 % of the faces), so that
    its mip blocks are the original's, which the far views' references read."""
    extent = sample_extent(FAR_DISTANCE + 1.0, samples)
    bounds = face_lod_bounds(mesh, faces, (size, size), extent)
    bounds = bounds[np.isfinite(bounds)]
    minified = len(bounds) > 0 and np.percentile(bounds, 90) >= 0
    return ALIGNMENT if minified else 1


# ------------------------------------------------------------------------------------- packing


def group_charts(
    mesh: TexturedMesh, materials: Sequence[int], charts: np.ndarray
) -> tuple[np.ndarray, Charts, np.ndarray, np.ndarray]:
    """The faces of ``materials`` as :class:`~geoscaler.uv.packing.Charts`: ``((G,) face indices,
    charts, (C',) global chart id of each local chart, (C', 2) shift)``; a corner is a
    :func:`~geoscaler.uv.uvmaps.uv_corner_ids` on one chart (a cut chart's pieces are charts).

    xatlas packs charts whose corners have equal UVs as one: the pieces of a cut chart, which
    meet along the cut, are each moved by a shift of their own (:data:`SEPARATION` times their
    local index along u), which the charts' UVs include."""
    faces = np.flatnonzero(np.isin(mesh.face_material, materials))
    ids = uv_corner_ids(mesh)[mesh.faces[faces]]  # (G, 3)
    count = int(charts.max(initial=0)) + 1
    keys, corner_faces = np.unique(ids * count + charts[faces, None], return_inverse=True)
    corner_faces = corner_faces.reshape(-1, 3)
    used_ids = keys // count  # the UV-space corner of each corner
    corner_uvs = np.zeros((len(keys), 2))
    corner_uvs[corner_faces.reshape(-1)] = mesh.uvs[mesh.faces[faces]].reshape(-1, 2)
    global_charts, local = np.unique(charts[faces], return_inverse=True)
    corner_chart = np.zeros(len(keys), np.int64)
    corner_chart[corner_faces] = local.reshape(-1, 1)
    on_cut = np.bincount(used_ids)[used_ids] > 1  # a corner some other chart shares
    shift = np.zeros((len(global_charts), 2))
    cut = np.unique(corner_chart[on_cut])
    shift[cut, 0] = (cut + 1) * SEPARATION
    corner_uvs += shift[corner_chart]
    group = Charts(corner_faces, corner_uvs, corner_chart, len(global_charts))
    return faces, group, global_charts, shift


def repack(
    mesh: TexturedMesh,
    sizes: Sequence[tuple[int, int] | None],
    tri_ids: Sequence[torch.Tensor],
    samples_per_side: int,
    detail: Sequence[float | None] | None = None,
    budget: Budget | None = None,
    align: bool = True,
    lost: LostDetail | None = None,
) -> Atlas:
    """The new layout of ``mesh`` for textures of ``sizes`` (per material), charts scaled by
    what some views (the training views, never the validation's) show of them and by the
    detail their texels lose at those sizes (:func:`planned_scales`).

    The charts are packed whole first (:func:`plan_charts`); where one would span more than
    :data:`CUT_SIDE` of its atlas at that packing's relative scales and the density that
    fills every texel (:func:`cut_lengths`), those charts are cut
    (:func:`geoscaler.uv.uvmaps.cut_charts`) into pieces at most that long and packed again,
    and the cut layout is taken where its ``k`` is at least :data:`CUT_GAIN` times the whole
    charts' (its packing searches no sparser: a cut whose groups do not all pack that densely
    is refused, and said so in ``cut_skipped``).
    The cut is not planned where, at the whole plan's cost, it would not fit ``budget``.

    Args:
        mesh: the mesh.
        sizes: per material the output texture ``(h, w)`` (None: untextured).
        tri_ids: per view the face of each covered sample (:func:`chart_footprint`).
        samples_per_side: the renderer's samples per side (for the padding).
        detail: per material the original's texels per texel of its output (its size over
            the output's; None: unknown): no chart gets more texels than the original has,
            and where the far views minify the new texture each chart covers a power-of-two
            block of the original's texels (:func:`alignment_for`). None: neither.
        budget: the time the plan must be made in (None: no limit): the packing's search
            stops at its end (:func:`~geoscaler.uv.packing.pack`).
        align: False: charts are never aligned (the other layout a race weighs).
        lost: per face the detail its texels lose (:func:`~geoscaler.uv.detail.lost_detail`);
            None: the same everywhere (charts scaled by the views alone).

    Returns:
        The :class:`Atlas`, each packed group's guards checked (:func:`group_problems`): both
        plans are laid out unchecked and only the one taken is checked; where a group of the
        whole charts' plan breaks a guard, that plan is made again checking each group as it
        is laid out, and such a group keeps its layout.
    """
    charts = chart_labels(mesh)
    budget = budget or unlimited()
    started = budget.now()
    plan = partial(plan_charts, mesh, sizes, tri_ids=tri_ids, samples_per_side=samples_per_side,
                   detail=detail, budget=budget, lost=lost)  # fmt: skip
    whole = plan(charts, terms=PlanTerms(align, checked=False))
    longest = cut_lengths(mesh, whole, charts)
    charts_cut = int(np.isfinite(longest).sum())
    atlas, cut_skipped, k_cut = whole, None, None
    seconds = budget.now() - started  # what the cut's plan costs too, about
    if charts_cut and not budget.fits(seconds):
        cut_skipped = "the time budget left no time to plan the cut"
    elif charts_cut:
        pieces = cut_charts(mesh, charts, longest)
        least = max(LEAST_GAIN, CUT_GAIN * whole.facts.k)  # no sparser cut would be taken
        cut = plan(pieces, terms=PlanTerms(whole.aligned, least, fall_back=False, checked=False))
        cut_skipped = _cut_refusal(mesh, whole, cut)
        k_cut = None if cut_skipped else cut.facts.k
        if k_cut is not None and k_cut >= CUT_GAIN * whole.facts.k:
            atlas = cut
    if atlas is whole and atlas_problems(mesh, whole):  # planned again, checked group by
        atlas = whole = plan(charts, terms=PlanTerms(align))  # group: those that break a
        # guard keep their layout, with the reason
    added = len(mesh.with_uvs(atlas.uvs).uvs) - len(mesh.uvs)
    atlas.facts = replace(atlas.facts, charts_cut=charts_cut, k_whole=whole.facts.k,
                          cut=atlas is not whole, vertices_added=added,
                          cut_skipped=cut_skipped, k_cut=k_cut)  # fmt: skip
    return atlas


def _cut_refusal(mesh: TexturedMesh, whole: Atlas, cut: Atlas) -> str | None:
    """Why the ``cut`` layout cannot be taken over ``whole`` (None: it can, where dense
    enough): a group it could not pack (its ``k`` would not compare), or, where it is dense
    enough to be taken, a guard it breaks (:func:`atlas_problems`)."""
    refused = sorted({cut.kept[name] for name in cut.kept.keys() - whole.kept.keys()})
    if not refused and cut.facts.k >= CUT_GAIN * whole.facts.k:
        refused = atlas_problems(mesh, cut)
    return "the pieces' layout was refused: " + "; ".join(refused) if refused else None


def cut_lengths(mesh: TexturedMesh, atlas: Atlas, charts: np.ndarray) -> np.ndarray:
    """``(C,)`` float64 longest piece of each chart (old UV units) for
    :func:`~geoscaler.uv.uvmaps.cut_charts`: :data:`CUT_SIDE` of the atlas at the density
    where the moved charts of its group, at their packed relative scales, would fill every
    texel, where its side is longer than that there; ``inf`` elsewhere (charts not moved
    too).

    The all-texels density, not the packed one, so that the pieces do not follow the packer's
    heuristic (a whole-chart packing 0.5 % sparser halved other pieces, and moved the cut
    layout's ``k`` by 15 %), and are short enough at the density the cut then reaches."""
    count = len(atlas.planned)
    _, extent = chart_boxes(mesh, charts, count)
    area = np.bincount(charts, np.abs(uv_areas(mesh.uvs, mesh.faces)), minlength=count)
    longest = np.full(count, np.inf)
    for materials in atlas.groups:
        faces = np.isin(mesh.face_material, materials) & (atlas.chart_of_face >= 0)
        moved = np.unique(atlas.chart_of_face[faces])
        filled = float((atlas.planned[moved] ** 2 * area[moved]).sum())
        dense = atlas.planned[moved] / math.sqrt(max(filled, 1e-30))
        spans = dense * extent[moved].max(axis=1) > CUT_SIDE
        longest[moved[spans]] = CUT_SIDE / dense[spans]
    return longest


def plan_charts(
    mesh: TexturedMesh,
    sizes: Sequence[tuple[int, int] | None],
    charts: np.ndarray,
    tri_ids: Sequence[torch.Tensor],
    samples_per_side: int,
    detail: Sequence[float | None] | None,
    budget: Budget | None = None,
    terms: PlanTerms = PlanTerms(),
    lost: LostDetail | None = None,
) -> Atlas:
    """The layout of ``charts`` (``(F,)`` labels, each chart moved whole) as :func:`repack`
    plans it on ``terms``, within ``budget`` (:func:`~geoscaler.uv.packing.pack`), each
    chart's scale weighed by the detail it loses (``lost``; None: not weighed); a group that
    does not fit them keeps its layout, with the reason."""
    groups, kept = layout_groups(mesh, sizes, charts)
    count = int(charts.max()) + 1 if len(charts) else 0
    chart_area = np.bincount(charts, np.abs(uv_areas(mesh.uvs, mesh.faces)), minlength=count)
    atlas = Atlas(
        mesh.corner_uvs().copy(),
        np.full(len(mesh.faces), -1, np.int64),
        np.zeros(count),
        np.tile(np.eye(2), (count, 1, 1)),
        np.zeros((count, 2)),
        np.zeros(count, bool),
        [],
        list(sizes),
        [],
        {},
        chart_footprint(charts, tri_ids),
    )
    chart_detail = None if lost is None else lost.per_chart(charts, count)
    for materials in groups:
        try:
            _lay_out(
                mesh,
                atlas,
                materials,
                charts,
                chart_area,
                samples_per_side,
                detail,
                budget,
                terms,
                chart_detail,
            )
        except PackingError as error:  # AtlasError included: that group keeps its layout
            kept.update({m: str(error) for m in materials})
    atlas.kept = {mesh.materials[i].name: reason for i, reason in sorted(kept.items())}
    atlas.facts = layout_facts(mesh, atlas, charts, chart_area)
    return atlas


def _lay_out(
    mesh: TexturedMesh,
    atlas: Atlas,
    materials: list[int],
    charts: np.ndarray,
    chart_area: np.ndarray,
    samples_per_side: int,
    detail: Sequence[float | None] | None,
    budget: Budget | None,
    terms: PlanTerms = PlanTerms(),
    chart_detail: np.ndarray | None = None,
) -> None:
    """Pack the charts of ``materials`` into ``atlas`` (in place) within ``budget`` on
    ``terms`` (:class:`PlanTerms`), each chart's scale weighed by ``(C,)`` ``chart_detail``
    (:func:`planned_scales`; None: not weighed); or leave ``atlas`` as it was and raise
    :class:`~geoscaler.uv.packing.PackingError` when they do not fit, break a guard (where
    checked) or found no packing in time."""
    faces, group, ids, shift = group_charts(mesh, materials, charts)
    size = atlas.sizes[materials[0]][0]
    padding = padding_for(mesh, mesh.faces[faces], (size, size), samples_per_side)
    rotate = not has_normal_map(mesh, materials)
    lost = None if chart_detail is None else chart_detail[ids]
    scales = planned_scales(atlas.footprint[ids], chart_area[ids], lost)
    cap = None if detail is None else detail[materials[0]]
    aligned = terms.align and cap is not None
    blocks = alignment_for(mesh, mesh.faces[faces], size, samples_per_side) if aligned else 1
    grid, packed, spacing = cap if blocks > 1 else None, None, padding + PACKER_MARGIN
    weights = atlas.footprint[ids]
    if grid is not None:
        least = density_for_gain(terms.least_gain, scales, weights, size, cap, aligned=True)
        try:  # the spacing leaves room for rounding the offsets
            packed = pack(group, scales, size, spacing + blocks, rotate, budget, cap, True,
                          sparsest=least)  # fmt: skip
        except PackingError:
            if not terms.fall_back:
                raise
            blocks, grid = 1, None  # aligned, the charts do not fit: unaligned
    if packed is None:
        least = density_for_gain(terms.least_gain, scales, weights, size, cap)
        packed = pack(group, scales, size, spacing, rotate, budget, cap, sparsest=least)
    before = copy.deepcopy(atlas) if terms.checked else atlas
    offset = packed.offset + np.einsum("cij,cj->ci", packed.linear, shift)
    if grid is not None:
        offset = np.round(offset * size / blocks) * blocks / size
    atlas.planned[ids] = np.sqrt(np.abs(np.linalg.det(packed.linear)))
    atlas.linear[ids] = packed.linear
    atlas.offset[ids] = offset
    atlas.mirrored[ids] = np.linalg.det(packed.linear) < 0
    atlas.chart_of_face[faces] = charts[faces]
    atlas.uvs[faces] = mapped_corners(mesh, atlas, faces)
    atlas.groups.append(materials)
    atlas.paddings.append(padding)
    atlas.alignments.append(blocks)
    problems = group_problems(mesh, atlas, len(atlas.groups) - 1) if terms.checked else []
    if problems:
        atlas.__dict__.update(before.__dict__)
        raise AtlasError("the new UV layout broke a guard: " + "; ".join(problems))


def chart_boxes(
    mesh: TexturedMesh, charts: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """``((C, 2) low corner, (C, 2) extent)`` float64 of each chart's UV bounding box in UV
    units; ``charts`` is ``(F,)`` (:func:`~geoscaler.uv.uvmaps.chart_labels`), ``count`` >= C."""
    corners = mesh.corner_uvs().astype(np.float64).reshape(-1, 2)
    return label_boxes(corners, np.repeat(charts, 3), count)


def weighted_gain(scales: np.ndarray, weights: np.ndarray) -> float:
    """Geometric mean of ``(C,)`` density gains ``scales`` weighted by ``(C,)`` ``weights``
    (1.0 where the weights sum to nothing)."""
    total = weights.sum()
    return float(np.exp((weights * np.log(scales)).sum() / total)) if total > 0 else 1.0


def density_for_gain(
    gain: float,
    scales: np.ndarray,
    weights: np.ndarray,
    size: int,
    cap: float | None,
    aligned: bool = False,
) -> float:
    """The least density (atlas texels per scaled UV unit) at which charts of ``(C,)``
    ``scales``, as packed there (:func:`~geoscaler.uv.packing.scales_at` with ``cap`` and
    ``aligned``), reach ``gain`` in ``k`` (:func:`weighted_gain` by ``(C,)`` ``weights``);
    ``inf`` where the caps keep them below it at any density. ``k`` rises with the density,
    in steps where aligned."""

    def gain_at(tpu: float) -> float:
        return weighted_gain(scales_at(scales, tpu, size, cap, aligned) * tpu / size, weights)

    low = gain * size / weighted_gain(scales, weights)  # without caps: caps only lower k
    if cap is None:
        return low
    high = max(low, float((cap * size / np.maximum(scales, 1e-30)).max()))  # every chart capped
    if gain_at(high) < gain:
        return math.inf
    while high > low * (1 + 1e-9):  # bisection: gain_at(low) < gain <= gain_at(high)
        middle = math.sqrt(low * high)
        low, high = (low, middle) if gain_at(middle) >= gain else (middle, high)
    return high


def layout_facts(
    mesh: TexturedMesh, atlas: Atlas, charts: np.ndarray, chart_area: np.ndarray
) -> AtlasFacts:
    """What the report says of a layout: charts moved, density gains, the original's quirks
    (:class:`AtlasFacts`)."""
    moved = np.unique(atlas.chart_of_face[atlas.chart_of_face >= 0])
    scales = atlas.scales[moved]
    _, extent = chart_boxes(mesh, charts, len(chart_area))
    signed = np.bincount(charts, uv_areas(mesh.uvs, mesh.faces), minlength=len(chart_area))
    return AtlasFacts(
        charts=int(len(moved)),
        k=round(weighted_gain(scales, atlas.footprint[moved]), 4),
        k_area=round(weighted_gain(scales, chart_area[moved]), 4),
        padding_texels=atlas.padding,
        alignment_texels=max(atlas.alignments, default=1),
        mirrored_by_packer=int(atlas.mirrored[moved].sum()),
        tiling_charts=int((extent[moved] > 1.0).any(axis=1).sum()),
        mirrored_charts_in_original=int((signed[moved] < 0).sum()),
        kept=dict(atlas.kept),
    )


# -------------------------------------------------------------------------------------- guards


def atlas_problems(mesh: TexturedMesh, atlas: Atlas) -> list[str]:
    """Every guard the layout breaks, one line each (empty: none): :func:`group_problems` of
    every group."""
    return [line for g in range(len(atlas.groups)) for line in group_problems(mesh, atlas, g)]


def group_problems(mesh: TexturedMesh, atlas: Atlas, group: int) -> list[str]:
    """The guards one group's layout breaks: charts not at their planned scale, faces not
    moved by their chart's map or flipped, a normal-mapped chart mirrored, charts (pieces,
    :func:`map_pieces`) overlapping or closer than the group's padding."""
    materials = atlas.groups[group]
    faces = np.flatnonzero(np.isin(mesh.face_material, materials) & (atlas.chart_of_face >= 0))
    chart = atlas.chart_of_face[faces]
    charts = np.unique(chart)
    problems = []
    wrong = np.abs(atlas.scales[charts] / np.maximum(atlas.planned[charts], 1e-30) - 1)
    if (wrong > SCALE_TOLERANCE).any():
        problems.append(f"{int((wrong > SCALE_TOLERANCE).sum())} charts not at their planned scale")
    old_corners, new_corners = mesh.corner_uvs()[faces].astype(float), atlas.uvs[faces]
    if np.abs(mapped_corners(mesh, atlas, faces) - new_corners).max(initial=0) > 1e-5:
        problems.append("faces not moved by their chart's map")
    old, new = corner_areas(old_corners), corner_areas(new_corners)
    expected = np.linalg.det(atlas.linear[chart]) * old
    flipped = (np.sign(new) != np.sign(expected)) & (np.abs(expected) > 1e-14)
    if flipped.any():
        problems.append(f"{int(flipped.sum())} faces flipped in the new layout")
    if atlas.mirrored[charts].any() and has_normal_map(mesh, materials):
        problems.append("a chart of a material with a normal map was mirrored")
    size = atlas.sizes[materials[0]][0]
    pieces = map_pieces(atlas)[chart]
    texels, labels = chart_texels(new_corners, pieces, size)
    shared = overlapping_texels(texels, labels)
    if len(shared):
        problems.append(f"{len(shared)} texels covered by two charts")
    close = padding_violations(texels, labels, size, atlas.paddings[group])
    if close:
        problems.append(f"{close} texels closer to another chart than the padding")
    align = atlas.alignments[group] if group < len(atlas.alignments) else 1
    steps = atlas.offset[charts] * size / align
    if align > 1 and np.abs(steps - np.round(steps)).max(initial=0) > 1e-6:
        problems.append(f"charts off the {align}-texel grid")
    return problems


def mapped_corners(mesh: TexturedMesh, atlas: Atlas, faces: np.ndarray) -> np.ndarray:
    """``(G, 3, 2)`` float64: the old corner UVs of ``faces`` moved by their chart's map."""
    chart, old = atlas.chart_of_face[faces], mesh.corner_uvs()[faces].astype(np.float64)
    return np.einsum("fij,fkj->fki", atlas.linear[chart], old) + atlas.offset[chart][:, None]


def map_pieces(atlas: Atlas) -> np.ndarray:
    """``(C,)`` int64: charts moved by the same map (the same linear part, offsets within a
    millionth) share a piece. Charts that shared texels in the original (duplicates: xatlas
    packs charts with the same UVs as one) share them in the new layout too, as they did: the
    guards compare pieces, not charts."""
    keys = np.c_[np.round(atlas.linear.reshape(-1, 4), 9), np.round(atlas.offset, 6)]
    return np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1)
