"""The OBJ geometry reader: triangles grouped by material, as the format defines them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import mesh_params
from mesh_support import SQUARE_ELEMENTS, write_obj_asset

from geoscaler.errors import GeoscalerError
from geoscaler.io import load_mesh, obj_geometry
from geoscaler.io.obj_geometry import obj_parts

SQUARE = SQUARE_ELEMENTS + "vn 0 0 1\n"
HERE = Path("here.obj")


def corners(part) -> np.ndarray:
    """``(F, 3, 5)``: per triangle corner its position and UV."""
    return np.concatenate([part.positions[part.faces], part.uvs[part.faces]], axis=2)


def test_a_polygon_is_a_fan_of_triangles_over_its_first_corner():
    (part,) = obj_parts(SQUARE + "f 1/1/1 2/2/1 3/3/1 4/4/1\n", {}, HERE)
    expected = [
        [[0, 0, 0, 0, 0], [1, 0, 0, 1, 0], [1, 1, 0, 1, 1]],
        [[0, 0, 0, 0, 0], [1, 1, 0, 1, 1], [0, 1, 0, 0, 1]],
    ]
    np.testing.assert_array_equal(corners(part), expected)
    np.testing.assert_array_equal(part.normals, np.tile([0.0, 0.0, 1.0], (4, 1)))


def test_negative_indices_count_back_from_the_elements_read_so_far():
    text = SQUARE + "f -4/-4 -3/-3 -2/-2\nv 5 5 5\nvt 0.5 0.5\nf -5/-5 -3/-3 -1/-1\n"
    (part,) = obj_parts(text, {}, HERE)
    np.testing.assert_array_equal(
        corners(part),
        [
            [[0, 0, 0, 0, 0], [1, 0, 0, 1, 0], [1, 1, 0, 1, 1]],
            [[0, 0, 0, 0, 0], [1, 1, 0, 1, 1], [5, 5, 5, 0.5, 0.5]],
        ],
    )


def test_faces_are_grouped_by_the_material_in_use_in_the_order_first_used():
    text = SQUARE + (
        "f 1/1 2/2 3/3\n"  # before any usemtl: no material
        "usemtl wood\nf 1/1 3/3 4/4\n"
        "usemtl unknown\nf 2/2 3/3 4/4\n"  # a name no library defines: no material
        "g other\nusemtl wood\nf 1/1 2/2 4/4\n"
    )
    parts = obj_parts(text, {"stone": 0, "wood": 1}, HERE)
    assert [p.material for p in parts] == [None, 1]
    assert [len(p.faces) for p in parts] == [2, 2]


def test_uvs_and_normals_are_kept_only_where_every_corner_of_a_material_gives_them():
    text = SQUARE + "f 1/1/1 2/2/1 3/3/1\nf 1//1 3//1 4//1\n"
    (part,) = obj_parts(text, {}, HERE)
    assert part.uvs is None
    np.testing.assert_array_equal(part.normals, np.tile([0.0, 0.0, 1.0], (len(part.positions), 1)))


def test_extra_numbers_are_skipped_and_a_lone_u_has_v_zero():
    text = "v 0 0 0 1 0.5 0.25\nv 1 0 0\nv 0 1 0\nvt 0.5\nvt 1 0 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    (part,) = obj_parts(text, {}, HERE)
    np.testing.assert_array_equal(part.positions[part.faces[0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(part.uvs[part.faces[0]], [[0.5, 0], [1, 0], [0, 1]])


def test_a_corner_shared_by_faces_is_one_vertex():
    (part,) = obj_parts(SQUARE + "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n", {}, HERE)
    assert len(part.positions) == 4
    np.testing.assert_array_equal(part.faces, [[0, 1, 2], [0, 2, 3]])


def test_points_lines_and_degenerate_faces_are_not_triangles():
    assert obj_parts(SQUARE + "p 1\nl 1 2\nf 1 2\n", {}, HERE) == []


@pytest.mark.parametrize("line", ["v 1 2", "v 1 2 x", "vt", "vn 0 0"])
def test_an_element_without_its_numbers_is_refused_with_its_line(line: str):
    with pytest.raises(GeoscalerError, match=f"here.obj: line 10: '{line}' needs"):
        obj_parts(SQUARE + line + "\n", {}, HERE)


def test_a_malformed_vertex_in_a_file_is_a_clear_error(tmp_path: Path):
    path = write_obj_asset(tmp_path, obj="mtllib mesh.mtl\nv 0 0\n" + SQUARE)
    with pytest.raises(GeoscalerError, match=r"mesh.obj: line 2: 'v 0 0' needs 3 numbers"):
        load_mesh(path)


@pytest.mark.parametrize("path", [p for p in mesh_params() if str(p.values[0]).endswith(".obj")
                                  or p.values[0] is None])  # fmt: skip
def test_every_development_obj_reads_the_triangles_trimesh_reads(path: Path):
    """An independent reader of the same files: the same corners, face by face."""
    text = path.read_text(errors="replace")
    ours = np.concatenate([corners(p) for p in obj_parts(text, {}, path)])
    theirs = trimesh.load(path, process=False, force="mesh")
    expected = np.concatenate(
        [theirs.vertices[theirs.faces], theirs.visual.uv[theirs.faces]], axis=2
    )
    assert ours.shape == expected.shape
    # the same triangles, each possibly starting at another corner (quads split otherwise)
    np.testing.assert_allclose(_canonical(ours), _canonical(expected), atol=1e-6)


def _canonical(triangles: np.ndarray) -> np.ndarray:
    """Each triangle rotated to start at its lexicographically least corner, then sorted."""
    rotations = np.stack([np.roll(triangles, -k, axis=1) for k in range(3)], axis=1)
    keys = rotations.reshape(len(triangles), 3, -1)
    best = np.array([min(range(3), key=lambda k, t=t: tuple(t[k])) for t in keys])
    rotated = rotations[np.arange(len(triangles)), best].reshape(len(triangles), -1)
    return rotated[np.lexsort(rotated.T[::-1])]


def test_corners_of_mixed_forms_read_as_the_same_corners_written_alike():
    mixed = SQUARE + "f 1/1/1 2/2 3//1\nf 1 3/3/1 4/4\n"
    alike = SQUARE + "f 1/1/1 2/2/0 3/0/1\nf 1/0/0 3/3/1 4/4/0\n"
    (part,) = obj_parts(mixed, {}, HERE)
    assert part.uvs is None and part.normals is None
    with pytest.raises(GeoscalerError, match="line 10: face corner '2/2/0' is not a normal index"):
        obj_parts(alike, {}, HERE)
    np.testing.assert_array_equal(
        part.positions[part.faces],
        [[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]],
    )


@pytest.mark.parametrize(
    ("face", "message"),
    [
        ("f 1/1 2/0 3/3", "face corner '2/0' is not a texture coordinate index"),
        ("f /1 2/2 3/3", "face corner '/1' is not a vertex index"),
        ("f 1/1 2/2 x/3", "face corner 'x/3' is not a vertex index"),
        ("f 1/1 2/2 5/3", "face corner '5/3' refers to vertex 5, but the file defines 4;"),
        ("f 1/1 2/2 -5/3", "face corner '-5/3' refers to vertex -5, but the file defines 4 before"),
        (
            "f 1/1 2/2 3/99999999999999999999",
            "face corner '3/99999999999999999999' refers to "
            "texture coordinate 99999999999999999999, but the file defines 4;",
        ),
    ],
)
def test_a_bad_face_index_is_refused_with_its_line(face: str, message: str):
    with pytest.raises(GeoscalerError, match=f"here.obj: line 10: {message}"):
        obj_parts(SQUARE + face + "\n", {}, HERE)


@pytest.mark.parametrize("largest", [9, 2**40])
def test_distinct_rows_are_numpys_distinct_rows(largest: int):
    rows = np.random.default_rng(0).integers(-1, 3, (200, 3), dtype=np.int64)
    rows[rows == 2] = largest  # a key past int64 is made another way, to the same result
    distinct, inverse = obj_geometry._distinct_rows(rows)
    expected, expected_inverse = np.unique(rows, axis=0, return_inverse=True)
    np.testing.assert_array_equal(distinct, expected)
    np.testing.assert_array_equal(inverse, expected_inverse.reshape(-1))
