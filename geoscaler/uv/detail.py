"""The detail each chart's texels lose at the output size: what a plan spends texels on.

A chart of flat colour loses nothing when it gets fewer texels; a chart of fine print loses
the most. :func:`lost_detail` measures, per face, the variance of the original's texels one
octave finer than the output within each output texel (what a box filter to the output size
discards of that octave: the detail one more octave of texels would keep), over the texels
inside the charts only (a texel on a chart's border averages the gutter beside it, whose
contrast is no detail of the chart). :func:`~geoscaler.uv.atlas.planned_scales` weighs each
chart's screen samples by it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from PIL.Image import Resampling

from geoscaler.mesh import TexturedMesh
from geoscaler.resize.filters import resize_float
from geoscaler.uv.packing import chart_texels


@dataclass(frozen=True)
class LostDetail:
    """Per face the detail its texels lose at the output size (:func:`lost_detail`).

    Attributes:
        energy: ``(F,)`` float64 sum over the face's interior output texels of the variance
            of the original's texels one octave finer within each (sRGB in [0, 1], summed
            over the colour channels).
        texels: ``(F,)`` float64 interior output texels of each face (0: none, or no map).
    """

    energy: np.ndarray
    texels: np.ndarray

    def per_chart(self, charts: np.ndarray, count: int) -> np.ndarray:
        """``(count,)`` mean lost detail per interior texel of each chart of ``(F,)`` labels
        ``charts``; a chart without interior texels gets the median of the charts with some.
        Every chart 1.0 where none has interior texels or none loses anything (nothing
        measured, or a texture that keeps all its detail: no chart weighs more)."""
        texels = np.bincount(charts, self.texels, count)
        measured = texels > 0
        mean = np.bincount(charts, self.energy, count) / np.maximum(texels, 1.0)
        if not (mean[measured] > 0).any():
            return np.ones(count)
        return np.where(measured, mean, float(np.median(mean[measured])))


def lost_detail(
    mesh: TexturedMesh,
    references: Sequence[np.ndarray | None],
    sizes: Sequence[tuple[int, int] | None],
) -> LostDetail:
    """The detail each face's texels lose at its material's output size: ``references`` are
    per material the original's ``(H, W, C)`` uint8 sRGB base colour (None: no map),
    ``sizes`` the output ``(h, w)`` (None: untextured); a material whose output is not square
    is not measured (no new layout packs it)."""
    count = len(mesh.faces)
    energy, texels = np.zeros(count), np.zeros(count)
    corners = mesh.corner_uvs().astype(np.float64)
    for material, (reference, size) in enumerate(zip(references, sizes, strict=True)):
        if reference is None or size is None or size[0] != size[1]:
            continue
        faces = np.flatnonzero(mesh.face_material == material)
        variance = block_variance(reference, size).ravel()
        texel, face = interior_texels(corners[faces], size[0])
        energy[faces] = np.bincount(face, variance[texel], len(faces))
        texels[faces] = np.bincount(face, minlength=len(faces))
    return LostDetail(energy, texels)


def block_variance(reference: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``(h, w)`` float64 variance, summed over the colour channels (alpha left out), of
    ``reference``'s ``(H, W, C)`` uint8 sRGB texels one octave finer than ``size = (h, w)``
    (at most its own) within each output texel: the box filter's mean of squares less its
    squared mean. One channel at a time, so that at most one plane of a large original is
    held in float."""
    finer = (min(reference.shape[0], 2 * size[0]), min(reference.shape[1], 2 * size[1]))
    variance = np.zeros(size)
    colours = 1 if reference.shape[2] <= 2 else 3  # grey (+ alpha) or RGB (+ alpha)
    for channel in range(colours):
        plane = reference[..., channel : channel + 1].astype(np.float32) / 255.0
        fine = resize_float(plane, finer, Resampling.BOX)
        del plane
        mean = resize_float(fine, size, Resampling.BOX)[..., 0].astype(np.float64)
        squares = resize_float(fine * fine, size, Resampling.BOX)[..., 0].astype(np.float64)
        variance += np.maximum(squares - mean * mean, 0.0)
    return variance


def interior_texels(corner_uvs: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``((N,) flat texel, (N,) face)`` pairs of the texels of a ``size x size`` grid that
    faces of ``(F, 3, 2)`` ``corner_uvs`` cover (:func:`~geoscaler.uv.packing.chart_texels`,
    one sample a texel) whose eight neighbours are covered too (by any face)."""
    from scipy.ndimage import binary_erosion

    texel, face = chart_texels(corner_uvs, np.arange(len(corner_uvs)), size, supersample=1)
    covered = np.zeros(size * size, bool)
    covered[texel] = True
    inner = binary_erosion(covered.reshape(size, size), np.ones((3, 3), bool)).ravel()
    keep = inner[texel]
    return texel[keep], face[keep]
