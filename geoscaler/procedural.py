"""The built-in demo asset, made entirely by project code.

A bumpy cube-sphere whose six faces are six UV charts in a 3 x 2 atlas with empty gutters, and a
procedural texture with fine detail (thin latitude/longitude lines, a small checker, dots) so
that naive downsampling visibly hurts. The pattern is a function of the 3D surface point, so it
is continuous across chart seams and extends naturally into the gutters.
"""

from __future__ import annotations

import numpy as np

from geoscaler.mesh import Material, TexturedMesh

# Cube faces as (normal, tangent a, bitangent b) with a x b = normal, so faces wind CCW outside.
_CUBE_FACES = np.array(
    [
        [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        [[-1, 0, 0], [0, 0, 1], [0, 1, 0]],
        [[0, 1, 0], [0, 0, 1], [1, 0, 0]],
        [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
        [[0, 0, 1], [1, 0, 0], [0, 1, 0]],
        [[0, 0, -1], [0, 1, 0], [1, 0, 0]],
    ],
    dtype=np.float64,
)
_ATLAS_COLUMNS, _ATLAS_ROWS = 3, 2
_CHART_FILL = 0.86  # fraction of an atlas cell a chart covers; the rest is gutter


def _chart_frame(chart: int) -> tuple[float, float, float]:
    """``(u0, v0, side)``: lower-left corner and side of the square chart in UV units."""
    cell_u, cell_v = 1 / _ATLAS_COLUMNS, 1 / _ATLAS_ROWS
    side = _CHART_FILL * min(cell_u, cell_v)
    column, row = chart % _ATLAS_COLUMNS, chart // _ATLAS_COLUMNS
    return (column + 0.5) * cell_u - side / 2, (row + 0.5) * cell_v - side / 2, side


def _surface(chart: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(..., 3)`` points of the bumpy sphere at chart coordinates ``s, t`` in [-1, 1]."""
    frame = _CUBE_FACES[chart]
    cube = frame[..., 0, :] + s[..., None] * frame[..., 1, :] + t[..., None] * frame[..., 2, :]
    unit = cube / np.linalg.norm(cube, axis=-1, keepdims=True)
    x, y, z = unit[..., 0], unit[..., 1], unit[..., 2]
    bump = 1 + 0.06 * np.sin(5 * x) * np.sin(4 * y + 1) * np.cos(3 * z)
    return unit * bump[..., None]


def _pattern(points: np.ndarray) -> np.ndarray:
    """``(..., 3)`` sRGB colour in [0, 1] of the procedural pattern at surface points."""
    unit = points / np.linalg.norm(points, axis=-1, keepdims=True)
    longitude = np.arctan2(unit[..., 2], unit[..., 0])
    latitude = np.arcsin(np.clip(unit[..., 1], -1, 1))
    hue = (longitude / (2 * np.pi) + 0.5)[..., None]
    base = 0.55 + 0.35 * np.cos(2 * np.pi * (hue + np.array([0.0, 1 / 3, 2 / 3])))
    checker = np.sign(np.prod(np.sin(45 * unit), axis=-1))
    colour = base * (0.85 + 0.15 * checker[..., None])
    step = np.radians(15.0)
    for angle in (longitude, latitude):
        distance = np.abs((angle + step / 2) % step - step / 2)
        line = np.clip(1.5 - distance / np.radians(0.35), 0, 1)
        colour = colour * (1 - line[..., None]) + 0.08 * line[..., None]
    dots = np.sin(70 * longitude) * np.sin(70 * latitude) > 0.92
    return np.where(dots[..., None], np.array([0.98, 0.95, 0.4]), colour)


def _texture(size: int) -> np.ndarray:
    """``(size, size, 3)`` uint8 sRGB atlas: each texel shows the surface point it maps to."""
    centres = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(centres, 1 - centres)  # row 0 is the top of the image: v near 1
    column = np.minimum((u * _ATLAS_COLUMNS).astype(int), _ATLAS_COLUMNS - 1)
    row = np.minimum((v * _ATLAS_ROWS).astype(int), _ATLAS_ROWS - 1)
    chart = row * _ATLAS_COLUMNS + column
    frames = np.array([_chart_frame(c) for c in range(6)])
    u0, v0, side = frames[chart].transpose(2, 0, 1)
    s = (u - u0) / side * 2 - 1
    t = (v - v0) / side * 2 - 1
    colour = _pattern(_surface(chart, s, t))
    return np.round(np.clip(colour, 0, 1) * 255).astype(np.uint8)


def demo_mesh(subdivisions: int = 32, texture_size: int = 1024) -> TexturedMesh:
    """The demo asset: 6 charts of ``subdivisions^2`` quads, a ``texture_size``^2 atlas.

    With the defaults: 6,534 vertices (split at the 12 cube edges), 12,288 triangles.
    """
    n = subdivisions + 1
    grid = np.linspace(-1.0, 1.0, n)
    s, t = np.meshgrid(grid, grid, indexing="ij")  # (n, n), s along a, t along b
    positions, uvs, faces = [], [], []
    for chart in range(6):
        positions.append(_surface(np.full(s.shape, chart), s, t).reshape(-1, 3))
        u0, v0, side = _chart_frame(chart)
        uvs.append(np.stack([u0 + (s + 1) / 2 * side, v0 + (t + 1) / 2 * side], -1).reshape(-1, 2))
        index = chart * n * n + np.arange(n * n).reshape(n, n)
        a, b, c, d = index[:-1, :-1], index[1:, :-1], index[1:, 1:], index[:-1, 1:]
        faces.append(np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).reshape(-1, 3))
    positions = np.concatenate(positions).astype(np.float32)
    faces = np.concatenate(faces).astype(np.int64)
    _, vertex_to_point = np.unique(positions.round(6), axis=0, return_inverse=True)
    return TexturedMesh(
        positions=positions,
        faces=faces,
        uvs=np.concatenate(uvs).astype(np.float32),
        normals=positions / np.linalg.norm(positions, axis=1, keepdims=True),
        vertex_to_point=vertex_to_point.reshape(-1).astype(np.int64),
        face_material=np.zeros(len(faces), dtype=np.int64),
        materials=[Material("geoscaler_demo", _texture(texture_size))],
    )
