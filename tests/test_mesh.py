"""The in-memory data model: edited copies, the texture check, welding and normals."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_support import TEXTURE, two_material_mesh

from geoscaler.errors import GeoscalerError
from geoscaler.filters import box
from geoscaler.mesh import TextureError, check_texture, compute_vertex_normals, weld_points


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
