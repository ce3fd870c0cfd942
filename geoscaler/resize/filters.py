"""Baseline texture downsamplers of the evaluation protocol (PROTOCOL.md, protocol 1).

A texture is an ``(H, W, C)`` uint8 array of stored (sRGB) values, row 0 at the top, ``C`` in
1..4 (grey, grey+alpha, RGB, RGBA). Every method keeps the channel count and works on each
channel independently, alpha included and never premultiplied, so colour under transparent
texels survives. Each returns an ``(h, w, C)`` uint8 array with ``(h, w) = target_size(H, W,
scale)``:

- ``box``, ``bicubic``, ``lanczos``: Pillow's ``Image.BOX``, ``BICUBIC`` and ``LANCZOS``
  resamplers on the texture as stored, as users resize textures today.
- ``pbd``: Perceptually Based Downscaling (Oztireli and Gross 2015), closed form, 2 x 2
  patches (see :func:`pbd`).
"""

from __future__ import annotations

import os
import threading
import weakref
from collections.abc import Callable, Hashable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh, check_texture
from geoscaler.protocol import REFERENCE_MAX_SIZE
from geoscaler.resize.sizes import SizeRule, check_scale, round_ratio

PBD_PATCH = 2
"""Side of PBD's square patches, in low-resolution pixels."""
PBD_MIN_VARIANCE = 1e-6
"""Patch variance of the box-downscaled image (values in [0, 1]) below which PBD's
contrast ratio is 0 and the patch contributes its plain mean."""

__all__ = [
    "BASELINES",
    "bicubic",
    "box",
    "check_scale",
    "downsample_texture",
    "lanczos",
    "pbd",
    "output_sizes",
    "reference_size",
    "reference_texture",
    "reference_textures",
    "resize_channels",
    "target_size",
]


def target_size(height: int, width: int, scale: int) -> tuple[int, int]:
    """Size of a texture downsampled by ``scale``: each side divided, rounded to whole texels.

    ``h = round(height / scale)``, ``w = round(width / scale)``, halves rounded up (1000 x 750 at 8
    -> 125 x 94): :meth:`geoscaler.resize.sizes.SizeRule.size` with the scale alone.

    Raises:
        GeoscalerError: ``scale`` is not a whole number >= 2 (bools and floats such as 4.0
            count as not whole numbers) or is larger than the texture's shorter side.
    """
    return SizeRule(scale=check_scale(scale)).size(height, width)


def _size_of(texture: np.ndarray, target: int | tuple[int, int]) -> tuple[int, int]:
    """The output size for a scale (``int``) or an explicit ``(h, w)`` no larger than the
    texture."""
    height, width = texture.shape[:2]
    if isinstance(target, tuple):
        h, w = (int(side) for side in target)
        if not (1 <= h <= height and 1 <= w <= width):
            raise GeoscalerError(
                f"size {h} x {w}: a {height} x {width} texture is only made smaller, to at "
                "least 1 x 1"
            )
        return h, w
    return target_size(height, width, target)


PARALLEL_TEXELS = 1 << 20
"""Texels from which :func:`resize_channels` and :func:`resize_float` resize the channels on
threads at once."""

_CHANNELS = (1, 2, 3, 4)
"""Channel counts the filters accept (grey, grey+alpha, RGB, RGBA); checked by
:func:`geoscaler.mesh.check_texture`, which raises a GeoscalerError."""


def resize_channels(
    texture: np.ndarray, size: tuple[int, int], resample: Image.Resampling
) -> np.ndarray:
    """Resize ``(H, W, C)`` uint8 to ``size = (h, w)`` with a Pillow filter, channel by channel.

    Each channel is resampled as its own 8-bit 'L' image: for RGB this is bit-identical to
    resizing the RGB image, and for alpha it avoids Pillow's RGBA path, which premultiplies
    colour by alpha (and so loses colour under transparent texels). Channels of a texture of
    :data:`PARALLEL_TEXELS` or more are resized on threads at once (on two cores a 4096 x 4096
    RGB texture's bicubic and Lanczos resizes took 0.28 to 0.32 s instead of 0.51 to 0.61 s).
    """
    planes = [np.ascontiguousarray(texture[..., c]) for c in range(texture.shape[2])]
    return np.stack(_resized_planes(planes, size, resample), axis=-1)


def resize_float(
    values: np.ndarray, size: tuple[int, int], resample: Image.Resampling
) -> np.ndarray:
    """Resize ``(H, W, C)`` float32 to ``size = (h, w)`` with a Pillow filter, channel by
    channel as 32-bit float ('F') images: the filter of :func:`resize_channels` without its
    8-bit input and output, for values quantised once, afterwards (a bake's chart colours);
    large planes on threads at once, as there."""
    planes = [np.ascontiguousarray(values[..., c], np.float32) for c in range(values.shape[2])]
    return np.stack(_resized_planes(planes, size, resample), axis=-1)


def _resized_planes(
    planes: list[np.ndarray], size: tuple[int, int], resample: Image.Resampling
) -> list[np.ndarray]:
    """Each ``(H, W)`` plane (uint8 or float32) resized to ``size = (h, w)`` by Pillow; planes
    of :data:`PARALLEL_TEXELS` or more on threads at once (Pillow resizes without holding the
    GIL)."""
    h, w = size

    def resized(plane: np.ndarray) -> np.ndarray:
        return np.asarray(Image.fromarray(plane).resize((w, h), resample))

    workers = min(len(planes), os.cpu_count() or 1)
    if workers < 2 or planes[0].size < PARALLEL_TEXELS:
        return [resized(plane) for plane in planes]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(resized, planes))


def _resample(
    texture: np.ndarray, target: int | tuple[int, int], resample: Image.Resampling
) -> np.ndarray:
    """Validate, then resize ``texture`` to ``target`` (a scale or a size) with a Pillow
    filter; a texture resized the same way before is not resized again (a job's Lanczos
    filter and ``direct``'s start resize the same original: 0.3 s each at 4096 x 4096)."""
    check_texture(texture, channels=_CHANNELS)
    size = _size_of(texture, target)
    resized = _RESIZED.get(texture, (size, resample))
    if resized is None:
        resized = _RESIZED.put(texture, (size, resample), resize_channels(texture, size, resample))
    return resized.copy()  # the caller's to change


def box(texture: np.ndarray, scale: int | tuple[int, int]) -> np.ndarray:
    """Area average (Pillow ``Image.BOX``): ``(H, W, C)`` uint8 -> ``(h, w, C)`` uint8.

    For sides divisible by ``scale`` each output texel is the mean of its ``scale x scale``
    block; otherwise Pillow averages the texels whose centres fall in the output texel's
    footprint.
    """
    return _resample(texture, scale, Image.Resampling.BOX)


def bicubic(texture: np.ndarray, scale: int | tuple[int, int]) -> np.ndarray:
    """Pillow ``Image.BICUBIC``: ``(H, W, C)`` uint8 -> ``(h, w, C)`` uint8."""
    return _resample(texture, scale, Image.Resampling.BICUBIC)


def lanczos(texture: np.ndarray, scale: int | tuple[int, int]) -> np.ndarray:
    """Pillow ``Image.LANCZOS``: ``(H, W, C)`` uint8 -> ``(h, w, C)`` uint8."""
    return _resample(texture, scale, Image.Resampling.LANCZOS)


def _box_weights(in_size: int, out_size: int) -> sp.csr_matrix:
    """``(out_size, in_size)`` sparse matrix of Pillow's BOX filter weights along one axis.

    Output texel ``j`` covers ``[j r, (j + 1) r)`` of the input, ``r = in_size / out_size``;
    it averages, with equal weights, the input texels whose centres ``i + 0.5`` lie in
    ``(j r, (j + 1) r]``, the texels Pillow's BOX filter weights. For a divisible size this is
    the plain mean of the ``r`` texels of the block.
    """
    ratio = in_size / out_size
    rows, cols = [], []
    for j in range(out_size):
        centre = (j + 0.5) * ratio
        first = max(int(centre - 0.5 * ratio + 0.5), 0)
        last = min(int(centre + 0.5 * ratio + 0.5), in_size)
        inside = [i for i in range(first, last) if -0.5 < (i - centre + 0.5) / ratio <= 0.5]
        rows += [j] * len(inside)
        cols += inside
    counts = np.bincount(rows, minlength=out_size).astype(np.float64)
    weights = 1.0 / counts[rows]
    return sp.csr_matrix((weights, (rows, cols)), shape=(out_size, in_size))


def _box_float(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Box-downscale ``(H, W, C)`` float64 to ``(h, w, C)`` with Pillow's BOX weights, exactly.

    Separable: ``out[:, :, c] = A_h @ image[:, :, c] @ A_w.T`` with the sparse
    :func:`_box_weights` matrices, all channels at once, no 8-bit rounding.
    """
    height, width, channels = image.shape
    h, w = size
    rows = _box_weights(height, h) @ image.reshape(height, width * channels)
    rows = rows.reshape(h, width, channels).transpose(1, 0, 2).reshape(width, h * channels)
    cols = _box_weights(width, w) @ rows
    return cols.reshape(w, h, channels).transpose(1, 0, 2)


def _patch_mean(x: np.ndarray, patch: tuple[int, int]) -> np.ndarray:
    """'Valid' correlation with the averaging patch: ``(h, w, C)`` -> ``(h-ph+1, w-pw+1, C)``."""
    ph, pw = patch
    h, w = x.shape[0] - ph + 1, x.shape[1] - pw + 1
    return sum(x[dy : dy + h, dx : dx + w] for dy in range(ph) for dx in range(pw)) / (ph * pw)


def _patch_sum_full(x: np.ndarray, patch: tuple[int, int]) -> np.ndarray:
    """'Full' correlation with a patch of ones: ``(h-ph+1, w-pw+1, C)`` -> ``(h, w, C)``.

    Output pixel ``(y, x)`` sums the values of every patch that covers low-res pixel
    ``(y, x)``: the adjoint of :func:`_patch_mean` (up to its ``1 / (ph pw)``).
    """
    ph, pw = patch
    padded = np.pad(x, ((ph - 1, ph - 1), (pw - 1, pw - 1), (0, 0)))
    h, w = x.shape[0] + ph - 1, x.shape[1] + pw - 1
    return sum(padded[dy : dy + h, dx : dx + w] for dy in range(ph) for dx in range(pw))


def _pbd_float(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """PBD's closed form on ``(H, W, C)`` float64 values in [0, 1] -> ``(h, w, C)`` float64.

    Algorithm 1 of the paper, per channel, patches ``p x p`` (``p = PBD_PATCH``, or the
    output side when that is smaller)::

        L  = box(H), L2 = box(H^2)                     # (h, w): mean and mean square
        M  = mean_p(L)                                 # (h-p+1, w-p+1) patch means
        Sl = mean_p(L^2) - M^2                         # patch variance of L
        Sh = mean_p(L2) - M^2                          # variance of H within the patch
        R  = sqrt(Sh / Sl) where Sl > 1e-6, else 0     # contrast ratio
        D  = sum_k (M_k + R_k (L - M_k)) / count       # over the patches k covering a pixel

    i.e. ``D = (full(M) + full(R) L - full(R M)) / full(1)`` with ``full`` the 'full'
    correlation with a ``p x p`` patch of ones. Every patch of ``D`` then has the mean and
    (for a single patch, exactly) the variance of the high-resolution texels it covers.
    """
    patch = (min(PBD_PATCH, size[0]), min(PBD_PATCH, size[1]))
    low = _box_float(image, size)
    low_sq = _box_float(image * image, size)
    mean = _patch_mean(low, patch)
    var_low = _patch_mean(low * low, patch) - mean * mean
    var_high = np.maximum(_patch_mean(low_sq, patch) - mean * mean, 0.0)
    ratio = np.zeros_like(mean)
    flat = var_low <= PBD_MIN_VARIANCE
    np.sqrt(var_high / np.where(flat, 1.0, var_low), out=ratio, where=~flat)
    count = _patch_sum_full(np.ones_like(mean), patch)
    total = (
        _patch_sum_full(mean, patch)
        + _patch_sum_full(ratio, patch) * low
        - _patch_sum_full(ratio * mean, patch)
    )
    return total / count


def pbd(texture: np.ndarray, scale: int | tuple[int, int]) -> np.ndarray:
    """Perceptually Based Downscaling: ``(H, W, C)`` uint8 -> ``(h, w, C)`` uint8.

    A. C. Oztireli and M. Gross, "Perceptually Based Downscaling of Images", ACM Transactions
    on Graphics 34(4), 2015: the closed form with 2 x 2 patches (:func:`_pbd_float`). Each
    2 x 2 patch of the result keeps the mean and the local contrast (variance) of the texels
    it replaces, so it is sharper than ``box``.

    Works on the stored (sRGB) values like the other baselines, each channel (alpha included)
    on its own, in float64 on values scaled to [0, 1]; the result is clipped to [0, 1] and
    rounded half up to 8 bits.

    Sizes that ``scale`` does not divide: ``L`` and ``L2`` are computed directly at
    ``target_size`` with Pillow's BOX weights (:func:`_box_weights`, in float64), so ``L`` is
    always the ``box`` baseline before its 8-bit rounding. As a consequence a constant
    texture gives that constant, and a texture made of constant ``scale x scale`` blocks gives
    exactly ``box``'s result.

    Patent notice: PBD is covered by US patent 10,325,346. It is
    provided only as a baseline for comparison; check the patent before using it in a
    product.
    """
    check_texture(texture, channels=_CHANNELS)
    size = _size_of(texture, scale)
    result = _pbd_float(texture.astype(np.float64) / 255.0, size)
    return np.floor(np.clip(result, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


BASELINES: dict[str, Callable[[np.ndarray, int | tuple[int, int]], np.ndarray]] = {
    "box": box,
    "bicubic": bicubic,
    "lanczos": lanczos,
    "pbd": pbd,
}
"""Baseline name -> ``fn(texture, scale or (h, w)) -> downsampled texture``."""


def downsample_texture(texture: np.ndarray, scale: int, method: str) -> np.ndarray:
    """Downsample ``(H, W, C)`` uint8 by ``scale`` with the baseline ``method``.

    Returns:
        ``(h, w, C)`` uint8, ``(h, w) = target_size(H, W, scale)``.

    Raises:
        GeoscalerError: unknown ``method`` (the message lists the known ones), invalid
            ``scale`` or texture.
    """
    if method not in BASELINES:
        raise GeoscalerError(
            f"unknown downsampling method {method!r}: choose one of {', '.join(BASELINES)}"
        )
    return BASELINES[method](texture, scale)


class _Resized:
    """The last ``size`` resized arrays, by original (an array not changed in place) and how
    it was resized. An entry goes when its original is freed, so it is never mistaken for a
    later array at the same id, and holds no memory for an asset that is done."""

    def __init__(self, size: int = 8):
        self.size = size
        self.entries: dict[tuple[int, Hashable], tuple[weakref.ref, np.ndarray]] = {}
        # the app resizes on its worker and window threads; reentrant, since a collection
        # inside put() may free an original and call _forget on the same thread
        self.lock = threading.RLock()

    def get(self, original: np.ndarray, how: Hashable) -> np.ndarray | None:
        with self.lock:
            entry = self.entries.get((id(original), how))
        return entry[1] if entry is not None and entry[0]() is original else None

    def put(self, original: np.ndarray, how: Hashable, resized: np.ndarray) -> np.ndarray:
        resized.flags.writeable = False  # shared by every caller
        key = (id(original), how)
        with self.lock:
            for oldest in list(self.entries)[: max(0, len(self.entries) - self.size + 1)]:
                self.entries.pop(oldest, None)
            self.entries[key] = (weakref.ref(original, lambda _: self._forget(key)), resized)
        return resized

    def _forget(self, key: tuple[int, Hashable]) -> None:
        with self.lock:
            self.entries.pop(key, None)


_RESIZED = _Resized()
"""The Pillow filters' results (:func:`_resample`)."""
_REFERENCES = _Resized()
"""Reduced reference maps: a 4096 x 4096 original takes about 0.5 s to reduce, and a job asks
for its reference from each filter, the method and the renderer."""


def reference_texture(texture: np.ndarray, max_size: int = REFERENCE_MAX_SIZE) -> np.ndarray:
    """The protocol's reference map: an original reduced to ``max_size`` on its longer side.

    A texture whose longer side exceeds ``max_size`` is resized with Pillow ``LANCZOS``
    (channel by channel, as the baselines) so that its longer side is ``max_size`` and its
    shorter side ``round(short * max_size / long)`` (half up, at least 1): the aspect ratio
    is kept. Any other texture is returned as is (the same array, not a copy). A reduced map
    is made once per original and shared, read-only.

    Args:
        texture: ``(H, W, C)`` uint8.
        max_size: the longest side allowed, >= 1.

    Returns:
        ``(H', W', C)`` uint8 with ``max(H', W') <= max_size``.
    """
    check_texture(texture, channels=_CHANNELS)
    if max_size < 1:
        raise GeoscalerError(f"max_size {max_size}: must be at least 1 texel")
    size = reference_size(*texture.shape[:2], max_size)
    if size == texture.shape[:2]:
        return texture
    reduced = _REFERENCES.get(texture, max_size)
    if reduced is None:
        reduced = resize_channels(texture, size, Image.Resampling.LANCZOS)
        reduced = _REFERENCES.put(texture, max_size, reduced)
    return reduced


def reference_size(height: int, width: int, max_size: int = REFERENCE_MAX_SIZE) -> tuple[int, int]:
    """``(h, w)`` of the reference map of a ``height x width`` original (see
    :func:`reference_texture`): the original's size, or its aspect ratio at ``max_size``."""
    longer = max(height, width)
    if longer <= max_size:
        return height, width
    return (
        max(round_ratio(height * max_size, longer), 1),
        max(round_ratio(width * max_size, longer), 1),
    )


def reference_textures(
    mesh: TexturedMesh, max_size: int | None = REFERENCE_MAX_SIZE
) -> list[np.ndarray | None]:
    """The reference map of every material's base colour (None where untextured): the one
    definition of "the reference textures" that methods, scores and the app use.

    ``max_size``: the protocol's cap (:data:`REFERENCE_MAX_SIZE`) for evaluation; None for
    the product, which optimises against the full-resolution originals. Materials showing one
    image share one reference array (reduced once)."""
    reduced: dict[int, np.ndarray] = {}
    for material in mesh.materials:
        image = material.base_color_texture
        if image is not None and id(image) not in reduced:
            reduced[id(image)] = image if max_size is None else reference_texture(image, max_size)
    return [
        None if m.base_color_texture is None else reduced[id(m.base_color_texture)]
        for m in mesh.materials
    ]


def output_sizes(
    mesh: TexturedMesh,
    rule: int | SizeRule,
    max_size: int | None = REFERENCE_MAX_SIZE,
) -> list[tuple[int, int] | None]:
    """Per material the ``(h, w)`` its base-colour map ships at (None where untextured):
    ``rule`` (a scale, or a :class:`~geoscaler.resize.sizes.SizeRule`) applied to the reference map
    of ``max_size`` (:func:`reference_textures`). The size every method returns.

    Raises:
        GeoscalerError: the scale is too large for a texture (the message names the material).
    """
    rule = rule if isinstance(rule, SizeRule) else SizeRule(scale=check_scale(rule))
    sizes: list[tuple[int, int] | None] = []
    for material in mesh.materials:
        texture = material.base_color_texture
        if texture is None:
            sizes.append(None)
            continue
        height, width = texture.shape[:2]
        if max_size is not None:
            height, width = reference_size(height, width, max_size)
        try:
            sizes.append(rule.size(height, width))
        except GeoscalerError as error:
            raise GeoscalerError(f"material {material.name!r}: {error}") from None
    return sizes
