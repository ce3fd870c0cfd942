"""The UV inspector's geometry: chart outlines, and the warp of methods that move UVs.

Everything here is numpy in UV units (``v = 0`` at the bottom of the texture, as in
:mod:`geoscaler.mesh`); :class:`UVPicture` draws it with GL over a texture.
"""

from __future__ import annotations

import moderngl
import numpy as np

from geoscaler.mesh import TexturedMesh
from geoscaler.report.figures import colormap
from geoscaler.uv.uvmaps import rasterize_uv, tiled_face_uvs, uv_corner_ids

from .gl_renderer import program

OUTLINE_COLOUR = (1.0, 0.85, 0.1, 1.0)
GRID_COLOUR = (0.2, 0.9, 1.0, 1.0)
OUTSIDE_GREY = 64  # heatmap texels no face covers


def chart_outlines(mesh: TexturedMesh, material: int | None = None) -> np.ndarray:
    """``(E, 2, 2)`` float32 UV segments: the boundary edges of the UV charts.

    An edge is on a chart boundary when no other face shares both of its UV corners
    (:func:`geoscaler.uv.uvmaps.uv_corner_ids`). Faces are shifted by whole tiles into [0, 1)^2.
    """
    faces = mesh.faces if material is None else mesh.faces[mesh.face_material == material]
    if len(faces) == 0:
        return np.zeros((0, 2, 2), np.float32)
    corner = uv_corner_ids(mesh)[faces]  # (F, 3)
    ends = np.stack([corner, np.roll(corner, -1, axis=1)], axis=2).reshape(-1, 2)  # (3F, 2)
    _, edge, count = np.unique(
        np.sort(ends, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    boundary = count[edge.reshape(-1)] == 1
    uv = tiled_face_uvs(mesh, faces)  # (F, 3, 2)
    segments = np.stack([uv, np.roll(uv, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    return segments[boundary].astype(np.float32)


def warp_field(
    mesh: TexturedMesh, uvs: np.ndarray, resolution: int = 256
) -> tuple[np.ndarray, np.ndarray]:
    """Where each point of the original UV layout moved to.

    Args:
        uvs: ``(V, 2)`` the method's UVs for the mesh's vertices.
        resolution: texels per side of the field.

    Returns:
        ``(displacement, covered)``: ``(R, R, 2)`` float32 new minus old UV at each texel of
        the original layout (row 0 at the top), and ``(R, R)`` bool texels that faces cover.
    """
    import torch

    gbuffer = rasterize_uv(mesh, resolution)
    moved = torch.from_numpy(np.asarray(uvs, np.float64) - mesh.uvs.astype(np.float64))
    corner = moved[torch.from_numpy(mesh.faces)].permute(2, 0, 1)  # (2, F, 3)
    values, _, _ = gbuffer.interpolate(corner)
    displacement = np.zeros((resolution * resolution, 2), np.float32)
    pixels = gbuffer.pixels.long().numpy()
    displacement[pixels] = values.T.numpy()
    covered = np.zeros(resolution * resolution, bool)
    covered[pixels] = True
    shape = (resolution, resolution)
    return displacement.reshape(*shape, 2), covered.reshape(shape)


def warp_grid(displacement: np.ndarray, covered: np.ndarray, lines: int = 24) -> np.ndarray:
    """``(S, 2, 2)`` float32 UV segments of a regular grid deformed by the warp.

    Grid points sit at texel centres of the field, ``lines`` rows and columns of them; each is
    moved by its displacement, and neighbours both covered are joined.
    """
    resolution = covered.shape[0]
    index = ((np.arange(lines) + 0.5) * resolution / lines).astype(int)
    rows, cols = np.meshgrid(index, index, indexing="ij")
    u = (cols + 0.5) / resolution
    v = 1.0 - (rows + 0.5) / resolution
    points = np.stack([u, v], axis=-1) + displacement[rows, cols]
    inside = covered[rows, cols]
    segments = []
    for a, b, ok in (
        (points[:, :-1], points[:, 1:], inside[:, :-1] & inside[:, 1:]),
        (points[:-1], points[1:], inside[:-1] & inside[1:]),
    ):
        segments.append(np.stack([a[ok], b[ok]], axis=1))
    return np.concatenate(segments).astype(np.float32)


def heatmap(values: np.ndarray, mask: np.ndarray, top: float | None = None) -> np.ndarray:
    """``(H, W, 4)`` uint8 opaque picture of ``values`` / ``top`` on the project's error ramp
    (:func:`geoscaler.report.figures.colormap`), grey where ``mask`` is False (``top``: the largest
    value by default)."""
    top = float(values[mask].max()) if top is None and mask.any() else (top or 1.0)
    rgb = colormap(values / max(top, 1e-12))
    rgb[~mask] = OUTSIDE_GREY
    alpha = np.full(rgb.shape[:-1] + (1,), 255, np.uint8)
    return np.concatenate([rgb, alpha], axis=-1)


class UVPicture:
    """A texture drawn at level 0 over the UV square with line segments on top, in GL.

    Attributes:
        image: ``(size, size)`` RGBA8 texture (rows bottom-up, as GL renders).
    """

    def __init__(self, ctx: moderngl.Context, size: int = 512):
        self.ctx = ctx
        self.size = size
        self.image = ctx.texture((size, size), 4)
        self.fbo = ctx.framebuffer([self.image])
        self.image_program = program(ctx, "fullscreen.vert", "uv_image.frag")
        self.line_program = program(ctx, "uv_lines.vert", "uv_lines.frag")
        self.empty = ctx.vertex_array(self.image_program, [])

    def draw(
        self,
        texture: moderngl.Texture | None,
        layers: list[tuple[np.ndarray, tuple[float, float, float, float]]],
    ) -> None:
        """Draw ``texture`` (grey when None) and each ``(segments (S, 2, 2), colour)`` layer."""
        self.fbo.use()
        self.fbo.clear(0.25, 0.25, 0.25, 1.0)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        if texture is not None:
            texture.use(0)
            self.image_program["image"] = 0
            self.empty.render(moderngl.TRIANGLES, vertices=3)
        for segments, colour in layers:
            if len(segments) == 0:
                continue
            buffer = self.ctx.buffer(np.ascontiguousarray(segments, np.float32).tobytes())
            vao = self.ctx.vertex_array(self.line_program, [(buffer, "2f", "uv")])
            self.line_program["line_colour"] = colour
            vao.render(moderngl.LINES)
            vao.release()
            buffer.release()

    def release(self) -> None:
        for thing in (self.fbo, self.image, self.empty, self.image_program, self.line_program):
            thing.release()
