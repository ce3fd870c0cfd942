"""The in-memory data model: edited copies, the texture check, welding and normals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from mesh_support import TEXTURE, ribbon_mesh, two_material_mesh

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import (
    Material,
    TexturedMesh,
    TextureError,
    check_geometry,
    check_texture,
    compute_vertex_normals,
    weld_points,
)
from geoscaler.resize.filters import box
from geoscaler.uv import uvmaps
from geoscaler.uv.uvmaps import uv_coverage


def test_with_texture_returns_an_edited_copy():
    mesh = two_material_mesh()
    small = np.zeros((1, 2, 4), np.uint8)
    uvs = mesh.uvs * 0.5
    edited = mesh.with_texture(0, small, uvs)
    assert edited.materials[0].base_color_texture is small
    assert edited.materials[1] is mesh.materials[1]
    np.testing.assert_array_equal(edited.uvs, uvs)
    np.testing.assert_array_equal(mesh.materials[0].base_color_texture, TEXTURE)
    assert mesh.uvs.max() == 1.0
    with pytest.raises(ValueError, match="uint8"):
        mesh.with_texture(0, small.astype(np.float32))
    with pytest.raises(ValueError, match="shape"):
        mesh.with_texture(0, np.zeros((2, 2), np.uint8))
    with pytest.raises(ValueError, match="out of range"):
        mesh.with_texture(2, small)
    with pytest.raises(ValueError, match="uvs"):
        mesh.with_texture(0, small, uvs[:2])


def test_with_uvs_splits_a_vertex_only_where_its_corners_disagree():
    mesh = two_material_mesh()
    mesh.attributes = {"COLOR_0": np.arange(18, dtype=np.float32).reshape(6, 3) / 18}
    same = mesh.with_uvs(mesh.corner_uvs())  # corners that agree: the same vertices
    np.testing.assert_array_equal(same.faces, mesh.faces)
    np.testing.assert_array_equal(same.uvs, mesh.uvs)
    corners = mesh.corner_uvs()
    corners[1] += 0.25  # face 1 (vertices 0, 2, 3) moves: vertices 0 and 2 split
    cut = mesh.with_uvs(corners)
    assert len(cut.uvs) == len(mesh.uvs) + 2
    np.testing.assert_array_equal(cut.corner_uvs(), corners)
    np.testing.assert_array_equal(cut.positions[cut.faces], mesh.positions[mesh.faces])
    np.testing.assert_array_equal(cut.vertex_to_point[cut.faces], mesh.vertex_to_point[mesh.faces])
    np.testing.assert_array_equal(cut.attributes["COLOR_0"][6:], mesh.attributes["COLOR_0"][[0, 2]])
    np.testing.assert_array_equal(cut.faces[[0, 2, 3]], mesh.faces[[0, 2, 3]])  # kept in place
    cut.validate()
    with pytest.raises(ValueError, match="per face corner"):
        mesh.with_uvs(np.zeros((4, 2, 2)))


def test_vertex_uvs_are_the_corner_uvs_of_each_face():
    mesh = ribbon_mesh(quads=2)
    np.testing.assert_array_equal(mesh.corner_uvs(), mesh.uvs[mesh.faces])
    np.testing.assert_array_equal(mesh.with_uvs(mesh.uvs * 2).uvs, mesh.uvs * 2)


def test_check_texture_is_one_check_with_one_message():
    """The data model and the texture filters refuse bad textures with the same words."""
    small = np.zeros((1, 2, 4), np.uint8)
    check_texture(small)
    check_texture(small[..., :1], channels=(1, 2, 3, 4))
    for bad in (small.astype(np.float32), np.zeros((0, 2, 3), np.uint8), small[..., :2], [[0]]):
        with pytest.raises(TextureError, match=r"expected an \(H, W, C\) uint8 array") as info:
            check_texture(bad)
        assert isinstance(info.value, ValueError) and isinstance(info.value, GeoscalerError)
    with pytest.raises(TextureError, match=r"got a uint8 array of shape \(1, 2, 2\)"):
        two_material_mesh().with_texture(0, small[..., :2])
    with pytest.raises(TextureError, match=r"C = 1, 2, 3 or 4 \(grey, grey\+alpha, RGB or RGBA\)"):
        box(np.zeros((2, 2, 5), np.uint8), 2)


def test_weld_points_and_vertex_normals():
    positions = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-0.0, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(weld_points(positions), [0, 1, 2, 0, 1])
    faces = np.array([[0, 1, 2], [3, 4, 2]])
    normals = compute_vertex_normals(positions, faces, weld_points(positions))
    assert normals.dtype == np.float32
    np.testing.assert_allclose(normals, [[0, 0, 1]] * 5)


def triangle_soup(uvs: np.ndarray, positions: np.ndarray | None = None) -> TexturedMesh:
    """One textured triangle per ``(3, 2)`` row of ``uvs`` ``(F, 3, 2)``, corners unshared."""
    count = len(uvs) * 3
    if positions is None:
        positions = np.tile(np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), (len(uvs), 1))
    return TexturedMesh(
        positions=positions.astype(np.float32),
        faces=np.arange(count).reshape(-1, 3),
        uvs=np.asarray(uvs, np.float32).reshape(-1, 2),
        normals=np.tile(np.float32([0, 0, 1]), (count, 1)),
        vertex_to_point=np.arange(count),
        face_material=np.zeros(len(uvs), np.int64),
        materials=[Material("m", TEXTURE)],
    )


def brute_force_coverage(mesh: TexturedMesh, size: int) -> float:
    """Texel centres inside any face shifted by any whole number of repeats: the definition."""
    centres = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(centres, 1 - centres)
    covered = np.zeros(u.shape, bool)
    for a, b, c in mesh.uvs[mesh.faces].astype(np.float64):
        low, high = np.floor(np.minimum(np.minimum(a, b), c)), np.ceil(np.maximum(a, b))
        high = np.maximum(high, np.ceil(c))
        for i in range(int(low[0]), int(high[0]) + 1):
            for j in range(int(low[1]), int(high[1]) + 1):
                x, y = u + i, v + j
                sides = [
                    (q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0])
                    for p, q in ((a, b), (b, c), (c, a))
                ]
                inside = (sides[0] >= 0) & (sides[1] >= 0) & (sides[2] >= 0)
                covered |= inside | ((sides[0] <= 0) & (sides[1] <= 0) & (sides[2] <= 0))
    return float(covered.mean())


@pytest.mark.parametrize("spread", [0.3, 1.5])
def test_uv_coverage_counts_texel_centres_with_repeat_addressing(spread: float):
    rng = np.random.default_rng(7)
    mesh = triangle_soup(rng.normal(size=(6, 3, 2)) * spread)
    assert uv_coverage(mesh, 0, 64) == brute_force_coverage(mesh, 64)


def test_uv_coverage_of_simple_layouts():
    half = np.float32([[[0, 0], [1, 0], [0, 1]]])
    assert uv_coverage(triangle_soup(half), 0, 64) == 2080 / 64**2  # u + v <= 1
    assert uv_coverage(triangle_soup(half + 3), 0, 64) == uv_coverage(triangle_soup(half), 0, 64)
    assert uv_coverage(triangle_soup(np.concatenate([half, 1 - half])), 0, 64) == 1.0
    assert uv_coverage(triangle_soup(half * 3), 0, 64) == 1.0  # holds a whole repeat
    assert uv_coverage(replace(triangle_soup(half), face_material=np.ones(1, int)), 0) == 0.0


def test_uv_coverage_costs_rows_not_area(monkeypatch):
    """40,000 copies of a face over the whole texture cost one face's 512 texel rows, 2,000
    jittered copies 512 rows each, and 20,000 faces tiling it 50 times each way the rows of
    the four distinct faces they are once wrapped (the rasteriser took minutes: faces times
    area). Work is counted in rows walked, the unit of ``COVERAGE_WORK``."""
    rows = []
    spans = uvmaps._spans

    def counted(corners, y):
        rows.append(len(y))
        return spans(corners, y)

    monkeypatch.setattr(uvmaps, "_spans", counted)

    def walked(mesh) -> tuple[float | None, int]:
        rows.clear()
        return uv_coverage(mesh), sum(rows)

    rng = np.random.default_rng(0)
    half = np.float32([[0, 0], [1, 0], [0, 1]])
    copies = triangle_soup(np.tile(half, (40_000, 1, 1)))
    jittered = triangle_soup(half + rng.normal(size=(2_000, 1, 2)) * 1e-3)
    cells = np.tile(np.stack([half, 1 - half]) * 0.5, (10_000, 1, 1))
    tiles = triangle_soup(cells + rng.integers(0, 100, (20_000, 1, 2)) * 0.5)
    assert walked(copies) == (walked(triangle_soup(half[None]))[0], 512)
    coverage, work = walked(jittered)
    assert 0.5 < coverage < 0.52 and work == 2_000 * 512
    assert walked(tiles) == (1.0, 4 * 512)


def test_uv_coverage_beyond_its_work_limit_is_not_measured():
    """Long diagonal slivers across thousands of repeats: no figure rather than minutes."""
    sliver = np.float32([[0, 0], [5000, 5000.1], [5000.01, 5000]])
    assert (
        uv_coverage(
            triangle_soup(np.tile(sliver, (100, 1, 1)) + np.arange(100)[:, None, None] * 1e-3)
        )
        is None
    )


@pytest.mark.parametrize(
    ("positions", "uvs", "message"),
    [
        ([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], None, "NaN or infinite"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0], [1, np.inf], [0, 1]], "NaN or infinite"),
        ([[0, 0, 0], [1e20, 0, 0], [0, 1, 0]], None, "coordinates up to 1e\\+20"),
        ([[0, 0, 0], [1e-40, 0, 0], [0, 1e-40, 0]], None, "too small to render"),
        ([[1, 1, 1]] * 3, None, "all its vertices at one point"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0], [1e30, 0], [0, 1]], "UVs up to 1e\\+30"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], None, "all 1 textured triangles are degenerate"),
    ],
)
def test_check_geometry_refuses_what_cannot_be_rendered(positions, uvs, message):
    uvs = np.float32([[0, 0], [1, 0], [0, 1]]) if uvs is None else np.float32(uvs)
    mesh = triangle_soup(uvs[None], np.float32(positions))
    with pytest.raises(GeoscalerError, match=f"^mesh.obj: .*{message}"):
        check_geometry(mesh, "mesh.obj")


def test_check_geometry_refuses_textured_faces_too_small_to_see():
    """A big untextured face beside a speck of textured one: the texture cannot be seen."""
    mesh = two_material_mesh()
    positions = mesh.positions.copy()
    positions[[0, 1, 2, 3], 0] *= 1e-4
    positions[[0, 1, 2, 3], 1] *= 1e-4
    with pytest.raises(GeoscalerError, match="too small to be seen"):
        check_geometry(replace(mesh, positions=positions), "mesh.obj")
    check_geometry(mesh, "mesh.obj")
