"""Baking a texture into a new UV layout of the same mesh.

Every texel of the new texture is the average of ``supersample x supersample`` samples, each
the original texture looked up where the chart's map sends the sample back in the old layout
(the charts moved by similarities, :mod:`geoscaler.uv.atlas`), filtered as a GPU does
(:meth:`geoscaler.render.texture.MipTexture.sample`: trilinear, its level of detail
from how far one sample moves in the old texture): an area filter over the original's texels,
read from its 8-bit texels (:class:`~geoscaler.render.texture.EncodedMipTexture`: no float copy of a
large map at full size).
Values are filtered as what they hold (:mod:`geoscaler.resize.maps`'s classes): colour in linear
light (alpha linear), tangent-space normals as vectors renormalised afterwards, data per
channel. Texels no face covers (gutters) read the original through their nearest chart's map,
so that mip levels and bilinear taps around a chart see what they saw around it in the
original.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from PIL import Image

from geoscaler.color import linear_to_srgb, srgb_to_linear
from geoscaler.render.encoded import Decoding, EncodedMipTexture, decode_codes
from geoscaler.render.raster import rasterize
from geoscaler.render.texture import UVFootprint
from geoscaler.resize.filters import resize_float
from geoscaler.resize.maps import resize_map
from geoscaler.resize.sizes import COLOR, NORMAL

BAKE_SAMPLES = 1 << 20
"""Samples of a bake read from the original at once: a 4096 x 4096 bake (1024 texels at 4
samples a side) read in one piece held several GB of coordinates and taps."""
BAKE_SECONDS_PER_SAMPLE = 0.5e-6
"""An upper bound on :func:`bake`'s seconds per sample of its ``size * oversample`` grid on an
idle machine: 0.3 to 0.5 microseconds on the 2-core AMD dev machine (the normal and
metallic-roughness maps of two 1024 Poly Haven assets baked into a new layout at 256 and 128
texels, 4 samples a side; the base colours of six development meshes at 4x, 1 to 16.8 M
samples, 0.31 to 0.40)."""


def decode(pixels: np.ndarray, kind: str) -> torch.Tensor:
    """``(H, W, C)`` uint8 map to ``(H, W, C)`` float32 values that filter linearly
    (:func:`decoding`)."""
    return decode_codes(pixels, decoding(kind, pixels.shape[2]))


def decoding(kind: str, channels: int) -> Decoding:
    """How a map of class ``kind`` with ``channels`` channels is read: per channel the float32
    value of each 8-bit code ``v``: COLOR's colour channels (all but a last alpha of 2 or 4
    channels) decoded from sRGB, NORMAL's first three as vectors ``2 v / 255 - 1``, everything
    else ``v / 255``."""
    values = (torch.arange(256, dtype=torch.float32) / 255.0)[:, None].repeat(1, channels)
    if kind == COLOR:
        colour = channels - 1 if channels in (2, 4) else channels
        values[:, :colour] = srgb_to_linear(values[:, :colour])
    elif kind == NORMAL and channels >= 3:
        values[:, :3] = values[:, :3] * 2.0 - 1.0
    return [(channel, values[:, channel].numpy()) for channel in range(channels)]


def encode(values: torch.Tensor, kind: str) -> np.ndarray:
    """The inverse of :func:`decode`, to ``(h, w, C)`` uint8; normals are renormalised first
    (a texel with no direction left points along +z)."""
    return stored(values, kind).mul(255.0).round().to(torch.uint8).numpy()


def stored(values: torch.Tensor, kind: str) -> torch.Tensor:
    """:func:`encode` before its rounding: ``(h, w, C)`` float32 in [0, 1]."""
    values = values.clone()
    channels = values.shape[2]
    if kind == COLOR:
        colour = channels - 1 if channels in (2, 4) else channels
        values[..., :colour] = linear_to_srgb(values[..., :colour])
    elif kind == NORMAL and channels >= 3:
        vectors = values[..., :3]
        length = vectors.norm(dim=-1, keepdim=True)
        up = torch.tensor([0.0, 0.0, 1.0]).expand_as(vectors)
        vectors = torch.where(length > 1e-6, vectors / length.clamp_min(1e-6), up)
        values[..., :3] = (vectors + 1.0) / 2.0
    return values.clamp(0.0, 1.0)


def bake(
    pixels: np.ndarray,
    kind: str,
    layout: ChartMaps,
    size: int,
    oversample: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Bake a map into a new layout whose charts moved by known maps.

    Each sample (texel centre of the ``size * oversample`` grid) in a chart, or outside every
    chart (its nearest), reads the original where the chart's map sends it back: the
    original's own texels there, around a chart too, so a bilinear or coarser lookup at a
    chart's rim sees what it saw in the original (its gutters, black on a scan, darken the
    coarse levels the far views read). With ``oversample > 1`` the bake is then resized to
    ``size``: colour with Pillow's Lanczos on its stored sRGB values, as the ``lanczos``
    baseline but in float (rounded to 8 bits once), other classes by
    :func:`geoscaler.resize.maps.resize_map`: the protocol scores sRGB images, and filtering in
    linear light softens edges (``benchmarks/far_views.py``; see docs/decisions/bake-filtering.md).

    Args:
        pixels: ``(H, W, C)`` uint8 map in the old layout (repeat addressing).
        kind: its class (``COLOR``, ``NORMAL`` or ``DATA``, :mod:`geoscaler.resize.sizes`).
        layout: the faces in the new layout and each chart's map.
        size: texels per side of the new map.
        oversample: samples per side of each texel.

    Returns:
        ``((size, size, C) uint8 map, (size, size) bool texels some face covers)``.
    """
    texture = EncodedMipTexture(pixels, decoding=decoding(kind, pixels.shape[2]))
    grid = size * oversample
    labels, covered = _nearest_chart(layout, grid)
    inverses = torch.linalg.inv(torch.from_numpy(layout.linear))  # (C, 2, 2)
    offsets = torch.from_numpy(layout.offset)
    values = torch.zeros(grid * grid, texture.channels)
    for sample in torch.split(torch.nonzero(labels.view(-1) >= 0).squeeze(1), BAKE_SAMPLES):
        chart = labels.view(-1)[sample]
        footprint = _footprint_back(sample, inverses[chart], offsets[chart], grid)
        values[sample] = texture.sample(footprint).T
    values = values.view(grid, grid, -1)
    if oversample > 1 and kind == COLOR:  # Lanczos on the sRGB values, as the baseline,
        values = stored(values, kind).numpy()  # in float: rounded to 8 bits once
        values = resize_float(values, (size, size), Image.Resampling.LANCZOS)
        baked = (np.clip(values, 0.0, 1.0) * 255.0).round().astype(np.uint8)
    elif oversample > 1:
        baked = resize_map(encode(values, kind), (size, size), kind)
    else:
        baked = encode(values, kind)
    texel_covered = covered.view(size, oversample, size, oversample).any(3).any(1)
    return baked, texel_covered.numpy()


def _footprint_back(
    sample: torch.Tensor, inverse: torch.Tensor, offset: torch.Tensor, grid: int
) -> UVFootprint:
    """Where the ``(N,)`` samples (flat indices on the ``grid x grid`` bake) read the original:
    each through its chart's ``(N, 2, 2)`` inverse map and ``(N, 2)`` offset."""
    x = (sample % grid).double() + 0.5
    y = (sample // grid).double() + 0.5
    new = torch.stack([x / grid, 1.0 - y / grid], dim=1) - offset
    old = torch.einsum("nij,nj->ni", inverse, new).float()
    step_x = (inverse[:, :, 0] / grid).float()
    step_y = (-inverse[:, :, 1] / grid).float()
    return UVFootprint(old[:, 0], old[:, 1], *step_x.T, *step_y.T)


@dataclass
class ChartMaps:
    """Faces in a new layout and the maps that moved their charts there.

    Attributes:
        corners: ``(F, 3, 2)`` new UVs in [0, 1] (v up) of the corners of the faces to bake.
        face_chart: ``(F,)`` int64 chart of each face.
        linear, offset: ``(C, 2, 2)`` and ``(C, 2)`` float64, ``new = linear @ old + offset``.
    """

    corners: np.ndarray
    face_chart: np.ndarray
    linear: np.ndarray
    offset: np.ndarray


def _nearest_chart(layout: ChartMaps, grid: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``((grid, grid) int64 chart of each sample, -1 where no face covers any; (grid, grid)
    bool samples a face covers)``: a sample no face covers takes its nearest covered
    sample's chart. (scipy.ndimage is imported here: a job imports it only where it bakes.)"""
    from scipy.ndimage import distance_transform_edt

    corners = torch.from_numpy(np.asarray(layout.corners, np.float64)).reshape(-1, 2)
    depth = torch.zeros(len(corners), 1)
    clip = torch.cat([corners * 2 - 1, depth, torch.ones_like(depth)], dim=1)
    gbuffer = rasterize(clip, torch.arange(len(clip)).view(-1, 3), grid)
    labels = np.full(grid * grid, -1, np.int64)
    labels[gbuffer.pixels.long().numpy()] = layout.face_chart[gbuffer.tri_ids.long().numpy()]
    labels = labels.reshape(grid, grid)
    covered = labels >= 0
    if covered.any():
        rows, cols = distance_transform_edt(~covered, return_distances=False, return_indices=True)
        labels = labels[rows, cols]
    return torch.from_numpy(labels), torch.from_numpy(covered)
