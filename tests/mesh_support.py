"""What the mesh and mesh-file tests share: small meshes and mesh files written by hand."""

from __future__ import annotations

import base64
import io
import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from geoscaler.io.gltf import FLOAT, UNSIGNED_INT
from geoscaler.mesh import Material, TexturedMesh, compute_vertex_normals, weld_points

FORMATS = [".obj", ".glb", ".gltf"]
DROPPED_MAPS = "ignore:material .* OBJ/MTL cannot express"

SQUARE_ELEMENTS = """v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
"""
"""The corners of the unit square in z = 0 and their texture coordinates, as OBJ elements."""
QUAD_OBJ = "mtllib mesh.mtl\n" + SQUARE_ELEMENTS + "usemtl mat\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
TEXTURE = np.arange(4 * 8 * 3, dtype=np.uint8).reshape(4, 8, 3)


def png_bytes(pixels: np.ndarray | Image.Image) -> bytes:
    image = pixels if isinstance(pixels, Image.Image) else Image.fromarray(pixels)
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


def write_obj_asset(
    folder: Path,
    obj: str = QUAD_OBJ,
    mtl: str = "newmtl mat\nmap_Kd tex.png\n",
    texture: np.ndarray | Image.Image = TEXTURE,
) -> Path:
    """mesh.obj + mesh.mtl + tex.png in ``folder``; returns the OBJ path."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "mesh.obj").write_text(obj)
    (folder / "mesh.mtl").write_text(mtl)
    (folder / "tex.png").write_bytes(png_bytes(texture))
    return folder / "mesh.obj"


def data_uri(blob: bytes, mime: str) -> str:
    return f"data:{mime};base64," + base64.b64encode(blob).decode()


def one_primitive_scene() -> dict:
    """The part of a glTF document every hand-written test asset shares: one scene, one node,
    one mesh whose one primitive reads accessors 0 (POSITION), 1 (TEXCOORD_0), 2 (indices) and
    material 0."""
    return {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [
            {
                "primitives": [
                    {"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}
                ]
            }
        ],
    }


def write_gltf(
    folder: Path,
    gltf_uvs: np.ndarray,
    texture: np.ndarray = TEXTURE,
    material: dict | None = None,
    buffer_uri: str | None = None,
    image_uri: str | None = None,
    second_image_uri: str | None = None,
) -> Path:
    """A one-triangle glTF written by hand (not by trimesh); UVs in glTF's convention.

    ``buffer_uri``/``image_uri`` name external files (not written) instead of data URIs;
    ``second_image_uri`` adds texture 1 showing that file.
    """
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
    indices = np.array([0, 1, 2], dtype=np.uint32)
    blob = positions.tobytes() + gltf_uvs.astype(np.float32).tobytes() + indices.tobytes()
    views = [(0, 36), (36, 24), (60, 12)]
    material = material or {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}
    doc = {
        **one_primitive_scene(),
        "materials": [material],
        "textures": [{"source": 0}, {"source": 1}][: 2 if second_image_uri else 1],
        "images": [{"uri": image_uri or data_uri(png_bytes(texture), "image/png")}]
        + ([{"uri": second_image_uri}] if second_image_uri else []),
        "buffers": [
            {"byteLength": len(blob), "uri": buffer_uri or data_uri(blob, "application/gltf")}
        ],
        "bufferViews": [{"buffer": 0, "byteOffset": o, "byteLength": n} for o, n in views],
        "accessors": [
            {"bufferView": 0, "componentType": FLOAT, "count": 3, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": FLOAT, "count": 3, "type": "VEC2"},
            {"bufferView": 2, "componentType": UNSIGNED_INT, "count": 3, "type": "SCALAR"},
        ],
    }  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "mesh.gltf"
    path.write_text(json.dumps(doc))
    return path


def corner_table(mesh: TexturedMesh) -> list[tuple]:
    """Faces as sorted (positions, UVs, material name) rows: compares meshes up to order."""
    rows = []
    for face, material in zip(mesh.faces, mesh.face_material, strict=True):
        corners = tuple(tuple(np.round(np.r_[mesh.positions[v], mesh.uvs[v]], 6)) for v in face)
        rows.append((corners, mesh.materials[material].name))
    return sorted(rows)


def assert_same_mesh(a: TexturedMesh, b: TexturedMesh) -> None:
    """Identical geometry, UVs (1e-6), normals, materials and textures (exact)."""
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_allclose(a.uvs, b.uvs, atol=1e-6, rtol=0)
    np.testing.assert_allclose(a.normals, b.normals, atol=1e-6)
    np.testing.assert_array_equal(a.vertex_to_point, b.vertex_to_point)
    np.testing.assert_array_equal(a.face_material, b.face_material)
    assert [m.name for m in a.materials] == [m.name for m in b.materials]
    for ma, mb in zip(a.materials, b.materials, strict=True):
        np.testing.assert_allclose(ma.base_color_factor, mb.base_color_factor, atol=1e-6)
        if ma.base_color_texture is None:
            assert mb.base_color_texture is None
        else:
            np.testing.assert_array_equal(ma.base_color_texture, mb.base_color_texture)


def mesh_of(
    positions: np.ndarray,
    faces: np.ndarray,
    uvs: np.ndarray,
    face_material: np.ndarray,
    materials: list[Material],
    vertex_to_point: np.ndarray | None = None,
) -> TexturedMesh:
    """A mesh of these arrays, its vertex normals computed (points welded by position unless
    ``vertex_to_point`` is given)."""
    points = weld_points(positions) if vertex_to_point is None else vertex_to_point
    return TexturedMesh(
        positions=positions,
        faces=faces,
        uvs=uvs,
        normals=compute_vertex_normals(positions, faces, points),
        vertex_to_point=points,
        face_material=np.asarray(face_material),
        materials=materials,
    )


def two_material_mesh() -> TexturedMesh:
    """Two quads sharing an edge: one textured, one plain colour (factor only)."""
    positions = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=np.float32
    )
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5], [0.5, 0.5]], dtype=np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]], dtype=np.int64)
    materials = [
        Material("painted", TEXTURE),
        Material("plain", None, np.array([0.2, 0.4, 0.6, 1.0], dtype=np.float32)),
    ]
    return mesh_of(positions, faces, uvs, np.array([0, 0, 1, 1]), materials)


def signed_volume(mesh: TexturedMesh) -> float:
    corners = mesh.positions.astype(np.float64)[mesh.faces]
    return float(np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum())


HALF = 1 / math.sqrt(2)  # a quad whose corners sit at distance 1: normalisation is the identity


def quad_mesh(texture: np.ndarray, factor=(1.0, 1.0, 1.0, 1.0)) -> TexturedMesh:
    """A unit quad facing +z, its texture over the whole of it."""
    positions = np.array([[-HALF, -HALF, 0], [HALF, -HALF, 0], [HALF, HALF, 0], [-HALF, HALF, 0]])
    return TexturedMesh(
        positions=positions.astype(np.float32),
        faces=np.array([[0, 1, 2], [0, 2, 3]]),
        uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float32),
        normals=np.tile([0.0, 0.0, 1.0], (4, 1)).astype(np.float32),
        vertex_to_point=np.arange(4),
        face_material=np.zeros(2, dtype=np.int64),
        materials=[Material("quad", texture, np.asarray(factor, dtype=np.float32))],
    )


def three_material_demo() -> TexturedMesh:
    """The small demo asset with its faces dealt to a textured, a tinted (same texture) and an
    untextured material in turn."""
    from geoscaler.procedural import demo_mesh

    mesh = demo_mesh(subdivisions=4, texture_size=32)
    mesh.face_material = np.arange(len(mesh.faces)) % 3
    mesh.materials = [
        mesh.materials[0],
        Material("tinted", mesh.materials[0].base_color_texture, np.array([1, 0.5, 0.25, 1])),
        Material("plain", None, np.array([0.2, 0.4, 0.6, 1.0], dtype=np.float32)),
    ]
    return mesh


def ribbon_mesh(quads: int = 16, texture_size: int = 128) -> TexturedMesh:
    """A strip of ``quads`` unit quads along x, one UV chart 0.9 long and 0.1 wide across the
    middle of a random texture: a chart that spans its atlas, as a scan's longest ones do."""
    x = np.repeat(np.arange(quads + 1, dtype=np.float64), 2)
    y = np.tile([0.0, 1.0], quads + 1)
    positions = np.stack([x, y, np.zeros_like(x)], axis=1).astype(np.float32)
    uvs = np.stack([0.05 + 0.9 * x / quads, 0.45 + 0.1 * y], axis=1).astype(np.float32)
    first = 2 * np.arange(quads)[:, None]
    faces = np.concatenate([first + [0, 2, 3], first + [0, 3, 1]]).astype(np.int64)
    rng = np.random.default_rng(3)
    texture = rng.integers(0, 256, (texture_size, texture_size, 3), dtype=np.uint8)
    return mesh_of(
        positions, faces, uvs, np.zeros(len(faces), np.int64), [Material("ribbon", texture)]
    )


def pbr_demo(subdivisions: int = 8, texture_size: int = 128, seed: int = 7) -> TexturedMesh:
    """The demo asset with a bumpy normal map (random tilts of up to about 30 degrees) and a
    metallic-roughness map of random texels, both ``texture_size`` square."""
    from geoscaler.procedural import demo_mesh

    mesh = demo_mesh(subdivisions=subdivisions, texture_size=texture_size)
    rng = np.random.default_rng(seed)
    shape = (texture_size, texture_size, 3)
    normal = rng.integers(60, 196, shape, dtype=np.uint8)
    normal[..., 2] = 230
    packed = rng.integers(0, 256, shape, dtype=np.uint8)
    mesh.materials[0].maps.update(normalTexture=normal, metallicRoughnessTexture=packed)
    return mesh
