"""Every texture map of a material resized as what it holds.

A map is an ``(H, W, C)`` uint8 array, row 0 at the top, ``C`` in 1..4; it is resized to
``size = (h, w)`` with ``1 <= h <= H`` and ``1 <= w <= W`` (any ratio, also non-integer), and
comes back ``(h, w, C)`` uint8. glTF slots fall in three classes (:func:`texture_class`):

- ``COLOR`` (base colour, emissive, sheen/specular colour): colour channels are sRGB-encoded;
  they are decoded to linear light, filtered with Pillow's Lanczos kernel in float32, clipped to
  [0, 1], encoded back and rounded. Alpha (``C`` 2 or 4) is linear coverage, filtered on its own
  the same way, never premultiplied; with an ``alpha_cutoff`` (glTF ``alphaMode: MASK``) it is
  scaled afterwards so that the share of texels that pass the cutoff stays what it was.
- ``NORMAL`` (tangent-space normal maps): RGB encodes ``xyz = 2 v / 255 - 1`` (the filter is the
  same for OpenGL- and DirectX-style green). Each texel's vector is normalised, the unit vectors
  are averaged with Pillow's BOX filter (non-negative weights: a negative lobe could flip a
  vector), the mean is renormalised and encoded again, with ``z >= 0``. A 4th channel is data.
- ``DATA`` (metallic-roughness, occlusion, ARM, everything else): linear values, each channel
  resized on its own with Pillow's Lanczos, clamped to 0..255: the ``lanczos`` baseline of
  :mod:`geoscaler.resize.filters`. Channels never mix.

One implementation of each idea: the sRGB transfer is :mod:`geoscaler.render.texture`'s (the decode
as a 256-entry table made with it), the Lanczos and BOX kernels are Pillow's, run through
:func:`geoscaler.resize.filters.resize_channels` (8-bit planes for data, float32 planes otherwise).

Memory: no float copy of a whole map is made. Float planes are decoded ``_BAND`` rows at a
time and filtered along rows into float32 ``(H, w)`` intermediates, then along columns
(:func:`_separable`): one intermediate per colour or alpha channel in turn, three for normals
(x, y, z together). Beyond the input the peak is ``k x H x w x 4`` bytes (``k`` = 1, or 3 for
normals), a few float32 arrays of the output's size and a few ``_BAND x W`` bands: measured
for 8192 x 8192 RGB -> 2048 x 2048, 0.21 GB (COLOR) and 0.36 GB (NORMAL) above the process
holding the input, where one float32 RGBA copy of the input would be 1 GB. DATA maps take one
uint8 copy of a channel and Pillow's copy of it (0.1 GB).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterator

import numpy as np
import torch
from PIL import Image

from geoscaler.color import linear_to_srgb, srgb_to_linear
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import check_texture
from geoscaler.resize.filters import resize_channels
from geoscaler.resize.sizes import COLOR, DATA, NORMAL, TEXTURE_CLASSES

__all__ = [
    "COLOR",
    "DATA",
    "METHOD_NAMES",
    "NORMAL",
    "TEXTURE_CLASSES",
    "alpha_coverage",
    "normal_shortening",
    "resize_alpha",
    "resize_map",
    "texture_class",
    "toksvig_roughness",
]


METHOD_NAMES: dict[str, str] = {
    COLOR: "Lanczos in linear light",
    NORMAL: "vector average, renormalised",
    DATA: "Lanczos per channel",
}
"""Texture class -> the short name of its resize method, as reports print it."""

_SLOTS = {
    "baseColorTexture": COLOR,
    "emissiveTexture": COLOR,
    "normalTexture": NORMAL,
    "metallicRoughnessTexture": DATA,
    "occlusionTexture": DATA,
    # The archived specular-glossiness workflow stores sRGB colour under names the suffix rule
    # would call data: diffuse (RGB + linear alpha) and specular (RGB) + glossiness (alpha).
    "KHR_materials_pbrSpecularGlossiness/diffuseTexture": COLOR,
    "KHR_materials_pbrSpecularGlossiness/specularGlossinessTexture": COLOR,
    # MTL maps glTF has no slot for (``mtl:KEYWORD``): ambient, specular and reflection colours;
    # the others (map_Ns, map_d, bump, disp, ...) are data by the rule.
    "mtl:map_Ka": COLOR,
    "mtl:map_Ks": COLOR,
    "mtl:refl": COLOR,
}
"""Slots whose class is not given by the suffix rule of :func:`texture_class`."""

_BAND = 256
"""Rows decoded at a time where a whole-map float temporary is not needed."""

_LEVELS = np.arange(256, dtype=np.float32)
_UNIT = _LEVELS / np.float32(255.0)
"""``(256,)`` float32: 8-bit value -> [0, 1]."""
_SRGB_DECODE = srgb_to_linear(torch.from_numpy(_UNIT)).numpy()
"""``(256,)`` float32: 8-bit sRGB value -> linear light (the same numbers as
:func:`geoscaler.color.texture_to_linear`)."""
_SNORM_DECODE = _LEVELS * np.float32(2.0 / 255.0) - np.float32(1.0)
"""``(256,)`` float32: 8-bit normal-map value -> vector component ``2 v / 255 - 1``."""


def texture_class(slot: str) -> str:
    """Class of a material's texture slot. Slots are glTF names: "baseColorTexture",
    "emissiveTexture" -> COLOR; "normalTexture" -> NORMAL; "metallicRoughnessTexture",
    "occlusionTexture" -> DATA; extension slots are written
    "KHR_materials_clearcoat/clearcoatNormalTexture" (extension/field): field names ending in
    "NormalTexture" -> NORMAL, "ColorTexture" (sheenColorTexture, specularColorTexture, ...)
    -> COLOR, everything else -> DATA.

    MTL maps glTF has no slot for are ``"mtl:KEYWORD"``: ``map_Ka``, ``map_Ks`` and ``refl``
    are COLOR, the rest DATA. One exception to the suffix rule: the two maps of
    ``KHR_materials_pbrSpecularGlossiness`` (``diffuseTexture``, ``specularGlossinessTexture``)
    hold sRGB colour (plus linear alpha), so they are COLOR.
    """
    if slot in _SLOTS:
        return _SLOTS[slot]
    field = slot.rpartition("/")[2]
    if field.endswith("NormalTexture"):
        return NORMAL
    if field.endswith("ColorTexture"):
        return COLOR
    return DATA


def resize_map(
    pixels: np.ndarray, size: tuple[int, int], kind: str, *, alpha_cutoff: float | None = None
) -> np.ndarray:
    """(H, W, C) uint8 (C 1-4, row 0 at the top) -> (h, w, C) uint8 at size=(h, w), each
    class as what it holds.

    Args:
        pixels: ``(H, W, C)`` uint8 map; a NORMAL map needs ``C >= 3`` (RGB = xyz).
        size: ``(h, w)`` in texels, ``1 <= h <= H``, ``1 <= w <= W``.
        kind: ``COLOR``, ``NORMAL`` or ``DATA`` (see the module docstring for each method).
        alpha_cutoff: glTF ``alphaCutoff`` of a ``MASK`` material, a number >= 0 (0.5 by
            glTF's default): the alpha of a COLOR map (``C`` 2 or 4) is then scaled so that
            the share of texels with ``alpha / 255 >= alpha_cutoff`` stays what it was (see
            :func:`_coverage_scale`). ``None``: alpha is filtered linearly. Maps without an
            alpha channel, and NORMAL and DATA maps, have no coverage and ignore it.

    Returns:
        ``(h, w, C)`` uint8, a new array; a copy of ``pixels`` when ``size`` is its size.

    Raises:
        GeoscalerError: not a uint8 map of 1-4 channels (3-4 for NORMAL), an unknown ``kind``,
            a size larger than the map or smaller than 1 texel, a bad ``alpha_cutoff``.
    """
    size = _check(pixels, size, kind)
    if alpha_cutoff is not None and not (
        isinstance(alpha_cutoff, numbers.Real)
        and not isinstance(alpha_cutoff, bool)
        and math.isfinite(alpha_cutoff)
        and alpha_cutoff >= 0
    ):
        raise GeoscalerError(f"alphaCutoff {alpha_cutoff!r}: must be a number >= 0, e.g. 0.5")
    if size == pixels.shape[:2]:
        return pixels.copy()
    if kind == COLOR:
        return _resize_color(pixels, size, alpha_cutoff)
    if kind == NORMAL:
        return _resize_normal(pixels, size)
    return resize_channels(pixels, size, Image.Resampling.LANCZOS)


def normal_shortening(pixels: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """How much a normal map's vectors cancel out when it is resized to ``size``.

    The length of the mean of the unit vectors over each output texel's footprint (the same
    BOX average as :func:`resize_map` with ``NORMAL``), before renormalisation: 1 where the
    footprint is flat, smaller where it is bumpy. Toksvig's factor for widening the specular
    lobe (roughness) of the smaller map.

    Args:
        pixels: ``(H, W, C)`` uint8 normal map, ``C`` 3 or 4 (a 4th channel is ignored).
        size: ``(h, w)``, as for :func:`resize_map`.

    Returns:
        ``(h, w)`` float32 in (0, 1]: lengths, clamped to [1e-6, 1] (float rounding can make
        the mean of identical unit vectors a hair longer than 1).
    """
    size = _check(pixels, size, NORMAL)
    if size == pixels.shape[:2]:
        return np.ones(size, np.float32)
    lengths = np.linalg.norm(_mean_unit_normals(pixels, size), axis=-1)
    return np.clip(lengths, 1e-6, 1.0).astype(np.float32)


def toksvig_roughness(
    metallic_roughness: np.ndarray, shortening: np.ndarray, roughness_factor: float = 1.0
) -> np.ndarray:
    """A metallic-roughness map whose roughness (G) is widened by a normal map's shortening.

    A minified normal map loses the variance of its normals; under light that variance is
    what made highlights spread. Toksvig's factor gives it back as roughness: with ``s`` the
    shortening (:func:`normal_shortening`), the variance ``(1 - s) / s`` is added to the GGX
    ``a^2`` twice, as Filament's specular anti-aliasing adds its kernel roughness:
    ``a'^2 = min(1, a^2 + 2 (1 - s) / s)`` with ``a = r^2`` and ``r = G / 255 x factor``.

    Args:
        metallic_roughness: ``(h, w, C)`` uint8 map at its shipping size, ``C`` 3 or 4
            (roughness in G; grey maps, whose one channel is every value, are returned as
            they are).
        shortening: ``(hn, wn)`` float32 in (0, 1], at the normal map's shipping size;
            resampled bilinearly to ``(h, w)`` where the sizes differ.
        roughness_factor: the material's ``roughnessFactor``; 0 leaves the map as it is.

    Returns:
        ``(h, w, C)`` uint8, a new array; only G changes, and never gets smaller.
    """
    out = metallic_roughness.copy()
    if out.ndim != 3 or out.shape[2] < 3 or roughness_factor <= 0:
        return out
    height, width = out.shape[:2]
    if shortening.shape != (height, width):
        plane = Image.fromarray(np.asarray(shortening, np.float32))
        shortening = np.asarray(plane.resize((width, height), Image.Resampling.BILINEAR))
    s = np.clip(shortening, 1e-6, 1.0).astype(np.float64)
    roughness = out[..., 1] / 255.0 * roughness_factor
    alpha_sq = np.minimum(roughness**4 + 2.0 * (1.0 - s) / s, 1.0)
    widened = np.clip(alpha_sq**0.25 / roughness_factor, 0.0, 1.0) * 255.0
    out[..., 1] = np.maximum(np.round(widened), out[..., 1]).astype(np.uint8)
    return out


def alpha_coverage(alpha: np.ndarray, alpha_cutoff: float) -> float:
    """Share of texels a glTF ``MASK`` material keeps: ``alpha / 255 >= alpha_cutoff``.

    Args:
        alpha: ``(H, W)`` uint8 alpha channel (any shape of uint8 works).
        alpha_cutoff: the material's ``alphaCutoff``.

    Returns:
        The fraction in [0, 1].
    """
    return np.count_nonzero(alpha >= _first_kept(alpha_cutoff)) / alpha.size


# ----------------------------------------------------------------------------- checks


def _check(pixels: np.ndarray, size: tuple[int, int], kind: str) -> tuple[int, int]:
    """Validate a map, its class and its target size; return the size as ``(h, w)`` ints."""
    if kind not in TEXTURE_CLASSES:
        raise GeoscalerError(
            f"unknown texture class {kind!r}: choose one of {', '.join(TEXTURE_CLASSES)}"
        )
    check_texture(pixels, f"{kind} map", channels=(3, 4) if kind == NORMAL else (1, 2, 3, 4))
    height, width = pixels.shape[:2]
    try:
        h, w = (int(side) for side in size)
        whole = all(int(side) == side and not isinstance(side, bool) for side in size)
    except (TypeError, ValueError):
        h = w = 0
        whole = False
    if not whole or not (1 <= h <= height and 1 <= w <= width):
        raise GeoscalerError(
            f"cannot resize a {height} x {width} {kind} map to {size!r}: the size must be "
            f"(h, w) whole numbers from 1 x 1 up to {height} x {width} (maps are only reduced)"
        )
    return h, w


# ----------------------------------------------------------------------------- filters


def _separable(
    bands: Iterator[tuple[np.ndarray, ...]],
    height: int,
    size: tuple[int, int],
    resample: Image.Resampling,
) -> list[np.ndarray]:
    """Filter planes that arrive in row bands with a Pillow filter, rows first, then columns.

    Args:
        bands: for consecutive row bands from the top, ``k`` float32 planes ``(b, W)`` each
            (``b <= _BAND``), together covering ``height`` rows.
        height: ``H``, the rows of the whole planes.
        size: ``(h, w)``.
        resample: the Pillow filter (``LANCZOS`` or ``BOX``).

    Returns:
        ``k`` float32 planes ``(h, w)``, not clamped (Lanczos can overshoot [0, 1]).

    Each band is filtered along its rows into ``k`` float32 ``(H, w)`` intermediates, which
    are then filtered along their columns: Pillow's own order and precision (float64 sums,
    float32 between the passes), so the result is Pillow's on the whole plane to float32
    rounding (1 ulp), and a band size never changes it. Peak: the intermediates plus one band.
    """
    h, w = size
    rows: list[np.ndarray] = []
    top = 0
    for planes in bands:
        if not rows:
            rows = [np.empty((height, w), np.float32) for _ in planes]
        for row, plane in zip(rows, planes, strict=True):
            row[top : top + len(plane)] = _pillow_plane(plane, (len(plane), w), resample)
        top += len(planes[0])
    return [_pillow_plane(row, (h, w), resample) for row in rows]


def _pillow_plane(plane: np.ndarray, size: tuple[int, int], resample: Image.Resampling):
    """``(H, W)`` float32 -> ``size`` float32 through
    :func:`geoscaler.resize.filters.resize_channels` (a Pillow 'F' image; a side left unchanged is
    not filtered)."""
    return resize_channels(plane[..., None], size, resample)[..., 0]


def _decoded_bands(channel: np.ndarray, table: np.ndarray) -> Iterator[tuple[np.ndarray]]:
    """``(H, W)`` uint8 (any strides) as ``(b, W)`` float32 bands of ``table[channel]``
    (``np.take`` on a band: indexing a whole channel at once would make an ``(H, W)`` int64
    copy of the indices, 0.5 GB at 8k, and an ``(H, W)`` float32 plane)."""
    for top in range(0, channel.shape[0], _BAND):
        yield (np.take(table, channel[top : top + _BAND]),)


def _to_uint8(unit: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (clipped first) -> uint8, rounded half up."""
    return np.floor(np.clip(unit, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


# ----------------------------------------------------------------------------- colour


def _resize_color(
    pixels: np.ndarray, size: tuple[int, int], alpha_cutoff: float | None
) -> np.ndarray:
    """COLOR: sRGB channels Lanczos-filtered in linear light, alpha as linear coverage.

    Per channel: ``(H, W)`` uint8 -> decode table -> float32 linear -> Lanczos -> clip to
    [0, 1] -> sRGB encode (:func:`geoscaler.color.linear_to_srgb`) -> ``round(255 x)``.
    """
    channels = pixels.shape[2]
    colours = channels - 1 if channels in (2, 4) else channels
    result = np.empty((*size, channels), np.uint8)
    for c in range(colours):
        bands = _decoded_bands(pixels[..., c], _SRGB_DECODE)
        (linear,) = _separable(bands, len(pixels), size, Image.Resampling.LANCZOS)
        encoded = linear_to_srgb(torch.from_numpy(linear)).numpy()
        result[..., c] = _to_uint8(encoded)
    if colours < channels:
        result[..., -1] = resize_alpha(pixels[..., -1], size, alpha_cutoff)
    return result


def resize_alpha(
    alpha: np.ndarray, size: tuple[int, int], alpha_cutoff: float | None
) -> np.ndarray:
    """``(H, W)`` uint8 alpha -> ``(h, w)`` uint8: Lanczos on ``alpha / 255`` in float32,
    clipped to [0, 1], then (with a cutoff) scaled to keep the coverage, then rounded."""
    bands = _decoded_bands(alpha, _UNIT)
    (filtered,) = _separable(bands, len(alpha), size, Image.Resampling.LANCZOS)
    filtered = np.clip(filtered, 0.0, 1.0)
    if alpha_cutoff is not None:
        first = _first_kept(alpha_cutoff)
        if 0 < first < 256:  # else every texel passes, or none can, whatever the scale
            threshold = (first - 0.5) / 255.0  # round(255 a) >= first  <=>  a >= threshold
            filtered *= _coverage_scale(filtered, alpha_coverage(alpha, alpha_cutoff), threshold)
    return _to_uint8(filtered)


def _first_kept(alpha_cutoff: float) -> int:
    """The smallest 8-bit alpha ``q`` with ``q / 255 >= alpha_cutoff`` (256 when none is)."""
    return int(np.count_nonzero(np.arange(256) / 255.0 < alpha_cutoff))


def _coverage_scale(alpha: np.ndarray, coverage: float, threshold: float) -> float:
    """The scale ``s >= 0`` such that ``s * alpha >= threshold`` for ``round(coverage n)`` of
    the ``n`` texels of ``alpha`` (``(h, w)`` float in [0, 1]).

    Castaño's coverage-preserving alpha ("Computing alpha mipmaps", 2010) searches ``s`` by
    bisection; the count is a step function of ``s`` that steps at ``threshold / alpha``, so
    the exact ``s`` is found directly here: rank the alphas, and put ``threshold / s`` halfway
    between the smallest alpha that must pass and the largest one that must not. Ties (texels
    of one alpha) pass or fail together, whichever count is closer; texels of alpha 0 never
    pass. With nothing to keep, ``s`` is 1 when nothing passes anyway, else it puts the
    largest alpha at half the threshold.
    """
    ranked = np.sort(alpha, axis=None)
    n = ranked.size
    keep = min(round(coverage * n), int(np.count_nonzero(ranked > 0)))
    if keep > 0:
        value = ranked[n - keep]
        above = n - int(np.searchsorted(ranked, value, "right"))
        with_ties = n - int(np.searchsorted(ranked, value, "left"))
        keep = above if keep - above < with_ties - keep else with_ties
    if keep == 0:
        return 1.0 if ranked[-1] < threshold else 0.5 * threshold / float(ranked[-1])
    dropped = float(ranked[n - keep - 1]) if keep < n else 0.0
    return threshold / (0.5 * (float(ranked[n - keep]) + dropped))


# ----------------------------------------------------------------------------- normals


def _resize_normal(pixels: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """NORMAL: mean of unit vectors, ``z`` clamped to >= 0, renormalised (``(0, 0, 1)`` where
    the mean vanishes), encoded ``round((n + 1) 255 / 2)``; a 4th channel as DATA."""
    mean = _mean_unit_normals(pixels, size)
    mean[..., 2] = np.maximum(mean[..., 2], 0.0)
    length = np.linalg.norm(mean, axis=-1, keepdims=True)
    flat = length[..., 0] < 1e-6
    mean[flat] = (0.0, 0.0, 1.0)
    length[flat] = 1.0
    encoded = _to_uint8((mean / length + 1.0) * 0.5)
    if pixels.shape[2] == 3:
        return encoded
    extra = resize_channels(pixels[..., 3:], size, Image.Resampling.LANCZOS)
    return np.concatenate([encoded, extra], axis=-1)


def _mean_unit_normals(pixels: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``(h, w, 3)`` float32: the BOX mean of the texels' unit vectors over each footprint.

    Each texel's ``2 v / 255 - 1`` is divided by its length (never 0: no 8-bit triple decodes
    to the zero vector), a band of rows at a time; x, y and z are filtered as float32 planes.
    """
    means = _separable(_unit_vector_bands(pixels), len(pixels), size, Image.Resampling.BOX)
    return np.stack(means, axis=-1)


def _unit_vector_bands(pixels: np.ndarray) -> Iterator[tuple[np.ndarray, ...]]:
    """``(H, W, C)`` uint8 normal map as bands of three ``(b, W)`` float32 planes: the x, y
    and z of the texels' unit vectors."""
    for top in range(0, len(pixels), _BAND):
        vectors = np.take(_SNORM_DECODE, pixels[top : top + _BAND, :, :3])
        vectors /= np.sqrt(np.einsum("...c,...c->...", vectors, vectors))[..., None]
        yield tuple(np.ascontiguousarray(vectors[..., c]) for c in range(3))
