"""Texture slots: how a material's maps are named in glTF, in MTL and in output file names.

A slot is a glTF name: the core slots (:data:`TEXTURE_SLOTS`), an extension's texture field as
``"EXTENSION/field"`` (``"KHR_materials_clearcoat/clearcoatNormalTexture"``), or an MTL map
glTF has no slot for as ``"mtl:KEYWORD"`` (``"mtl:map_Ks"``; :data:`MTL_MAPS`).
"""

from __future__ import annotations

import re
from collections.abc import Iterator

from geoscaler.mesh import BASE_COLOR

TEXTURE_SLOTS = {
    BASE_COLOR: ("pbrMetallicRoughness", "baseColorTexture"),
    "metallicRoughnessTexture": ("pbrMetallicRoughness", "metallicRoughnessTexture"),
    "normalTexture": ("normalTexture",),
    "occlusionTexture": ("occlusionTexture",),
    "emissiveTexture": ("emissiveTexture",),
}
"""The core texture slots of a glTF material: slot name -> path of its texture-info object in
the material JSON. An extension's slot is at ``("extensions", EXTENSION, field)``."""
SPECULAR_GLOSSINESS = "KHR_materials_pbrSpecularGlossiness"
"""The archived workflow whose ``diffuseTexture`` is the base colour where a material has no
``baseColorTexture`` (the same image: it is written as both)."""
MTL_PREFIX = "mtl:"
MTL_PROPERTIES = "mtl"
"""The key of ``Material.properties`` under which the OBJ reader keeps what only MTL says:
``{"keywords": {slot: keyword}, "options": {slot: "-bm 0.5"}, "statements": ["Ns 10"]}``.
Not written to glTF."""
MTL_MAPS = {
    "map_Kd": BASE_COLOR,
    "norm": "normalTexture",
    "map_bump": "normalTexture",
    "bump": "normalTexture",
    "map_Ke": "emissiveTexture",
    **{k: MTL_PREFIX + k for k in ("map_Ka", "map_Ks", "map_Ns", "map_d", "disp", "decal")},
    **{k: MTL_PREFIX + k for k in ("refl", "map_Pr", "map_Pm", "map_Ps")},
}
"""MTL map keywords GeoScaler reads and writes -> slot. A ``bump``/``map_bump`` (or ``norm``)
image in grey is a height map, not a normal map: its slot is then ``"mtl:" + keyword``."""
MTL_KEYWORDS = {BASE_COLOR: "map_Kd", "normalTexture": "norm", "emissiveTexture": "map_Ke"}
"""The keyword each slot MTL can express is written with, unless the file read said another
(``properties["mtl"]["keywords"]``); ``"mtl:KEYWORD"`` slots are written with KEYWORD."""


def slot_path(slot: str) -> tuple[str, ...]:
    """Where a glTF texture slot's texture-info object is in the material JSON."""
    if slot in TEXTURE_SLOTS:
        return TEXTURE_SLOTS[slot]
    extension, _, name = slot.partition("/")
    return ("extensions", extension, name)


def slot_info(material_properties: dict, slot: str) -> dict:
    """The glTF texture-info object of ``slot`` in a material's properties (:attr:`Material.
    properties`; the base colour's under ``pbrMetallicRoughness``), empty when absent."""
    node = material_properties
    for key in slot_path(slot):
        node = node.get(key) if isinstance(node, dict) else None
    return node if isinstance(node, dict) else {}


def in_gltf(slot: str) -> bool:
    """Whether glTF can hold the slot (every slot but MTL's own)."""
    return not slot.startswith(MTL_PREFIX)


def in_mtl(slot: str) -> bool:
    """Whether MTL can hold the slot: base colour, normal, emissive and MTL's own maps."""
    return slot in MTL_KEYWORDS or slot.startswith(MTL_PREFIX)


def texture_infos(material: dict) -> Iterator[tuple[str, dict, str]]:
    """``(slot, parent object, key)`` of every texture-info object of a material JSON: the core
    slots, then each extension's top-level fields named ``...Texture``, in file order."""
    for slot, keys in TEXTURE_SLOTS.items():
        parent = material.get(keys[0]) if len(keys) == 2 else material
        if isinstance(parent, dict) and isinstance(parent.get(keys[-1]), dict):
            yield slot, parent, keys[-1]
    extensions = material.get("extensions", {})
    for name, extension in extensions.items() if isinstance(extensions, dict) else ():
        for key, info in extension.items() if isinstance(extension, dict) else ():
            if key.endswith("Texture") and isinstance(info, dict):
                yield f"{name}/{key}", extension, key


_FILE_NAMES = {
    BASE_COLOR: "basecolor",
    "metallicRoughnessTexture": "metallicroughness",
    "normalTexture": "normal",
    "occlusionTexture": "occlusion",
    "emissiveTexture": "emissive",
}


def slot_file_name(slot: str) -> str:
    """The part of an output file name that says the slot, for images made without a source:
    ``basecolor``, ``normal``, ``clearcoatnormal``, ``map_ks``..."""
    if slot in _FILE_NAMES:
        return _FILE_NAMES[slot]
    field = slot.rpartition("/")[2].removeprefix(MTL_PREFIX).removesuffix("Texture")
    return re.sub(r"[^a-z0-9_]+", "", field.lower()) or "map"
