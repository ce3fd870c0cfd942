"""``KHR_texture_transform`` on the base colour: folded into the UVs on reading, unfolded on
writing glTF.

Everything past :mod:`geoscaler.io` samples the base colour at the mesh's UVs, so a glTF
material whose base-colour texture has a transform is read with the transform applied to the
UVs of its faces (the UVs the texture is really sampled at), and written back with the inverse
applied and the extension kept, so the file keeps its own UVs and transform. The other maps keep
their texture-info objects, transforms included, and are written back as read. OBJ/MTL cannot
hold a transform: an OBJ is written with the applied UVs.

The extension's matrix is ``uv' = T R S uv`` in glTF's UV space (``v`` down the image), with
``T`` the offset, ``R = [[cos a, sin a], [-sin a, cos a]]`` (``a`` the rotation) and ``S`` the
scale (../shared/PROTOCOL.md, "Material inputs per sample").
"""

from __future__ import annotations

import math

import numpy as np

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import BASE_COLOR, TexturedMesh

from .slots import slot_info

EXTENSION = "KHR_texture_transform"
FLIP_V = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 1.0], [0.0, 0.0, 1.0]])
"""glTF's UV space to GeoScaler's (``v`` up) and back: ``(u, v) -> (u, 1 - v)``."""


def transform_matrix(info: dict, where: str) -> np.ndarray | None:
    """The ``(3, 3)`` float64 affine map of a texture-info object's ``KHR_texture_transform``
    in GeoScaler's UV convention (``uv' = M @ (u, v, 1)``), None without one.

    The extension's numbers are checked when the file is read (:mod:`geoscaler.io.gltf_check`);
    ``where`` starts the message of the one refusal left here: a scale of zero, which samples
    the whole texture at one point.
    """
    extension = info.get("extensions", {}).get(EXTENSION)
    if extension is None:
        return None
    offset = [float(v) for v in extension.get("offset", [0.0, 0.0])]
    rotation = float(extension.get("rotation", 0.0))
    scale = [float(v) for v in extension.get("scale", [1.0, 1.0])]
    if 0.0 in scale:
        raise GeoscalerError(
            f"{where}: its {EXTENSION} has a scale of 0 {scale}, which samples the whole texture "
            "at one point. Fix the material's texture transform in your 3D tool and re-export."
        )
    cos, sin = math.cos(rotation), math.sin(rotation)
    translate = np.array([[1.0, 0.0, offset[0]], [0.0, 1.0, offset[1]], [0.0, 0.0, 1.0]])
    rotate = np.array([[cos, sin, 0.0], [-sin, cos, 0.0], [0.0, 0.0, 1.0]])
    gltf = translate @ rotate @ np.diag([scale[0], scale[1], 1.0])
    return FLIP_V @ gltf @ FLIP_V


def texture_coordinate_set(info: dict) -> int:
    """The UV set a texture-info object samples: the transform's ``texCoord`` override where
    it has one, else its own ``texCoord`` (default 0)."""
    extension = info.get("extensions", {}).get(EXTENSION, {})
    return extension.get("texCoord", info.get("texCoord", 0))


def apply(matrix: np.ndarray, uvs: np.ndarray) -> np.ndarray:
    """``(N, 2)`` UVs mapped by a ``(3, 3)`` affine ``matrix``, in float64."""
    return np.asarray(uvs, np.float64) @ matrix[:2, :2].T + matrix[:2, 2]


def base_color_matrix(material_json: dict, where: str) -> np.ndarray | None:
    """The transform of a glTF material's base-colour texture (:func:`transform_matrix`)."""
    info = material_json.get("pbrMetallicRoughness", {}).get(BASE_COLOR)
    return transform_matrix(info, where) if isinstance(info, dict) else None


def unfolded(mesh: TexturedMesh) -> TexturedMesh:
    """``mesh`` with each transformed material's UVs mapped back through its transform's
    inverse, the UVs its glTF file holds (a vertex shared by materials of different
    transforms is split). The mesh itself when no material has one."""
    corners = None
    for index, material in enumerate(mesh.materials):
        if material.base_color_texture is None:
            continue
        matrix = transform_matrix(slot_info(material.properties, BASE_COLOR), material.name)
        if matrix is None:
            continue
        if corners is None:
            corners = mesh.corner_uvs().astype(np.float64)
        faces = mesh.face_material == index
        inverse = apply(np.linalg.inv(matrix), corners[faces].reshape(-1, 2))
        corners[faces] = inverse.reshape(-1, 3, 2)
    return mesh if corners is None else mesh.with_uvs(corners.astype(np.float32))
