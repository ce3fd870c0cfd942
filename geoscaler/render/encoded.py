"""8-bit textures sampled as GPU-style mip chains without a float copy at full size.

:class:`EncodedMipTexture` is a :class:`~geoscaler.render.texture.MipTexture` for lookups only whose
level 0 stays the texture's 8-bit codes, decoded tap by tap, and whose coarser levels alone are
float32: what the renderer's references (the original, often the largest image of a job) and
the bake into a new layout read. A lookup gives the same bits as on the float chain.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from geoscaler.color import DECODED_SRGB
from geoscaler.render.texture import MipLayout, MipTexture, gather, mip_sizes, next_mip_level

ENCODED_BAND_TEXELS = 1 << 20
"""Texels of level 0 an :class:`EncodedMipTexture` decodes at a time to make level 1 (12 MB of
float32 RGB)."""

Decoding = Sequence[tuple[int, np.ndarray]]
"""How an :class:`EncodedMipTexture` reads each of its channels: ``(source channel, (256,)
float32 value of each 8-bit code)``."""


def srgb_decoding(channels: int) -> Decoding:
    """The :class:`Decoding` of :func:`~geoscaler.color.texture_to_linear`: linear RGB from
    an sRGB texture of ``channels`` channels (grey repeated, alpha not read:
    :func:`~geoscaler.color.to_rgb`)."""
    return [(c if channels >= 3 else 0, DECODED_SRGB) for c in range(3)]


class EncodedMipTexture(MipTexture):
    """The mip chain of an 8-bit texture, for lookups only, in a fraction of a
    :class:`MipTexture`'s memory: level 0 stays the texture's 8-bit codes, decoded tap by tap
    through a table per channel, and only the coarser levels are float32, made from level 0 a
    band of rows at a time (:func:`~geoscaler.render.texture.next_mip_level`). Every lookup gives
    the same bits as the :class:`MipTexture` of the decoded texture (by default
    ``texture_to_linear(texture)``); no gradient flows (the original's chain, which views are
    rendered from).

    At 8192 x 8192 RGB that is the texture's own 201 MB array (not copied on the CPU) and
    268 MB of coarser levels, where a MipTexture holds its table and texels, 1.07 GB each, and
    the 805 MB float32 level 0 they are made from.

    Args:
        texture: ``(H, W)`` or ``(H, W, C)`` uint8.
        device: where the chain lives.
        decoding: each channel's source channel and values (default: linear RGB of sRGB,
            :func:`srgb_decoding`).
    """

    def __init__(
        self,
        texture: np.ndarray,
        device: torch.device | str = "cpu",
        decoding: Decoding | None = None,
    ):
        if texture.dtype != np.uint8:
            raise TypeError(f"an 8-bit texture is expected, got {texture.dtype}")
        codes = np.ascontiguousarray(texture if texture.ndim == 3 else texture[..., None])
        height, width, self.stride = codes.shape
        decoding = srgb_decoding(self.stride) if decoding is None else decoding
        self.channels = len(decoding)
        self.layout = MipLayout(height, width, device)
        self.size = self.layout.size
        self.num_levels = self.layout.num_levels
        self.codes = _shared_tensor(codes.reshape(-1), device)
        self.sources = [source for source, _ in decoding]
        self.values = [torch.from_numpy(np.asarray(v, np.float32)).to(device) for _, v in decoding]
        self.coarse = _coarse_levels(codes, decoding, self.layout)

    @property
    def texels(self) -> torch.Tensor:
        """Not held: the point of this chain (:meth:`bilinear` and :meth:`sample` read it)."""
        raise AttributeError("an EncodedMipTexture holds no float level 0; sample it instead")

    def bilinear(self, u: torch.Tensor, v: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """``(C, N)`` bilinear samples at integer mip ``level``: the same bits as
        :meth:`MipTexture.bilinear` on the float chain. Samples at level 0 read the codes,
        the others the float levels."""
        at_fine = level == 0
        if not bool(at_fine.any()):
            return self._coarse_lookup(u, v, level)
        if bool(at_fine.all()):
            return self._fine_lookup(u, v, level)
        parts = [torch.nonzero(at_fine).squeeze(1), torch.nonzero(~at_fine).squeeze(1)]
        fine, coarse = (
            lookup(*(t.index_select(0, part) for t in (u, v, level)))
            for part, lookup in zip(parts, (self._fine_lookup, self._coarse_lookup), strict=True)
        )
        colour = fine.new_empty(self.channels, len(level))
        return colour.index_copy_(1, parts[0], fine).index_copy_(1, parts[1], coarse)

    def _coarse_lookup(self, u: torch.Tensor, v: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """``(C, N)`` bilinear samples at levels >= 1."""
        index, weight = self.layout.bilinear_taps(u, v, level)
        return gather(self.coarse, index - self.size[0] * self.size[1], weight)

    def _fine_lookup(self, u: torch.Tensor, v: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """``(C, N)`` bilinear samples at level 0, decoded from the codes."""
        index, weight = self.layout.bilinear_taps(u, v, level)
        texels = self.codes.view(-1, self.stride).index_select(0, index.view(-1))  # (4 N, .)
        return torch.cat(
            [  # each channel's table is a texel table its codes index
                gather(values[None], texels[:, source].int().view(weight.shape), weight)
                for source, values in zip(self.sources, self.values, strict=True)
            ]
        )


def _shared_tensor(array: np.ndarray, device: torch.device | str) -> torch.Tensor:
    """``array`` as a tensor on ``device``, sharing its memory on the CPU even when it is
    read-only (DLPack; ``torch.from_numpy`` would warn); a copy where that is refused."""
    try:
        return torch.from_dlpack(array).to(device)
    except (BufferError, RuntimeError, TypeError):
        return torch.from_numpy(array.copy()).to(device)


def decode_codes(
    codes: np.ndarray, decoding: Decoding, device: torch.device | str = "cpu"
) -> torch.Tensor:
    """``(h, w, len(decoding))`` float32 values of ``(h, w, C)`` uint8 ``codes``."""
    planes = [np.take(values, codes[..., source]) for source, values in decoding]
    return torch.from_numpy(np.stack(planes, axis=2)).to(device)


def _coarse_levels(codes: np.ndarray, decoding: Decoding, layout: MipLayout) -> torch.Tensor:
    """``(C, T - H W)`` float32 levels 1 and coarser of ``(H, W, .)`` uint8 ``codes``, one row
    per channel laid out as the flat chain past level 0: level 1 made from
    :data:`ENCODED_BAND_TEXELS` of level 0 at a time, each further level from the one above."""
    height, width = layout.size
    channels, device = len(decoding), layout.offsets.device
    table = torch.empty(channels, layout.num_texels - height * width, device=device)
    start, above = 0, None
    for h, w in mip_sizes(height, width)[1:]:
        level = table[:, start : start + h * w].view(channels, h, w).permute(1, 2, 0)
        if above is None:
            _halve_codes(codes, decoding, level)
        else:
            level.copy_(next_mip_level(above))
        above, start = level, start + h * w
    return table


def _halve_codes(codes: np.ndarray, decoding: Decoding, level: torch.Tensor) -> None:
    """Write into ``(h, w, C)`` ``level`` the level below ``(H, W, .)`` uint8 ``codes``, decoded
    a band at a time (``next_mip_level`` of rows ``[2 i, 2 j)`` gives rows ``[i, j)``)."""
    step = 2 if codes.shape[0] > 1 else 1
    band = max(ENCODED_BAND_TEXELS // (step * codes.shape[1]), 1)
    for first in range(0, level.shape[0], band):
        last = min(first + band, level.shape[0])
        decoded = decode_codes(codes[first * step : last * step], decoding, level.device)
        level[first:last] = next_mip_level(decoded)
