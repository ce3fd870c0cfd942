"""GeoCoding: filter texture features on the mesh graph, then bring them back to UV space.

Texels that are neighbours in UV space need not be neighbours on the surface (charts are cut
and packed), and neighbours on the surface may be far apart in the atlas. GeoCoding samples
the encoder's features at every vertex, filters them with graph convolutions over the mesh's
edges, interpolates them over each face and projects them onto the texture plane.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from geoscaler.render.texture import take
from geoscaler.uv.uvmaps import MeshGraph, UVRaster


class GraphConv(nn.Module):
    """``f'_i = theta1 f_i + theta2 sum_{j in N(i)} e_ij f_j`` (``e_ij``: edge length)."""

    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        self.theta1 = nn.Linear(in_channels, out_channels)
        self.theta2 = nn.Linear(in_channels, out_channels, bias=False)

    def forward(self, features: torch.Tensor, graph: MeshGraph) -> torch.Tensor:
        """``(P, C_in)`` point features to ``(P, C_out)``."""
        return self.theta1(features) + self.theta2(graph.neighbour_sum(features))


class GraphResidualBlock(nn.Module):
    """``relu(f + conv(relu(conv(f))))`` with graph convolutions."""

    def __init__(self, channels: int):
        super().__init__()
        self.first = GraphConv(channels, channels)
        self.second = GraphConv(channels, channels)

    def forward(self, features: torch.Tensor, graph: MeshGraph) -> torch.Tensor:
        inner = torch.relu(self.first(features, graph))
        return torch.relu(features + self.second(inner, graph))


def bilinear(plane: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``(C, h, w)`` at texel-index positions, clamped to the border.

    ``(x, y) = (j, i)`` is the centre of texel ``(i, j)``; positions on a texel centre return
    that texel exactly (no rounding), so a zero warp is an exact identity.

    Args:
        x, y: ``(N,)`` column and row positions (any shape, flattened).

    Returns:
        ``(C, N)``.
    """
    channels, height, width = plane.shape
    x = x.reshape(-1).clamp(0, width - 1)
    y = y.reshape(-1).clamp(0, height - 1)
    x0 = torch.floor(x).clamp(max=max(width - 2, 0))
    y0 = torch.floor(y).clamp(max=max(height - 2, 0))
    fx, fy = x - x0, y - y0
    x0, y0 = x0.long(), y0.long()
    x1 = (x0 + 1).clamp(max=width - 1)
    y1 = (y0 + 1).clamp(max=height - 1)
    index = torch.stack([y0 * width + x0, y0 * width + x1, y1 * width + x0, y1 * width + x1])
    values = take(plane.reshape(channels, -1), index.view(-1)).view(channels, 4, -1)
    top = values[:, 0] * (1 - fx) + values[:, 1] * fx
    bottom = values[:, 2] * (1 - fx) + values[:, 3] * fx
    return top * (1 - fy) + bottom * fy


def wrap_into_unit(uvs: torch.Tensor) -> torch.Tensor:
    """Repeat addressing for UVs outside ``[0, 1]``; those inside (1.0 included) stay."""
    outside = (uvs < 0) | (uvs > 1)
    return torch.where(outside, uvs - torch.floor(uvs), uvs)


def sample_at_uvs(features: torch.Tensor, uvs: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of a feature map at UV positions (GL texel centres).

    Args:
        features: ``(C, h, w)``; row 0 is the top of the texture (v = 1).
        uvs: ``(N, 2)`` UVs, v up; outside ``[0, 1]`` they repeat.

    Returns:
        ``(N, C)``.
    """
    _, height, width = features.shape
    wrapped = wrap_into_unit(uvs)
    x = wrapped[:, 0] * width - 0.5
    y = (1 - wrapped[:, 1]) * height - 0.5
    return bilinear(features, x, y).T


class GeoCoding(nn.Module):
    """Encoder features per material to geometry-aware features of the same shape.

    ``F_g = F_e + project(graph_blocks(pool_vertices(sample(F_e))))``: the skip residual keeps
    the features of texels that few vertices reach (a two-face square has four vertices for
    a whole texture).

    Args:
        channels: ``C1``, channels of the encoder features.
        graph_channels: ``C2``, channels on the graph.
        blocks: graph residual blocks.
        skip: add the skip residual from ``F_e`` (off only to show why it is needed).
    """

    def __init__(self, channels: int, graph_channels: int, blocks: int = 2, skip: bool = True):
        super().__init__()
        self.skip = skip
        self.into_graph = nn.Linear(channels, graph_channels)
        self.blocks = nn.ModuleList(GraphResidualBlock(graph_channels) for _ in range(blocks))
        self.out_of_graph = nn.Linear(graph_channels, channels)

    def vertex_features(
        self,
        features: Sequence[torch.Tensor | None],
        uvs: torch.Tensor,
        vertex_material: torch.Tensor,
    ) -> torch.Tensor:
        """``(V, C)``: each vertex samples the features of its own material's texture."""
        channels = next(f for f in features if f is not None).shape[0]
        out = uvs.new_zeros(len(uvs), channels)
        for material, plane in enumerate(features):
            if plane is None:
                continue
            vertices = torch.nonzero(vertex_material == material).squeeze(1)
            out = out.index_copy(0, vertices, sample_at_uvs(plane, uvs[vertices]))
        return out

    def forward(
        self,
        features: Sequence[torch.Tensor | None],
        uvs: torch.Tensor,
        vertex_material: torch.Tensor,
        graph: MeshGraph,
        rasters: Sequence[UVRaster | None],
    ) -> list[torch.Tensor | None]:
        """Args:
            features: per material ``(C1, h, w)`` encoder features (None: untextured).
            uvs: ``(V, 2)`` the mesh's UVs.
            vertex_material: ``(V,)`` material whose texture each vertex samples.
            graph: the mesh graph.
            rasters: per material the faces rasterised at ``h x w``.

        Returns:
            Per material ``(C1, h, w)`` features ``F_g``.
        """
        points = graph.pool_vertices(self.vertex_features(features, uvs, vertex_material))
        points = self.into_graph(points)
        for block in self.blocks:
            points = block(points, graph)
        points = self.out_of_graph(points)
        vertex_points = points.index_select(0, graph.vertex_to_point)
        return [
            None if plane is None else raster.interpolate(vertex_points) + plane * self.skip
            for plane, raster in zip(features, rasters, strict=True)
        ]
