"""UVWarper: a content-aware warp of the texture plane, applied to features and UVs alike.

A small head predicts an offset per texel of the output texture. The texel at ``x`` then shows
the content at ``x + o(x)`` (the remaining features are resampled there), and every vertex's UV
moves by the inverse of that map to first order, ``U' = U - o(U)``, so the surface still finds
its content: regions the warp stretches get more texels.

Guards (PROTOCOL: UVs must stay valid):

* offsets are at most :data:`MAX_OFFSET` texels per axis and zero on the texture's border
  ring. Bilinearly interpolated, ``o`` then changes by at most ``2 MAX_OFFSET`` per texel
  along each axis, so its Jacobian's Frobenius norm is below ``sqrt(4 (2 MAX_OFFSET)^2) = 0.8
  < 1``: ``U -> U - o(U)`` is one-to-one (no fold-over anywhere) and maps ``[0, 1]^2`` into
  itself (the border stays put);
* faces are linear between their corners, so a sliver face can still flip even under such a
  map: :func:`fold_free_factor` scales the whole warp down until no face changes orientation.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from geoscaler.nn.convolutional import conv3x3
from geoscaler.nn.geocoding import bilinear, sample_at_uvs

MAX_OFFSET = 0.2  # texels


class UVWarper(nn.Module):
    """Split features into a warp slice and the rest; predict offsets, warp the rest.

    Args:
        channels: input feature channels ``C``.
        warp_channels: the first ``warp_channels`` feed the offset head; the other
            ``C - warp_channels`` are warped and passed on.
    """

    def __init__(self, channels: int, warp_channels: int = 16):
        super().__init__()
        if not 0 < warp_channels < channels:
            raise ValueError(f"warp_channels must be in (0, {channels}), got {warp_channels}")
        self.warp_channels = warp_channels
        self.head = nn.Sequential(conv3x3(warp_channels, warp_channels), nn.ReLU())
        self.to_offset = conv3x3(warp_channels, 2)
        nn.init.zeros_(self.to_offset.weight)  # start at the identity warp
        nn.init.zeros_(self.to_offset.bias)

    def offsets(self, features: torch.Tensor) -> torch.Tensor:
        """``(2, h, w)`` offsets in texels (x right, y down) from ``(C, h, w)`` features."""
        raw = self.to_offset(self.head(features[None, : self.warp_channels]))[0]
        return bounded_offsets(raw)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(C, h, w)`` features to ``(offsets (2, h, w), warped rest (C - k, h, w))``."""
        offsets = self.offsets(features)
        return offsets, warp_plane(features[self.warp_channels :], offsets)


def bounded_offsets(raw: torch.Tensor) -> torch.Tensor:
    """``MAX_OFFSET tanh(raw)``, zeroed on the border ring of texels. ``(2, h, w)``."""
    offsets = MAX_OFFSET * torch.tanh(raw)
    return F.pad(offsets[:, 1:-1, 1:-1], (1, 1, 1, 1))


def warp_plane(plane: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """Resample ``(C, h, w)`` so that texel ``x`` shows ``plane`` at ``x + offsets(x)``.

    Zero offsets return ``plane`` exactly (samples land on texel centres).
    """
    channels, height, width = plane.shape
    rows = torch.arange(height, device=plane.device, dtype=offsets.dtype)
    cols = torch.arange(width, device=plane.device, dtype=offsets.dtype)
    samples = bilinear(plane, cols[None, :] + offsets[0], rows[:, None] + offsets[1])
    return samples.view(channels, height, width)


def warp_uvs(uvs: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """``U' = U - o(U)``: move ``(N, 2)`` UVs (v up) by the bilinear offset field.

    UVs outside ``[0, 1]`` (repeat addressing) move as their wrapped copy does.
    """
    _, height, width = offsets.shape
    moved = sample_at_uvs(offsets, uvs)  # (N, 2) texels, x right and y down
    step = torch.stack([moved[:, 0] / width, -moved[:, 1] / height], dim=1)
    return uvs - step


def signed_areas(uvs: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """``(F,)`` twice the signed UV-space area of every face."""
    a, b, c = (uvs[faces[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    return ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0]


@torch.no_grad()
def fold_free_factor(
    uvs: torch.Tensor, moved: torch.Tensor, faces: torch.Tensor, tries: int = 12
) -> float:
    """The largest ``t`` in ``1, 1/2, 1/4, ...`` (else 0) for which ``uvs + t (moved - uvs)``
    keeps the orientation of every face that has a non-degenerate orientation now.
    """
    before = signed_areas(uvs, faces)
    oriented = before.abs() > 1e-12
    factor = 1.0
    for _ in range(tries):
        after = signed_areas(uvs + factor * (moved - uvs), faces)
        if bool(((after * before)[oriented] > 0).all()):
            return factor
        factor /= 2
    return 0.0
