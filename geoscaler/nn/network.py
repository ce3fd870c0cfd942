"""The GeoScaler network and its ablation variants.

``encoder -> [GeoCoding] -> [UVWarper] -> decoder``, run on each textured material's texture
(one set of weights for all of them):

========  =========  ========
variant   GeoCoding  UVWarper
========  =========  ========
base      no         no
gcm       yes        no
uvw       no         yes
full      yes        yes
========  =========  ========
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn

from geoscaler.nn.convolutional import Decoder, Encoder
from geoscaler.nn.geocoding import GeoCoding
from geoscaler.nn.uvwarper import UVWarper, fold_free_factor, warp_plane, warp_uvs
from geoscaler.uv.uvmaps import INPUT_CHANNELS, MeshGraph, UVRaster

VARIANTS = {
    "base": (False, False),
    "gcm": (True, False),
    "uvw": (False, True),
    "full": (True, True),
}


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture settings.

    Attributes:
        variant: ``base``, ``gcm``, ``uvw`` or ``full``.
        channels: ``C1``, encoder (and decoder) feature channels.
        graph_channels: ``C2``, GeoCoding's channels on the mesh graph.
        warp_channels: feature channels the UVWarper's offset head reads.
        stem: the encoder's way down to the target size, ``"pool"`` or ``"unshuffle"``.
        residual: the decoder's output is added to a base texture (warm start from a
            downsampled texture, warped like the features); otherwise the texture is
            ``sigmoid(decoder)`` as in the paper.
    """

    variant: str = "full"
    channels: int = 64
    graph_channels: int = 64
    warp_channels: int = 16
    stem: str = "pool"
    residual: bool = False

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}")

    @property
    def geocoding(self) -> bool:
        return VARIANTS[self.variant][0]

    @property
    def uv_warper(self) -> bool:
        return VARIANTS[self.variant][1]


@dataclass
class MeshGeometry:
    """The mesh as the network sees it (all on the network's device).

    Attributes:
        uvs: ``(V, 2)`` the mesh's UVs.
        faces: ``(F, 3)`` int64 vertex indices (for the fold-over guard).
        vertex_material: ``(V,)`` int64 material whose texture each vertex samples (-1 unused).
        graph: the welded vertex graph.
        rasters: per material the faces rasterised at the output texture size (None where
            untextured).
    """

    uvs: torch.Tensor
    faces: torch.Tensor
    vertex_material: torch.Tensor
    graph: MeshGraph
    rasters: list[UVRaster | None]


@dataclass
class NetworkOutput:
    """Per material ``(h, w, 3)`` linear textures, and ``(V, 2)`` warped UVs or None."""

    textures: list[torch.Tensor | None]
    uvs: torch.Tensor | None


class GeoScalerNet(nn.Module):
    """Downsample textures by ``scale`` with geometry-aware features and an optional UV warp."""

    def __init__(self, config: NetworkConfig, scale: int):
        super().__init__()
        self.config = config
        self.scale = scale
        c = config.channels
        self.encoder = Encoder(INPUT_CHANNELS, c, scale, config.stem)
        self.geocoding = GeoCoding(c, config.graph_channels) if config.geocoding else None
        self.warper = UVWarper(c, config.warp_channels) if config.uv_warper else None
        decoder_in = c - config.warp_channels if self.warper is not None else c
        self.decoder = Decoder(decoder_in, c, zero_output=config.residual)

    def forward(
        self,
        inputs: Sequence[torch.Tensor | None],
        geometry: MeshGeometry,
        bases: Sequence[torch.Tensor | None] | None = None,
    ) -> NetworkOutput:
        """Args:
            inputs: per material ``(10, H, W)``: sRGB texture, position, normal, coverage.
            geometry: the mesh.
            bases: per material ``(3, H/s, W/s)`` linear base textures (``residual`` only).

        Returns:
            Textures ``H/s x W/s`` and, for the warping variants, new UVs.
        """
        features = [None if x is None else self.encoder(x[None])[0] for x in inputs]
        if self.geocoding is not None:
            features = self.geocoding(
                features, geometry.uvs, geometry.vertex_material, geometry.graph, geometry.rasters
            )
        offsets: list[torch.Tensor | None] = [None] * len(features)
        uvs = None
        if self.warper is not None:
            offsets = [None if f is None else self.warper.offsets(f) for f in features]
            moved = self._warped_uvs(geometry, offsets)
            # The UV warp is linear in the offsets: scaling them scales the move.
            factor = fold_free_factor(geometry.uvs, moved.detach(), geometry.faces)
            offsets = [None if o is None else o * factor for o in offsets]
            uvs = geometry.uvs + factor * (moved - geometry.uvs)
            features = [
                None if f is None else warp_plane(f[self.warper.warp_channels :], o)
                for f, o in zip(features, offsets, strict=True)
            ]
        textures = []
        for index, plane in enumerate(features):
            if plane is None:
                textures.append(None)
                continue
            colour = self.decoder(plane[None])[0]
            if self.config.residual:
                base = bases[index] if bases is not None else None
                if base is None:
                    raise ValueError("a residual network needs base textures")
                if offsets[index] is not None:
                    base = warp_plane(base, offsets[index])
                colour = (base + colour).clamp(0, 1)
            else:
                colour = torch.sigmoid(colour)
            textures.append(colour.permute(1, 2, 0))
        return NetworkOutput(textures, uvs)

    @staticmethod
    def _warped_uvs(geometry: MeshGeometry, offsets: Sequence[torch.Tensor | None]) -> torch.Tensor:
        """``(V, 2)``: every vertex moved by the offsets of its own material."""
        uvs = geometry.uvs
        for material, field in enumerate(offsets):
            if field is None:
                continue
            vertices = torch.nonzero(geometry.vertex_material == material).squeeze(1)
            uvs = uvs.index_copy(0, vertices, warp_uvs(geometry.uvs[vertices], field))
        return uvs


def parameter_count(module: nn.Module) -> int:
    """Number of trainable scalars."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
