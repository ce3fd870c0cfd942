"""Every map, attribute and reference of an asset survives loading and saving.

The data model (``Material.maps``, ``sources``, ``TexturedMesh.images``/``with_images``,
``attributes``), what is written (each distinct image once, unchanged ones byte for byte,
changed ones in their own format), and what is refused because it cannot be kept.
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from io_assets import (
    CLEAR_CLAMP,
    CLEARCOAT,
    COLORS_BYTES,
    COLORS_FLOAT,
    NORMAL,
    ORM,
    SECOND_UVS,
    TANGENTS,
    TRANSFORM,
    WOOD,
    document,
    encode,
    rich_document,
    rich_gltf,
    smooth,
    written_images,
)
from mesh_support import (
    QUAD_OBJ,
    TEXTURE,
    png_bytes,
    two_material_mesh,
    write_gltf,
    write_obj_asset,
)
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.io import (
    JPEG_QUALITY,
    encoded_image,
    image_to_texture,
    load_mesh,
    output_files,
    save_mesh,
    written_image,
)
from geoscaler.mesh import SourceImage, TextureError

BASE = "baseColorTexture"
CLEARCOAT_SLOT = "KHR_materials_clearcoat/clearcoat"


def decoded(data: bytes) -> np.ndarray:
    return image_to_texture(Image.open(io.BytesIO(data)))


@pytest.fixture
def rich(tmp_path: Path):
    return load_mesh(rich_gltf(tmp_path / "in"))


# ----------------------------------------------------------------------------- the model


def test_every_map_is_decoded_once_and_shared_by_identity(rich):
    painted, coated = rich.materials
    images = rich.images()
    assert [places for _, places in images] == [
        [(0, BASE), (1, BASE)],  # one file behind two image entries
        [(0, "normalTexture"), (1, f"{CLEARCOAT_SLOT}NormalTexture")],
        [(0, "occlusionTexture"), (1, "metallicRoughnessTexture"),
         (1, f"{CLEARCOAT_SLOT}RoughnessTexture")],
        [(1, f"{CLEARCOAT_SLOT}Texture")],
    ]  # fmt: skip
    wood, normal, orm, clearcoat = (pixels for pixels, _ in images)
    assert painted.base_color_texture is wood and coated.base_color_texture is wood
    assert coated.maps[f"{CLEARCOAT_SLOT}NormalTexture"] is normal
    for pixels, data in zip((wood, normal, orm, clearcoat), (WOOD, NORMAL, ORM, CLEARCOAT),
                            strict=True):  # fmt: skip
        np.testing.assert_array_equal(pixels, decoded(data))
        assert not pixels.flags.writeable
    source = painted.sources[BASE]
    assert coated.sources[BASE] is source and source.pixels is wood
    assert (source.mime, source.data, source.name) == ("image/jpeg", WOOD, "wood")
    assert coated.sources[f"{CLEARCOAT_SLOT}Texture"].name == "clearcoat"  # embedded: its name
    assert painted.sources["normalTexture"].mime == "image/png"


def test_with_images_replaces_every_place_an_array_is_shown(rich):
    wood = rich.materials[0].base_color_texture
    small = np.zeros((4, 4, 3), np.uint8)
    edited = rich.with_images({id(wood): small})
    assert [m.base_color_texture is small for m in edited.materials] == [True, True]
    assert edited.materials[0].maps["normalTexture"] is rich.materials[0].maps["normalTexture"]
    assert edited.materials[0].sources is rich.materials[0].sources  # sources unchanged
    assert rich.materials[0].base_color_texture is wood  # the original is not touched
    assert [places for _, places in edited.images()] == [places for _, places in rich.images()]
    with pytest.raises(TextureError, match="replacement of baseColorTexture of material 0"):
        rich.with_images({id(wood): np.zeros((4, 4), np.uint8)})


def test_attributes_are_read_welded_and_exact(rich):
    assert list(rich.attributes) == ["TANGENT", "COLOR_0", "TEXCOORD_1"]
    np.testing.assert_array_equal(
        rich.attributes["TANGENT"], np.concatenate([TANGENTS["painted"], TANGENTS["coated"]])
    )
    expected_colors = np.concatenate(
        [COLORS_BYTES / np.float64(255), np.c_[COLORS_FLOAT, np.ones(4)]]
    ).astype(np.float32)
    np.testing.assert_array_equal(rich.attributes["COLOR_0"], expected_colors)
    second = SECOND_UVS.astype(np.float64)
    second[:, 1] = 1 - second[:, 1]  # flipped into the OpenGL convention, as TEXCOORD_0
    np.testing.assert_array_equal(rich.attributes["TEXCOORD_1"], np.tile(second, (2, 1)))


def test_vertices_that_differ_only_in_an_attribute_stay_apart(tmp_path: Path):
    doc, blob = rich_document()
    # The second quad on top of the first, same UVs: only TANGENT and COLOR_0 tell them apart.
    second = doc["meshes"][0]["primitives"][1]["attributes"]
    second["POSITION"] = doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
    rich_gltf(tmp_path)
    (tmp_path / "rich.gltf").write_text(json.dumps(doc))
    mesh = load_mesh(tmp_path / "rich.gltf")
    assert len(mesh.positions) == 8 and mesh.num_points == 4


# ----------------------------------------------------------------------------- writing


@pytest.mark.parametrize("suffix", [".gltf", ".glb"])
def test_a_shared_texture_is_written_once_and_unchanged_maps_byte_for_byte(
    rich, tmp_path: Path, suffix: str
):
    out = tmp_path / "out" / f"out{suffix}"
    out.parent.mkdir()
    written = save_mesh(rich, out)
    doc = document(out)
    assert written_images(out) == [WOOD, NORMAL, ORM, CLEARCOAT]  # once each, bytes as read
    assert [i["mimeType"] for i in doc["images"]] == ["image/jpeg", *["image/png"] * 2,
                                                      "image/jpeg"]  # fmt: skip
    bases = [m["pbrMetallicRoughness"]["baseColorTexture"]["index"] for m in doc["materials"]]
    assert [doc["textures"][t]["source"] for t in bases] == [0, 0]
    if suffix == ".gltf":
        names = ["out_wood.jpg", "out_normal.png", "out_orm.png", "out_clearcoat.jpg"]
        assert [p.name for p in written] == [*names, "out.bin", "out.gltf"]
    assert output_files(rich, out) == written


def test_a_changed_jpeg_map_is_written_as_jpeg_and_a_png_map_as_png(rich, tmp_path: Path):
    wood, normal = (pixels for pixels, _ in rich.images()[:2])
    small_wood = np.ascontiguousarray(wood[::2, ::2])
    small_normal = np.ascontiguousarray(normal[::2, ::2])
    edited = rich.with_images({id(wood): small_wood, id(normal): small_normal})
    written = save_mesh(edited, tmp_path / "out.gltf")
    assert [p.name for p in written][:2] == ["out_wood.jpg", "out_normal.png"]
    jpeg = Image.open(written[0])
    assert jpeg.format == "JPEG" and jpeg.size == (8, 8)
    expected, mime = encoded_image(small_wood, rich.materials[0].sources[BASE], None)
    assert written[0].read_bytes() == expected
    assert written_image(edited, small_wood, tmp_path / "out.gltf") == (len(expected), mime)
    assert written_images(tmp_path / "out.gltf")[2:] == [ORM, CLEARCOAT]  # unchanged: as read
    reloaded = load_mesh(written[-1])
    assert [m.base_color_texture.shape for m in reloaded.materials] == [(8, 8, 3)] * 2
    np.testing.assert_array_equal(reloaded.materials[0].maps["normalTexture"], small_normal)
    np.testing.assert_array_equal(reloaded.materials[0].base_color_texture, decoded(expected))


@pytest.mark.parametrize("suffix", [".gltf", ".glb"])
def test_tangents_colours_and_second_uvs_round_trip_exactly(rich, tmp_path: Path, suffix: str):
    again = load_mesh(save_mesh(rich, tmp_path / f"out{suffix}")[-1])
    assert list(again.attributes) == list(rich.attributes)
    for name, values in rich.attributes.items():
        np.testing.assert_array_equal(again.attributes[name], values, err_msg=name)
    np.testing.assert_array_equal(again.positions, rich.positions)
    doc = document(tmp_path / f"out{suffix}")
    accessors = doc["accessors"]
    for primitive in doc["meshes"][0]["primitives"]:
        kinds = {n: accessors[a]["type"] for n, a in primitive["attributes"].items()}
        assert kinds == {"POSITION": "VEC3", "NORMAL": "VEC3", "TEXCOORD_0": "VEC2",
                         "TANGENT": "VEC4", "COLOR_0": "VEC4", "TEXCOORD_1": "VEC2"}  # fmt: skip


def test_texcoord_1_transforms_samplers_and_extensions_survive(rich, tmp_path: Path):
    save_mesh(rich, tmp_path / "out.gltf")
    doc = json.loads((tmp_path / "out.gltf").read_text())
    painted, coated = doc["materials"]
    assert painted["occlusionTexture"] == {"texCoord": 1, "strength": 0.75, "index": 2}
    assert painted["normalTexture"] == {"scale": 0.5, "extensions": TRANSFORM, "index": 1}
    assert doc["textures"][1] == {"source": 1, "sampler": 1}
    assert doc["samplers"][1] == CLEAR_CLAMP
    clearcoat = coated["extensions"]["KHR_materials_clearcoat"]
    assert clearcoat == {
        "clearcoatFactor": 1.0,
        "clearcoatTexture": {"index": 3},
        "clearcoatRoughnessTexture": {"index": 2},
        "clearcoatNormalTexture": {"scale": 0.8, "index": 1},
    }
    assert doc["textures"][2] == {"source": 2} and doc["textures"][3] == {"source": 3}
    assert doc["extensionsUsed"] == ["KHR_materials_clearcoat", "KHR_texture_transform"]
    assert "extensionsRequired" not in doc
    reloaded = load_mesh(tmp_path / "out.gltf")
    assert reloaded.materials[0].properties == rich.materials[0].properties


def test_webp_goes_through_ext_texture_webp_and_obj_refuses_it(rich, tmp_path: Path):
    save_mesh(rich, tmp_path / "out.glb", image_format="webp")
    doc = document(tmp_path / "out.glb")
    assert doc["extensionsRequired"] == ["EXT_texture_webp"]
    assert "EXT_texture_webp" in doc["extensionsUsed"]
    assert {i["mimeType"] for i in doc["images"]} == {"image/webp"}
    assert all(set(t) <= {"extensions", "sampler"} for t in doc["textures"])
    reloaded = load_mesh(tmp_path / "out.glb")
    assert reloaded.materials[0].sources[BASE].mime == "image/webp"
    # PNG sources are written as lossless WebP: the same texels come back.
    np.testing.assert_array_equal(reloaded.materials[0].maps["normalTexture"],
                                  rich.materials[0].maps["normalTexture"])  # fmt: skip
    with pytest.raises(GeoscalerError, match="OBJ/MTL readers do not read WebP"):
        save_mesh(rich, tmp_path / "out.obj", image_format="webp")


def test_the_encoder_rules():
    rgb = smooth(8, 8, 5)
    source = SourceImage(rgb, "image/jpeg", encode(rgb, "JPEG"), "wood")
    assert encoded_image(rgb, source, None) == (source.data, "image/jpeg")  # unchanged
    assert encoded_image(rgb, source, "jpeg") == (source.data, "image/jpeg")  # the same asked
    copy = rgb.copy()
    data, mime = encoded_image(copy, source, None)
    assert mime == "image/jpeg" and data != source.data
    assert encoded_image(copy, source, None)[0] is data  # memoised, not encoded twice
    expected = io.BytesIO()
    Image.fromarray(copy).save(expected, "JPEG", quality=JPEG_QUALITY, subsampling=2,
                               optimize=True)  # fmt: skip
    assert data == expected.getvalue()
    copy[0, 0] = 0  # changed in place: encoded again
    assert encoded_image(copy, source, None)[0] != data
    rgba = np.dstack([rgb, np.full((8, 8), 7, np.uint8)])
    assert encoded_image(rgba, source, None)[1] == "image/png"  # never alpha in a JPEG
    assert encoded_image(rgba, None, "jpeg")[1] == "image/png"
    grey = np.repeat(rgb[..., :1], 3, axis=2)
    png, mime = encoded_image(grey, None, None)
    assert mime == "image/png" and Image.open(io.BytesIO(png)).mode == "L"
    np.testing.assert_array_equal(decoded(png), grey)
    with pytest.raises(ValueError, match="image_format"):
        encoded_image(rgb, None, "gif")


def test_specular_glossiness_diffuse_is_the_base_colour_and_written_as_both(tmp_path: Path):
    gloss = "KHR_materials_pbrSpecularGlossiness"
    material = {"extensions": {gloss: {"diffuseTexture": {"index": 0},
                                       "diffuseFactor": [1, 0.5, 0.25, 1]}}}  # fmt: skip
    mesh = load_mesh(write_gltf(tmp_path / "in", np.zeros((3, 2)), material=material))
    loaded = mesh.materials[0]
    assert loaded.base_color_texture is loaded.maps[f"{gloss}/diffuseTexture"]
    np.testing.assert_array_equal(loaded.base_color_factor, np.float32([1, 0.5, 0.25, 1]))
    save_mesh(mesh, tmp_path / "out.gltf")
    written = json.loads((tmp_path / "out.gltf").read_text())["materials"][0]
    assert written["pbrMetallicRoughness"]["baseColorTexture"] == {"index": 0}
    assert written["extensions"][gloss]["diffuseTexture"] == {"index": 0}


# ----------------------------------------------------------------------------- OBJ


def test_obj_keeps_its_maps_keywords_options_and_statements(tmp_path: Path):
    mtl = ("newmtl mat\nKd 1 1 1\nKs 0.5 0.5 0.5\nNs 20\nKe 0.25 0.5 0.75\nillum 2\n"
           "map_Kd tex.png\nnorm -bm 0.5 n.png\nmap_Ke e.png\nmap_Ks s.jpg\n")  # fmt: skip
    path = write_obj_asset(tmp_path / "in", mtl=mtl)
    inputs = {"n.png": png_bytes(TEXTURE[::-1]), "e.png": png_bytes(TEXTURE[:, ::-1]),
              "s.jpg": encode(smooth(8, 8, 6), "JPEG")}  # fmt: skip
    for name, data in inputs.items():
        (tmp_path / "in" / name).write_bytes(data)
    mesh = load_mesh(path)
    material = mesh.materials[0]
    assert list(material.maps) == ["normalTexture", "emissiveTexture", "mtl:map_Ks"]
    assert material.properties["emissiveFactor"] == [0.25, 0.5, 0.75]
    written = save_mesh(mesh, tmp_path / "out.obj")
    assert [p.name for p in written] == ["out_tex.png", "out_n.png", "out_e.png", "out_s.jpg",
                                         "out.mtl", "out.obj"]  # fmt: skip
    assert (tmp_path / "out.mtl").read_text().splitlines()[2:] == [
        "newmtl mat", "Kd 1 1 1", "Ke 0.25 0.5 0.75", "Ks 0.5 0.5 0.5", "Ns 20", "illum 2",
        "map_Kd out_tex.png", "norm -bm 0.5 out_n.png", "map_Ke out_e.png",
        "map_Ks out_s.jpg",
    ]  # fmt: skip
    for name, data in {"tex.png": png_bytes(TEXTURE), **inputs}.items():
        assert (tmp_path / f"out_{name}").read_bytes() == data
    again = load_mesh(written[-1]).materials[0]
    assert list(again.maps) == list(material.maps)
    for slot, pixels in material.maps.items():
        np.testing.assert_array_equal(again.maps[slot], pixels)
    (tmp_path / "gltf").mkdir()
    with pytest.warns(UserWarning, match="glTF cannot express its mtl:map_Ks"):
        save_mesh(mesh, tmp_path / "gltf" / "out.gltf")
    doc = json.loads((tmp_path / "gltf" / "out.gltf").read_text())
    assert set(doc["materials"][0]) == {"name", "pbrMetallicRoughness", "normalTexture",
                                        "emissiveTexture", "emissiveFactor"}  # fmt: skip


def test_an_obj_texture_shared_by_two_materials_is_written_once(tmp_path: Path):
    obj = QUAD_OBJ.replace("f 1/1 3/3 4/4", "usemtl other\nf 1/1 3/3 4/4")
    mtl = "newmtl mat\nmap_Kd tex.png\nnewmtl other\nmap_Kd tex.png\nmap_Ks tex.png\n"
    mesh = load_mesh(write_obj_asset(tmp_path / "in", obj=obj, mtl=mtl))
    assert [places for _, places in mesh.images()] == [[(0, BASE), (1, BASE), (1, "mtl:map_Ks")]]
    written = save_mesh(mesh, tmp_path / "out.obj")
    assert [p.name for p in written] == ["out_tex.png", "out.mtl", "out.obj"]


# ----------------------------------------------------------------------------- refused


def edited_rich(folder: Path, edit) -> Path:
    path = rich_gltf(folder)
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    return path


def add_attributes(*names: str):
    def edit(doc: dict) -> None:
        for name in names:
            doc["meshes"][0]["primitives"][0]["attributes"][name] = 0

    return edit


REFUSED = {
    "skin": (lambda d: (d.__setitem__("skins", [{"joints": [0]}]),
             d["nodes"][0].__setitem__("skin", 0)), "has a skin (skeletal animation"),
    "animation": (lambda d: d.__setitem__("animations", [{"channels": [], "samplers": []}]),
                  "has 1 animation(s)"),
    "morph-targets": (lambda d: d["meshes"][0]["primitives"][1].__setitem__(
        "targets", [{"POSITION": 0}]), "meshes[0].primitives[1] has morph targets"),
    "joints": (add_attributes("JOINTS_0", "WEIGHTS_0"), "attribute(s) JOINTS_0, WEIGHTS_0"),
    "third-uv-set": (add_attributes("TEXCOORD_2"), "attribute(s) TEXCOORD_2"),
    "second-colour": (add_attributes("COLOR_1", "_TEMPERATURE"), "COLOR_1, _TEMPERATURE"),
}  # fmt: skip


@pytest.mark.parametrize("name", list(REFUSED))
def test_what_cannot_be_kept_is_refused_naming_it(tmp_path: Path, name: str):
    edit, words = REFUSED[name]
    path = edited_rich(tmp_path, edit)
    with pytest.raises(GeoscalerError) as info:
        load_mesh(path)
    message = str(info.value)
    assert words in message and "cannot keep" in message and "rich.gltf" in message


def test_a_tangent_on_some_primitives_only_is_dropped_with_a_warning(tmp_path: Path):
    path = edited_rich(tmp_path, lambda d: d["meshes"][0]["primitives"][1]["attributes"]
                       .pop("TANGENT"))  # fmt: skip
    with pytest.warns(UserWarning, match="only some primitives have TANGENT"):
        mesh = load_mesh(path)
    assert list(mesh.attributes) == ["COLOR_0", "TEXCOORD_1"]


def test_model_checks_refuse_bad_attributes():
    mesh = two_material_mesh()
    mesh.attributes["COLOR_0"] = np.full((len(mesh.positions), 3), 2.0, np.float32)
    with pytest.raises(ValueError, match="COLOR_0 has values outside"):
        mesh.validate()
    mesh.attributes = {"TANGENT": np.zeros((len(mesh.positions), 4), np.float32)}
    with pytest.raises(ValueError, match="w components"):
        mesh.validate()
    mesh.attributes = {"JOINTS_0": np.zeros((len(mesh.positions), 4), np.float32)}
    with warnings.catch_warnings(), pytest.raises(ValueError, match="JOINTS_0"):
        mesh.validate()
