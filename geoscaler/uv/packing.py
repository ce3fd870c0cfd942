"""Packing UV charts into one square atlas with ``xatlas``, each chart moved by a similarity.

:func:`pack` finds the densest packing of charts, each scaled by its own planned factor, into
one ``size x size`` atlas: a bisection on the texel density, ``xatlas`` packing at each step.
What comes back is, per chart, an exact similarity (uniform scale at the plan, translation, and
where allowed a turn by a multiple of 90 degrees or a transpose), derived from where ``xatlas``
put the chart. Facts about ``xatlas`` 0.0.11 this module works around (each checked on every
packing, never assumed):

- it stretches each chart along its axes to a whole number of texels (up to two more): the
  chart is shrunk back to its planned scale inside the box it was given;
- it silently shrinks charts larger than the atlas: such a packing is refused;
- it splits a chart folded over itself (faces wound both ways) and may split others, then
  moves the parts apart; it mishandles charts under a texel or two: such charts are packed as
  their bounding box (at least :data:`MIN_BOX_TEXELS` wide), the chart inside it;
- it ignores faces whose area is at most float32's epsilon (1.2e-7 in its units, absolute):
  a scan's finest faces, whose corners it then leaves out or whose chart it splits; charts are
  handed to it in units :data:`XATLAS_UNIT` times larger, where only degenerate faces are that
  small;
- ``rotate_charts`` may transpose a chart (a mirror): callers turn it off where that matters;
  ``rotate_charts_to_axis`` (a free rotation) is always off;
- its task scheduler can lose the wake-up it sends a worker thread that is going back to sleep
  (it notifies without the worker's mutex), and destroying the atlas then joins that thread
  forever: a hang right after a packing, seen once in four test runs here. A used atlas is
  destroyed only after the packings that follow it (:func:`_retire`), when its workers are
  long asleep, where a wake-up reaches them.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import xatlas

from geoscaler.clock import WALL_CLOCK, Budget, Clock
from geoscaler.errors import GeoscalerError

MIN_BOX_TEXELS = 2.0
"""Smallest side, in atlas texels, of the box a tiny chart is packed as."""
SEARCH_STEPS = 12
"""Most bisection steps of the density search."""
SEARCH_RATIO = 1.01
"""The density search stops once its bracket is this narrow (highest density tried that
failed over the highest that fitted): 1 % more texels a side is 0.09 dB of bicubic's loss at
5 dB per halving of the density, below what the race can tell apart; an xatlas packing of a
4096 scan's charts costs 0.1 to 0.25 s (ycb_chain at 4x, unaligned and aligned)."""
XATLAS_UNIT = 1024.0
"""xatlas units per scaled UV unit (see the module's note on faces it ignores): large enough
that only degenerate faces fall under its epsilon, since charts with ignored faces are packed
as boxes, less densely (see docs/decisions/packing-xatlas-settings.md)."""
XATLAS_PADDING_SHARE = 0.5
"""Share of the texels to keep empty between charts asked of xatlas as its padding: it dilates
every chart by its padding before placing it, so two charts end about twice it apart (asked 5,
it left 8 to 11 empty texels between the development scans' charts; asked 3, 6 to 8). Its
``bilinear`` option, one texel more around each chart, is off: the padding already keeps the
texels a lookup reads apart (see docs/decisions/atlas-padding.md)."""
PROBES = (1.16, 1.08, 1.04, 1.02)
"""Density steps tried above the bisection's answer: xatlas places charts by a randomised
heuristic, so whether they fit is not monotone in the density (see
docs/decisions/packing-xatlas-settings.md)."""
COARSE_MIN_SIZE = 1024
"""Atlases at least this large are searched at a smaller size first (:func:`pack`); below
it an xatlas packing costs under 0.1 s."""
COARSE_FACTOR = 2
"""The coarse search's atlas is this many times smaller a side: xatlas packs charts as
bitmaps of the atlas's texels, and a packing of a 4096 scan's charts into 512 texels costs a
third of one into 1024 (0.06 against 0.19 s, ycb_chain); a coarse texel covers four, so what
fits coarse mostly fits at full size (see docs/decisions/packing-xatlas-settings.md)."""
COARSE_RATIO = 1.04
"""The coarse search stops once its bracket is this narrow, and tries no :data:`PROBES`: it
only aims the full size's search, which climbs from its answer (:data:`CLIMB`)."""
REFINE_STEPS = (1.03, 1.0, 1 / 1.02, 1 / 1.05, 1 / 1.1)
"""Densities, relative to the coarse search's answer, tried at full size until one fits; where
the first fits, the search climbs above it (:data:`CLIMB`)."""
CLIMB = 1.03
"""Density step of the climb above the coarse answer at full size (coarse bitmaps waste texels
at the charts' edges: the full size fits more, 6 % on ycb_peach): 3 % more texels a side is
0.2 dB of bicubic's loss at 5 dB per halving, for two or three full-size packings instead of
five."""
COARSE_SPAN = 1.1
"""The climb goes no higher than this factor above the coarse answer."""
EDGE_HAIR = 1e-7
"""Samples this close to a face's edge (in samples) count as inside it (:func:`sample_spans`)."""
SCALE_TOLERANCE = 1e-3
"""Relative error allowed between a chart's planned and packed scale."""
RETIRED_ATLASES = 8
"""Used atlases kept alive (see the module's note on xatlas's workers), the oldest destroyed
first; also any idle for :data:`RETIRED_SECONDS`."""
RETIRED_SECONDS = 1.0
_retired: deque[tuple[float, xatlas.Atlas]] = deque()


class PackingError(GeoscalerError):
    """Charts that do not fit one atlas at their planned scales."""


@dataclass
class Charts:
    """Charts as UV corners and faces.

    Attributes:
        corner_faces: ``(G, 3)`` int64 corner of each face corner.
        corner_uvs: ``(K, 2)`` float64 UVs of the corners.
        corner_chart: ``(K,)`` int64 chart of each corner, ``0 .. count - 1``.
        count: number of charts.
    """

    corner_faces: np.ndarray
    corner_uvs: np.ndarray
    corner_chart: np.ndarray
    count: int

    def face_chart(self) -> np.ndarray:
        """``(G,)`` chart of each face."""
        return self.corner_chart[self.corner_faces[:, 0]]

    def extents(self) -> tuple[np.ndarray, np.ndarray]:
        """``((C, 2) low corner, (C, 2) extent)`` of each chart's UV bounding box."""
        return label_boxes(self.corner_uvs, self.corner_chart, self.count)


def label_boxes(
    points: np.ndarray, labels: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """``((count, 2) low corner, (count, 2) extent)`` float64 of the bounding box of the
    ``(N, 2)`` points of each of ``count`` labels (``labels`` ``(N,)``; an unused label's low
    corner is ``inf``)."""
    low, high = np.full((count, 2), np.inf), np.full((count, 2), -np.inf)
    for axis in range(2):
        np.minimum.at(low[:, axis], labels, points[:, axis])
        np.maximum.at(high[:, axis], labels, points[:, axis])
    return low, high - low


@dataclass
class Packed:
    """Where each chart went: ``new = linear @ old + offset``.

    Attributes:
        linear: ``(C, 2, 2)`` float64, a signed permutation times the chart's planned scale.
        offset: ``(C, 2)`` float64.
        texels_per_unit: atlas texels per scaled UV unit (the density found).
        boxed: ``(C,)`` bool, the chart was packed as its bounding box.
    """

    linear: np.ndarray
    offset: np.ndarray
    texels_per_unit: float
    boxed: np.ndarray


def signed_areas(uvs: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F,)`` float64 signed area of each face (positive: counter-clockwise)."""
    return corner_areas(np.asarray(uvs, np.float64)[faces])


def corner_areas(corners: np.ndarray) -> np.ndarray:
    """``(F,)`` float64 signed area of ``(F, 3, 2)`` triangles (positive: counter-clockwise)."""
    corners = np.asarray(corners, np.float64)
    a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def folded_charts(charts: Charts) -> np.ndarray:
    """``(C,)`` bool: the chart has faces wound both ways (folded over itself)."""
    area = signed_areas(charts.corner_uvs, charts.corner_faces)
    face_chart = charts.face_chart()
    ids = np.arange(charts.count)
    return np.isin(ids, face_chart[area > 0]) & np.isin(ids, face_chart[area < 0])


def _proxies(
    charts: Charts, scales: np.ndarray, tpu: float, boxes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What xatlas packs: ``((P, 2) proxy corners in old UV units, (Q, 3) faces, (P,) chart)``.
    A chart is its own proxy, or (``boxes``, or under :data:`MIN_BOX_TEXELS` at ``tpu``) its
    bounding box, widened to that minimum."""
    low, extent = charts.extents()
    least = MIN_BOX_TEXELS / (scales * tpu)  # (C,) old UV units
    boxes = boxes | (extent < least[:, None]).any(axis=1)
    keep = ~boxes[charts.face_chart()]
    uvs, faces, chart = [charts.corner_uvs], [charts.corner_faces[keep]], [charts.corner_chart]
    start = len(charts.corner_uvs)
    for box in np.flatnonzero(boxes):
        (u0, v0), (du, dv) = low[box], np.maximum(extent[box], least[box])
        uvs.append(np.array([[u0, v0], [u0 + du, v0], [u0 + du, v0 + dv], [u0, v0 + dv]]))
        faces.append(start + np.array([[0, 1, 2], [0, 2, 3]]))
        chart.append(np.full(4, box))
        start += 4
    uvs, faces, chart = np.concatenate(uvs), np.concatenate(faces), np.concatenate(chart)
    used = np.zeros(len(uvs), bool)
    used[faces] = True  # the corners of boxed charts are left out
    return uvs[used], (np.cumsum(used) - 1)[faces], chart[used]


def _pack_once(
    proxies: tuple[np.ndarray, np.ndarray, np.ndarray],
    scales: np.ndarray,
    size: int,
    tpu: float,
    padding: int,
    rotate: bool,
) -> np.ndarray | None:
    """``(P, 2)`` packed proxy corners in [0, 1], or None when they need more than one atlas
    or xatlas left a corner out or split one. About ``padding`` texels are left empty between
    charts: xatlas pads each chart by its own padding, so it is asked half of it
    (:data:`XATLAS_PADDING_SHARE`). It packs into ``size - padding`` texels, centred: with
    repeat addressing the atlas's border is a seam like any other, and xatlas places charts
    up to its edge."""
    uvs, faces, chart = proxies
    inner = size - padding  # xatlas ignores repeat addressing: keep padding across the border
    atlas = xatlas.Atlas()
    scaled = uvs * scales[chart, None] * XATLAS_UNIT
    atlas.add_uv_mesh(scaled.astype(np.float32), faces.astype(np.uint32))
    options = xatlas.PackOptions()
    options.resolution, options.texels_per_unit = inner, tpu / XATLAS_UNIT
    options.padding = math.ceil(XATLAS_PADDING_SHARE * padding)
    options.rotate_charts, options.rotate_charts_to_axis = rotate, False
    options.bilinear, options.blockAlign, options.bruteForce = False, False, False
    atlas.generate(pack_options=options)
    _retire(atlas)
    if atlas.atlas_count != 1 or (atlas.width, atlas.height) != (inner, inner):
        return None
    vmapping, indices, packed = atlas.get_mesh(0)
    new = np.full((len(uvs), 2), np.nan)
    new[vmapping] = (packed * inner + padding / 2) / size
    if indices.shape != faces.shape or np.isnan(new).any():
        return None
    if not np.allclose(new[vmapping], (packed * inner + padding / 2) / size, atol=1e-6):
        return None
    return new


def _retire(atlas: xatlas.Atlas, clock: Clock = WALL_CLOCK) -> None:
    """Keep a used atlas alive for a while; destroy those retired long (on ``clock``) or many
    packings ago."""
    now = clock.now()
    while _retired and (len(_retired) >= RETIRED_ATLASES or now - _retired[0][0] > RETIRED_SECONDS):
        _retired.popleft()
    _retired.append((now, atlas))


def _fit(old: np.ndarray, chart: np.ndarray, new: np.ndarray, count: int):
    """Per chart the least-squares affine map ``new = linear @ old + offset`` and its largest
    residual: ``((C, 2, 2), (C, 2), (C,))``, from the ``(P, 2)`` ``old`` and ``new`` points of
    each ``(P,)`` ``chart``: about their means, ``linear`` is the cross-covariance times the
    pseudo-inverse of the scatter (all charts at once)."""
    points = np.maximum(np.bincount(chart, minlength=count), 1)[:, None]
    old_mean = np.stack([np.bincount(chart, old[:, i], count) for i in (0, 1)], 1) / points
    new_mean = np.stack([np.bincount(chart, new[:, i], count) for i in (0, 1)], 1) / points
    about_old, about_new = old - old_mean[chart], new - new_mean[chart]
    scatter, cross = np.zeros((count, 2, 2)), np.zeros((count, 2, 2))
    for i in (0, 1):
        for j in (0, 1):
            scatter[:, i, j] = np.bincount(chart, about_old[:, i] * about_old[:, j], count)
            cross[:, i, j] = np.bincount(chart, about_new[:, i] * about_old[:, j], count)
    linear = cross @ np.linalg.pinv(scatter)
    offset = new_mean - np.einsum("cij,cj->ci", linear, old_mean)
    error = np.einsum("pij,pj->pi", linear[chart], old) + offset[chart] - new
    residual = np.zeros(count)
    np.maximum.at(residual, chart, np.abs(error).max(axis=1))
    return linear, offset, residual


def _similarity(
    matrix: np.ndarray, old: np.ndarray, new: np.ndarray, planned: float, size: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """One chart's exact similarity at scale ``planned`` from its fitted ``matrix``, placed at
    the low corner of the box xatlas gave it; None unless xatlas moved it by an axis-aligned
    map at least as large as planned and at most two texels larger."""
    axis = np.abs(matrix).argmax(axis=0)  # the new axis each old axis went to
    signs = np.zeros((2, 2))
    signs[axis, [0, 1]] = np.sign(matrix[axis, [0, 1]])
    off_axis = np.abs(matrix * (1 - np.abs(signs))).max() / np.abs(matrix).max()
    if axis[0] == axis[1] or off_axis > 1e-3:
        return None
    stretch = np.abs(matrix).max(axis=0)
    extent = old.max(axis=0) - old.min(axis=0)
    if (stretch < planned * (1 - SCALE_TOLERANCE)).any():
        return None  # shrunk
    if ((stretch - planned) * extent > 2.01 / size).any():
        return None
    linear = planned * signs
    return linear, new.min(axis=0) - (old @ linear.T).min(axis=0)


def _split(proxies, new: np.ndarray, count: int, size: int) -> np.ndarray:
    """``(C,)`` bool: xatlas did not move the chart's proxy as one piece."""
    old, _, chart = proxies
    return _fit(old, chart, new, count)[2] > 0.01 / size


def scales_at(
    scales: np.ndarray, tpu: float, size: int, cap: float | None, aligned: bool = False
) -> np.ndarray:
    """``(C,)`` ``scales`` as packed at density ``tpu``: each chart's planned scale
    (``scales * tpu / size``) at most ``cap`` (the original's texels per texel of the output:
    no chart gets more texels than the original has; None: no cap) and, where ``aligned``,
    rounded down to ``cap`` times a power of two, so that each new texel covers a power-of-two
    block of original texels."""
    if cap is None:
        return scales
    planned = scales * tpu / size
    if aligned:
        steps = np.floor(np.log2(np.maximum(planned, 1e-30) / cap) + 1e-9)
        return cap * 2.0 ** np.minimum(steps, 0.0) * size / tpu
    return np.minimum(planned, cap) * size / tpu


def filling_density(
    chart_area: np.ndarray,
    scales: np.ndarray,
    size: int,
    cap: float | None,
    aligned: bool = False,
) -> float:
    """Texels per scaled UV unit at which the charts, of ``(C,)`` UV areas ``chart_area``
    scaled by ``(C,)`` ``scales`` as packed there (:func:`scales_at` with ``cap`` and
    ``aligned``), would cover every texel of a ``size x size`` atlas; where capped charts never
    do, the density at which the last one reaches its cap (no denser packing differs)."""
    uncapped = size / math.sqrt(max(float((scales**2 * chart_area).sum()), 1e-30))
    if cap is None:
        return uncapped

    def covered(tpu: float) -> float:  # share of the atlas: rises with the density
        packed = scales_at(scales, tpu, size, cap, aligned) * tpu / size
        return float((packed**2 * chart_area).sum())

    low, high = uncapped, max(uncapped, float((cap * size / np.maximum(scales, 1e-30)).max()))
    if covered(high) <= 1.0:
        return high
    while high > low * (1 + 1e-9):  # bisection: covered(low) <= 1 < covered(high)
        middle = math.sqrt(low * high)
        low, high = (middle, high) if covered(middle) <= 1.0 else (low, middle)
    return high


def _place(
    charts: Charts,
    scales: np.ndarray,
    size: int,
    tpu: float,
    padding: int,
    rotate: bool,
    boxes: np.ndarray,
    cap: float | None = None,
    aligned: bool = False,
) -> tuple[Packed | None, np.ndarray]:
    """One packing at density ``tpu``: the charts' similarities, or None; and the boxes used
    (charts xatlas split are boxed and packed again). The scales are :func:`scales_at`
    ``tpu``."""
    scales = scales_at(scales, tpu, size, cap, aligned)
    for _ in range(4):
        proxies = _proxies(charts, scales, tpu, boxes)
        new = _pack_once(proxies, scales, size, tpu, padding, rotate)
        if new is None:
            return None, boxes
        split = _split(proxies, new, charts.count, size)
        if not split.any():
            break
        boxes = boxes | split
    else:
        return None, boxes
    old, _, chart = proxies
    fitted, _, _ = _fit(old, chart, new, charts.count)
    linear, offset = np.zeros((charts.count, 2, 2)), np.zeros((charts.count, 2))
    for index in range(charts.count):
        mine = chart == index
        planned = scales[index] * tpu / size
        found = _similarity(fitted[index], old[mine], new[mine], planned, size)
        if found is None:
            return None, boxes
        linear[index], offset[index] = found
    return Packed(linear, offset, tpu, boxes.copy()), boxes


def pack(
    charts: Charts,
    scales: np.ndarray,
    size: int,
    padding: int,
    rotate: bool,
    budget: Budget | None = None,
    cap: float | None = None,
    aligned: bool = False,
    aim: bool = False,
    sparsest: float | None = None,
) -> Packed:
    """The densest packing of ``charts``, each scaled by ``scales`` ``(C,)``, into one
    ``size x size`` atlas with ``padding`` texels between charts; charts turn by multiples of
    90 degrees or transpose only where ``rotate``. Deterministic: the same input gives the
    same output, unless the search is stopped by ``budget`` (None: never): past its end no
    further density is tried, and the densest found so far is returned.
    With a ``cap`` (the original's texels per output texel), each chart's scale at the
    density tried is at most the cap and, ``aligned``, rounded down to the cap times a power
    of two (:func:`scales_at`): the packed scales are ``sqrt(|det linear|)``, not ``scales``
    times the density.

    The search looks no lower than ``sparsest``, the least density worth a packing (texels per
    scaled UV unit; None: 1/16 of the density at which the charts would fill every texel):
    first at the middle of its bracket, then, where that does not fit, at ``sparsest``, and it
    gives up where even that does not fit (charts that many small ones' paddings crowd out of
    the atlas fail at every density, each failed packing as costly as one that fits).

    Atlases of at least :data:`COARSE_MIN_SIZE` are searched at a smaller size first
    (:data:`COARSE_FACTOR`), where a packing costs a third, to :data:`COARSE_RATIO` (``aim``:
    the search is such an aim); at full size :data:`REFINE_STEPS` times the coarse answer are
    tried until one fits, and where the first does, the search climbs above it by
    :data:`CLIMB` up to :data:`COARSE_SPAN`. Where nothing near the coarse answer fits, the
    full size is searched from scratch: a bisection from ``sparsest``, then :data:`PROBES`.
    Where the coarse search finds nothing even at ``sparsest``, the full size looks there and
    climbs from it (its finer texels fit a few percent more, rarely more than that).

    Raises:
        PackingError: not even a sparse packing holds the charts at their planned scales, or
            none was found within ``budget``.
    """
    if 2 * padding >= size:
        raise PackingError(f"a padding of {padding} texels leaves no room in {size}x{size}")
    areas = np.abs(signed_areas(charts.corner_uvs, charts.corner_faces))
    chart_area = np.bincount(charts.face_chart(), areas, minlength=charts.count)
    every_texel = filling_density(chart_area, scales, size, cap, aligned)
    refusal = f"the UV charts do not fit one {size}x{size} atlas at their planned scales" + (
        "" if sparsest is None else ", even at the least density worth packing"
    )
    late = "the time budget left no time to pack the UV charts"
    if sparsest is not None and sparsest > every_texel:
        raise PackingError(refusal)  # charts that dense would cover more than every texel
    least = every_texel / 16 if sparsest is None else sparsest
    search = _Search(charts, scales, size, padding, rotate, budget, cap, aligned)
    if size >= COARSE_MIN_SIZE:
        coarse = size // COARSE_FACTOR
        factor = size / coarse
        padded = math.ceil(padding / factor)
        try:
            rough = pack(charts, scales, coarse, padded, rotate, budget, cap, aligned, True,
                         least / factor)  # fmt: skip
        except PackingError:  # not even at the least density: the full size fits little more
            best = None if search.late() else search.place(least)
            if best is None:
                raise PackingError(late if search.late() else refusal) from None
            return search.climb(best, least * COARSE_SPAN)
        best = search.refine(rough.texels_per_unit * factor)
        if best is not None:
            return best
    best = search.start(least, every_texel)
    if best is None:
        raise PackingError(late if search.late() else refusal)
    ratio = COARSE_RATIO if aim else SEARCH_RATIO
    best = search.bisect(best.texels_per_unit, every_texel, ratio, best)
    return best if aim else search.probe(best)


@dataclass
class _Search:
    """The density search of one :func:`pack` call at one atlas size: each look packs once."""

    charts: Charts
    scales: np.ndarray
    size: int
    padding: int
    rotate: bool
    budget: Budget | None
    cap: float | None
    aligned: bool

    def __post_init__(self) -> None:
        self.boxes = folded_charts(self.charts)

    def late(self) -> bool:
        return self.budget is not None and self.budget.expired()

    def place(self, tpu: float) -> Packed | None:
        """The packing at density ``tpu``, or None (charts xatlas split are boxed from then
        on)."""
        packed, self.boxes = _place(self.charts, self.scales, self.size, tpu, self.padding,
                                    self.rotate, self.boxes, self.cap, self.aligned)  # fmt: skip
        return packed

    def refine(self, guess: float) -> Packed | None:
        """The packing at the first of :data:`REFINE_STEPS` times ``guess`` that fits, or None;
        where the first fits, the densest of the climb above it (:data:`CLIMB`, up to
        :data:`COARSE_SPAN` times ``guess``)."""
        for index, step in enumerate(REFINE_STEPS):
            if self.late():
                return None
            best = self.place(guess * step)
            if best is not None:
                return best if index > 0 else self.climb(best, guess * COARSE_SPAN)
        return None

    def climb(self, best: Packed, ceiling: float) -> Packed:
        """The densest packing of a climb above ``best`` in :data:`CLIMB` steps while they
        fit, up to density ``ceiling``."""
        while not self.late() and best.texels_per_unit * CLIMB <= ceiling:
            denser = self.place(best.texels_per_unit * CLIMB)
            if denser is None:
                break
            best = denser
        return best

    def start(self, least: float, most: float) -> Packed | None:
        """A first packing for the bisection: at the geometric middle of densities ``least``
        and ``most``, else at ``least``; None where neither fits (or the budget ended)."""
        for density in (math.sqrt(least * most), least):
            if self.late():
                return None
            packed = self.place(density)
            if packed is not None:
                return packed
        return None

    def bisect(self, low: float, high: float, ratio: float, best: Packed) -> Packed:
        """The densest packing a bisection finds between densities ``low`` (``best``'s) and
        ``high`` (not known to fit): at most :data:`SEARCH_STEPS` looks, until the bracket is
        ``ratio`` narrow or the budget ends."""
        for _ in range(SEARCH_STEPS):
            if self.late() or high <= low * ratio:
                break
            middle = math.sqrt(low * high)
            packed = self.place(middle)
            if packed is not None:
                low, best = middle, packed
            else:
                high = middle
        return best

    def probe(self, best: Packed) -> Packed:
        """``best``, or a denser packing :data:`PROBES` find above it."""
        for factor in PROBES:
            if self.late():
                break
            best = self.place(best.texels_per_unit * factor) or best
        return best


def chart_texels(
    corner_uvs: np.ndarray, labels: np.ndarray, size: int, supersample: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Texels each face's chart covers: ``((N,) flat texel index, (N,) label)`` pairs, each
    once, where a texel counts as covered when one of its ``supersample^2`` sample centres
    lies in a face (edges included, to :data:`EDGE_HAIR`); repeat addressing wraps texels
    onto the grid.

    Args:
        corner_uvs: ``(F, 3, 2)`` UVs of each face's corners; labels: ``(F,)`` int chart of
            each face; size: texels per side.
    """
    face, row, first, last = sample_spans(np.asarray(corner_uvs, np.float64), size * supersample)
    first, last = first // supersample, last // supersample  # texel columns
    span, offset = _expand(last - first + 1)
    col = np.mod(first[span] + offset, size)
    texel_row = np.mod(row[span] // supersample, size)
    texel, label = texel_row * size + col, labels[face[span]]
    count = int(labels.max(initial=0)) + 1
    least = np.full(size * size, count)
    np.minimum.at(least, texel, label)
    largest = np.full(size * size, -1)
    np.maximum.at(largest, texel, label)
    mixed = (least < largest)[texel]  # texels of two labels or more: each pair once
    keys = np.unique(texel[mixed] * count + label[mixed])
    single = np.flatnonzero(least == largest)
    keys = np.sort(np.r_[single * count + least[single], keys])  # by texel, then label
    return keys // count, keys % count


def sample_spans(
    corner_uvs: np.ndarray, grid: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The samples of a ``grid x grid`` lattice (centres at half-integers, rows downwards
    from ``v = 1``) inside each face, edges included, as runs along rows:
    ``((S,) face, (S,) row, (S,) first column, (S,) last column)`` int64 over the non-empty
    runs, rows and columns unwrapped (they may lie outside ``0 .. grid - 1``).

    Args:
        corner_uvs: ``(F, 3, 2)`` float64 UVs of each face's corners.
    """
    points = np.stack([corner_uvs[..., 0] * grid, (1.0 - corner_uvs[..., 1]) * grid], axis=-1)
    heights = points[..., 1]
    row0 = np.ceil(heights.min(axis=1) - 0.5).astype(np.int64)
    rows = np.maximum(np.floor(heights.max(axis=1) - 0.5).astype(np.int64) - row0 + 1, 0)
    face, offset = _expand(rows)
    row = row0[face] + offset
    y = row + 0.5
    turn = np.where(corner_areas(points) < 0, -1.0, 1.0)[face]  # inside: every side >= 0
    widths = points[face, :, 0]  # (S, 3): a face lies within its box, degenerate ones too
    lower, upper = widths.min(axis=1) - EDGE_HAIR, widths.max(axis=1) + EDGE_HAIR
    empty = np.zeros(len(face), bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        start, edge = points[face, a], points[face, b] - points[face, a]
        # side(x) = edge_x (y - start_y) - edge_y (x - start_x) = slope x + intercept
        slope = -edge[:, 1] * turn
        intercept = (edge[:, 0] * (y - start[:, 1]) + edge[:, 1] * start[:, 0]) * turn
        intercept += EDGE_HAIR * np.hypot(edge[:, 0], edge[:, 1])
        bound = -intercept / np.where(slope == 0, 1.0, slope)
        lower = np.where(slope > 0, np.maximum(lower, bound), lower)
        upper = np.where(slope < 0, np.minimum(upper, bound), upper)
        empty |= (slope == 0) & (intercept < 0)
    first = np.ceil(lower - 0.5)
    last = np.floor(upper - 0.5)
    keep = ~empty & (last >= first)
    return face[keep], row[keep], first[keep].astype(np.int64), last[keep].astype(np.int64)


def _expand(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For items of ``counts[i]`` elements each: ``(item, position within item)`` per
    element."""
    item = np.repeat(np.arange(len(counts)), counts)
    return item, np.arange(len(item)) - (np.cumsum(counts) - counts)[item]


def overlapping_texels(texels: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Flat texel indices covered by more than one label (:func:`chart_texels`)."""
    index, count = np.unique(texels, return_counts=True)
    return index[count > 1]


def padding_violations(texels: np.ndarray, labels: np.ndarray, size: int, padding: int) -> int:
    """Texels of one chart with a texel of another chart less than ``padding`` texels away
    (Chebyshev distance, repeat addressing; texels two charts cover are
    :func:`overlapping_texels`' and count for neither): 0 when at least ``padding - 1`` empty
    texels separate every two charts. Per texel, the least and the largest label within its
    window (separable minimum and maximum filters) differ from its own where a neighbour is
    another chart's. (scipy.ndimage is imported here: a job imports it only where it plans a
    layout.)"""
    from scipy.ndimage import maximum_filter, minimum_filter

    grid = np.full(size * size, -1, np.int64)
    grid[texels] = labels
    grid[overlapping_texels(texels, labels)] = -1
    grid = grid.reshape(size, size)
    window = 2 * max(padding - 1, 0) + 1
    charted = grid >= 0
    largest = maximum_filter(grid, size=window, mode="wrap")
    unlabelled = int(grid.max(initial=0)) + 1  # (the filters mishandle int64's largest)
    least = minimum_filter(np.where(charted, grid, unlabelled), size=window, mode="wrap")
    return int((charted & ((largest != grid) | (least != grid))).sum())
