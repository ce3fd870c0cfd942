"""The convolutional parts of the network: encoder, residual blocks and decoder."""

from __future__ import annotations

import math

import torch
from torch import nn


def conv3x3(in_channels: int, out_channels: int) -> nn.Conv2d:
    """A 3 x 3 convolution that keeps the spatial size (replicate padding: no dark borders)."""
    return nn.Conv2d(in_channels, out_channels, 3, padding=1, padding_mode="replicate")


class ResidualBlock(nn.Module):
    """``x + conv(relu(conv(x)))``, then ReLU."""

    def __init__(self, channels: int):
        super().__init__()
        self.first = conv3x3(channels, channels)
        self.second = conv3x3(channels, channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(x + self.second(torch.relu(self.first(x))))


class Encoder(nn.Module):
    """Texture plus geometry maps ``(B, C_in, H, W)`` to features ``(B, C, H/s, W/s)``.

    Two ways down to the target size:

    * ``"pool"`` (the paper's "convolutions and pooling"): a 3 x 3 convolution at the input
      size, then ``log2(s)`` times a 2 x 2 average pooling followed by a 3 x 3 convolution.
    * ``"unshuffle"`` (cheap, for CPUs): each ``s x s`` block of input texels becomes one
      position with ``C_in s^2`` channels, mixed by a 1 x 1 convolution. Nothing is lost, and
      no convolution runs above the target size.

    Either is followed by ``blocks`` residual blocks at the target size.
    """

    def __init__(
        self, in_channels: int, channels: int, scale: int, stem: str = "pool", blocks: int = 4
    ):
        super().__init__()
        halvings = int(math.log2(scale))
        if 2**halvings != scale:
            raise ValueError(f"scale must be a power of two, got {scale}")
        layers: list[nn.Module]
        if stem == "pool":
            layers = [conv3x3(in_channels, channels), nn.ReLU()]
            for _ in range(halvings):
                layers += [nn.AvgPool2d(2), conv3x3(channels, channels), nn.ReLU()]
        elif stem == "unshuffle":
            layers = [
                nn.PixelUnshuffle(scale),
                nn.Conv2d(in_channels * scale * scale, channels, 1),
                nn.ReLU(),
            ]
        else:
            raise ValueError(f"stem must be 'pool' or 'unshuffle', got {stem!r}")
        self.stem = nn.Sequential(*layers)
        self.blocks = nn.Sequential(*(ResidualBlock(channels) for _ in range(blocks)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.blocks(self.stem(x))


class Decoder(nn.Module):
    """Features ``(B, C_in, h, w)`` to a 3-channel map ``(B, 3, h, w)`` (no activation).

    Two 3 x 3 convolutions with ReLU (``C_in -> C -> C``), then a 3 x 3 convolution to RGB.
    ``zero_output`` starts the last layer at zero, so a decoder that adds to a base texture
    starts as the identity.
    """

    def __init__(self, in_channels: int, channels: int, zero_output: bool = False):
        super().__init__()
        self.body = nn.Sequential(
            conv3x3(in_channels, channels), nn.ReLU(), conv3x3(channels, channels), nn.ReLU()
        )
        self.to_rgb = conv3x3(channels, 3)
        if zero_output:
            nn.init.zeros_(self.to_rgb.weight)
            nn.init.zeros_(self.to_rgb.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.to_rgb(self.body(x))
