"""The asset as it ships: every map of every material at the size asked for its class.

The job's method makes the base colours (optimised through the renderer, or a filter); every
other map is resized here by what it holds (:func:`geoscaler.resize.maps.resize_map`: colour in
linear light, normals as vectors, data channel by channel) at the size its class's rule gives
(:class:`geoscaler.resize.sizes.SizePlan`), from the full-resolution original. A texture that
several slots or materials show is resized once and stays shared (sharing is by array identity, as
the loader gives it); one the rule does not shrink ships as it came, bytes and all.
"""

from __future__ import annotations

from collections.abc import Container, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from PIL import Image

from geoscaler.io.images import IMAGE_FORMATS, encoding_seconds
from geoscaler.io.slots import slot_info
from geoscaler.mesh import Material, SourceImage, TexturedMesh
from geoscaler.methods import MethodResult
from geoscaler.methods.repacked import oversampling
from geoscaler.protocol import BYTES_PER_TEXEL
from geoscaler.render.lit import METALLIC_ROUGHNESS, NORMAL
from geoscaler.resize.filters import resize_channels
from geoscaler.resize.maps import (
    METHOD_NAMES,
    normal_shortening,
    resize_map,
    texture_class,
    toksvig_roughness,
)
from geoscaler.resize.sizes import COLOR, SizePlan
from geoscaler.uv.atlas import Atlas
from geoscaler.uv.bake import BAKE_SECONDS_PER_SAMPLE, ChartMaps, bake

BASE_COLOR = "baseColorTexture"
LOSSLESS = "image/png"


@dataclass
class ShippedMap:
    """One distinct texture of the asset, before and after.

    Attributes:
        slots: ``"material/slot"`` of every place that shows it.
        kind: its class (:data:`geoscaler.resize.sizes.TEXTURE_CLASSES`).
        method: how it was made ("kept" when its rule does not shrink it).
        size_before, size_after: ``(h, w)`` texels.
        bytes_before: bytes of its encoded image in the input (0: unknown).
        bytes_after: bytes of its encoded image in the output (set once written).
        pixels: the array that ships.
        source: how the input image came in (its format is the output's, unless asked).
        format_before: the input image's MIME type ("" where it was made in code).
        format_after: the output image's MIME type (set once written).
    """

    slots: list[str]
    kind: str
    method: str
    size_before: tuple[int, int]
    size_after: tuple[int, int]
    bytes_before: int
    pixels: np.ndarray
    source: SourceImage | None = None
    bytes_after: int = 0
    format_before: str = ""
    format_after: str = ""

    @property
    def memory_before(self) -> int:
        """Texture memory of the input map, bytes (protocol: 4 bytes a texel, no mips)."""
        return self.size_before[0] * self.size_before[1] * BYTES_PER_TEXEL

    @property
    def memory_after(self) -> int:
        """Texture memory of the shipped map, bytes."""
        return self.size_after[0] * self.size_after[1] * BYTES_PER_TEXEL


def alpha_cutoff(material: Material) -> float | None:
    """glTF ``alphaCutoff`` where the material's ``alphaMode`` is ``MASK`` (default 0.5)."""
    if material.properties.get("alphaMode") != "MASK":
        return None
    return float(material.properties.get("alphaCutoff", 0.5))


def with_lossless_formats(mesh: TexturedMesh, plan: SizePlan) -> TexturedMesh:
    """``mesh`` with the images marked PNG that must ship lossless (sharing kept):

    - every base colour: it ships as the job validated it, 8-bit, and a lossy re-encoding (a
      JPEG or WebP input's format) would ship something else, measurably worse;
    - every normal or data map the plan makes smaller: JPEG's colour transform and chroma
      subsampling mix the channels of a packed map (occlusion, roughness, metallic) and the
      components of a normal, which lit renders show (docs/protocol.md, protocol 2).

    Colour maps other than the base colour (emissive...) and maps the plan keeps at their
    size keep their input's format (a kept map ships its input's very bytes)."""
    marked: dict[int, SourceImage] = {}
    materials = []
    for material in mesh.materials:
        sources = dict(material.sources)
        for slot, pixels in material.textures().items():
            source = sources.get(slot)
            if source is None or source.mime == LOSSLESS or not _ships_lossless(slot, pixels, plan):
                continue
            sources[slot] = marked.setdefault(id(source), replace(source, mime=LOSSLESS))
        materials.append(replace(material, sources=sources))
    return replace(mesh, materials=materials)


def _ships_lossless(slot: str, pixels: np.ndarray, plan: SizePlan) -> bool:
    if slot == BASE_COLOR:
        return True
    kind = texture_class(slot)
    return kind != COLOR and plan.rule(kind).size(*pixels.shape[:2]) != pixels.shape[:2]


def relayout_maps(
    mesh: TexturedMesh, atlas: Atlas, plan: SizePlan
) -> dict[int, tuple[np.ndarray, str]]:
    """Every map other than base colour that the repacked materials read on their first UV
    set, baked into the new layout at its class's size (:func:`geoscaler.uv.bake.bake`, from
    the full-resolution original): ``id(original array) -> (baked array, method)``. Maps on
    ``TEXCOORD_1`` keep their layout. Normal maps are vectors re-baked as they are: charts
    of a normal-mapped material only move and scale (:func:`geoscaler.uv.atlas.has_normal_map`),
    so tangent frames keep their directions."""
    made: dict[int, tuple[np.ndarray, str]] = {}
    for group in atlas.groups:
        faces = np.isin(mesh.face_material, group) & (atlas.chart_of_face >= 0)
        layout = ChartMaps(atlas.uvs[faces], atlas.chart_of_face[faces], atlas.linear, atlas.offset)
        for slot, pixels in _relaid_maps(mesh, group, made):
            kind = texture_class(slot)
            side, oversample = _relayout_grid(pixels, kind, plan)
            baked, _ = bake(pixels, kind, layout, side, oversample)
            made[id(pixels)] = baked, f"re-baked into the new UV layout ({kind})"
    return made


def _relaid_maps(
    mesh: TexturedMesh, materials: Iterable[int], done: Container[int] = ()
) -> Iterator[tuple[str, np.ndarray]]:
    """``(slot, pixels)`` of every map other than base colour that ``materials`` read on their
    first UV set, each array once, none whose ``id`` is in ``done``."""
    seen: set[int] = set()
    for index in materials:
        material = mesh.materials[index]
        for slot, pixels in material.maps.items():
            if id(pixels) in seen or id(pixels) in done:
                continue
            if slot_info(material.properties, slot).get("texCoord", 0):
                continue
            seen.add(id(pixels))
            yield slot, pixels


def _relayout_grid(pixels: np.ndarray, kind: str, plan: SizePlan) -> tuple[int, int]:
    """``(texels per side, samples per texel side)`` of the map ``pixels`` re-baked into a
    new layout at its class's size."""
    side = plan.rule(kind).size(*pixels.shape[:2])[0]
    return side, oversampling(pixels, side)


RESIZE_SECONDS_PER_TEXEL = 0.06e-6
"""An upper bound on the seconds :func:`ship_asset` takes to resize a normal or data map, per
texel of the original, its roughness widened by Toksvig included: 0.04 to 0.05 microseconds on the
2-core AMD dev machine (normal and metallic-roughness maps of 1024 and 4096 a side)."""


def export_seconds(mesh: TexturedMesh, plan: SizePlan, image_format: str | None) -> float:
    """An upper bound on the seconds :func:`ship_asset` and the encoding of every image take
    for ``mesh`` on the machine the rates were measured on
    (:func:`~geoscaler.io.images.encoding_seconds`, :data:`RESIZE_SECONDS_PER_TEXEL`): every
    image encoded at its class's size, every smaller map other than a base colour resized
    from its original. A map kept at its size in its own format ships its input's bytes:
    nothing to encode."""
    seconds = 0.0
    for pixels, places in mesh.images():
        material, slot = places[0]
        kind = COLOR if slot == BASE_COLOR else texture_class(slot)
        size = plan.rule(kind).size(*pixels.shape[:2])
        source = mesh.materials[material].sources.get(slot)
        as_it_came = image_format is None or (
            source is not None and IMAGE_FORMATS[image_format] == source.mime
        )
        if size == pixels.shape[:2] and slot != BASE_COLOR and as_it_came:
            continue
        seconds += encoding_seconds(*size)
        if slot != BASE_COLOR and size != pixels.shape[:2]:
            seconds += pixels.shape[0] * pixels.shape[1] * RESIZE_SECONDS_PER_TEXEL
    return seconds


def relayout_seconds(mesh: TexturedMesh, plan: SizePlan) -> float:
    """An upper bound on :func:`relayout_maps`'s seconds should every material with a base
    colour move to a new layout: every other map it reads on its first UV set baked at its
    class's size (:data:`~geoscaler.uv.bake.BAKE_SECONDS_PER_SAMPLE`)."""
    textured = [i for i, m in enumerate(mesh.materials) if m.base_color_texture is not None]
    samples = 0
    for slot, pixels in _relaid_maps(mesh, textured):
        side, oversample = _relayout_grid(pixels, texture_class(slot), plan)
        samples += (side * oversample) ** 2
    return samples * BAKE_SECONDS_PER_SAMPLE


def ship_asset(
    mesh: TexturedMesh,
    plan: SizePlan,
    base_colors: Sequence[np.ndarray | None],
    base_color_method: str,
    premade: Mapping[int, tuple[np.ndarray, str]] | None = None,
    toksvig: bool = True,
) -> tuple[TexturedMesh, list[ShippedMap]]:
    """The mesh as it ships, and what happened to each of its textures.

    Args:
        mesh: the loaded asset (its textures the originals).
        plan: the size rule of each texture class.
        base_colors: per material the method's ``(h, w, C)`` uint8 base colour (None: the
            material has none); materials sharing one base-colour image get the first one's.
        base_color_method: how the base colours were made, for the report.
        premade: maps already made, ``id(original array) -> (array, method)`` (the maps of
            a new UV layout, :func:`relayout_maps`).
        toksvig: widen the roughness of materials whose normal map got smaller
            (:func:`toksvig_maps`; in the mesh's own layout only, without ``premade``).

    Returns:
        The mesh to write (every texture replaced by its shipped array, sharing kept; base
        colours and smaller normal and data maps marked lossless,
        :func:`with_lossless_formats`) and one
        :class:`ShippedMap` per distinct texture, in :meth:`TexturedMesh.images` order.
    """
    given, mesh = mesh, with_lossless_formats(mesh, plan)
    made = {}
    for material, texture in zip(mesh.materials, base_colors, strict=True):
        original = material.base_color_texture
        if original is not None and texture is not None:
            made.setdefault(id(original), texture)
    shipped, replacements = [], {}
    for pixels, places in mesh.images():
        material_index, slot = places[0]
        material = mesh.materials[material_index]
        kind = COLOR if slot == BASE_COLOR else texture_class(slot)
        size = plan.rule(kind).size(*pixels.shape[:2])
        if id(pixels) in made:
            out, method = made[id(pixels)], base_color_method
        elif premade and id(pixels) in premade:
            out, method = premade[id(pixels)]
        elif size == pixels.shape[:2]:
            out, method = pixels, "kept"
        else:
            out = resize_map(pixels, size, kind, alpha_cutoff=alpha_cutoff(material))
            method = METHOD_NAMES[kind]
        if out is not pixels:
            replacements[id(pixels)] = out
        source = material.sources.get(slot)
        names = [f"{mesh.materials[m].name}/{s}" for m, s in places]
        before = len(source.data) if source is not None else 0
        sizes = pixels.shape[:2], out.shape[:2]
        made_map = ShippedMap(names, kind, method, *sizes, before, out, source)
        given_source = given.materials[material_index].sources.get(slot)
        made_map.format_before = "" if given_source is None else given_source.mime
        shipped.append(made_map)
    out = mesh.with_images(replacements)
    if toksvig and not premade:
        out = _widen_roughness(mesh, out, shipped)
    return out, shipped


def _widen_roughness(
    mesh: TexturedMesh, out: TexturedMesh, shipped: list[ShippedMap]
) -> TexturedMesh:
    """``out`` with :func:`toksvig_maps` applied, and ``shipped`` told of it."""
    widened = toksvig_maps(mesh, out)
    for made_map in shipped:
        if id(made_map.pixels) in widened:
            made_map.pixels = widened[id(made_map.pixels)]
            made_map.method = f"{made_map.method}, {TOKSVIG}"
    return out.with_images(widened)


TOKSVIG = "roughness widened by the normal map (Toksvig)"
"""What the report adds to the method of a metallic-roughness map :func:`toksvig_maps` made."""


def toksvig_maps(original: TexturedMesh, shipped: TexturedMesh) -> dict[int, np.ndarray]:
    """The metallic-roughness maps of ``shipped`` widened by what their material's normal map
    lost (:func:`geoscaler.resize.maps.toksvig_roughness`, from the original's full-resolution
    normal map): ``id(shipped map) -> widened map``.

    A material qualifies where its normal and metallic-roughness maps were both made smaller
    in its own layout (neither kept at its size nor re-baked) and read the same UVs (same
    ``texCoord`` and texture transform); a map several materials share is widened once, by
    the first one's normal map."""
    widened: dict[int, np.ndarray] = {}
    for before, after in zip(original.materials, shipped.materials, strict=True):
        normal, normal_out = before.maps.get(NORMAL), after.maps.get(NORMAL)
        packed = before.maps.get(METALLIC_ROUGHNESS)
        packed_out = after.maps.get(METALLIC_ROUGHNESS)
        if any(m is None for m in (normal, normal_out, packed, packed_out)):
            continue
        if id(packed_out) in widened or not _same_uv_set(before, NORMAL, METALLIC_ROUGHNESS):
            continue
        if normal_out.shape[:2] == normal.shape[:2] or packed_out.shape[:2] == packed.shape[:2]:
            continue
        shortening = normal_shortening(normal, normal_out.shape[:2])
        factor = float(after.properties.get("pbrMetallicRoughness", {}).get("roughnessFactor", 1))
        widened[id(packed_out)] = toksvig_roughness(packed_out, shortening, factor)
    return widened


def _same_uv_set(material: Material, first: str, second: str) -> bool:
    """Whether two slots of a material read their textures on the same UVs."""
    infos = [slot_info(material.properties, slot) for slot in (first, second)]
    keys = [
        (i.get("texCoord", 0), i.get("extensions", {}).get("KHR_texture_transform")) for i in infos
    ]
    return keys[0] == keys[1]


def asset_of(
    mesh: TexturedMesh, result: MethodResult, plan: SizePlan, method: str
) -> tuple[TexturedMesh, list[ShippedMap]]:
    """The asset as it ships for a method's result: its base colours and UVs (in a new
    layout every other map re-baked into it, :func:`relayout_maps`), the maps it made itself
    (:attr:`MethodResult.maps`), every other map at its class's size (:func:`ship_asset`)."""
    uvs = mesh.uvs if result.uvs is None else result.uvs
    premade = dict(result.maps or {})
    if result.layout is not None:
        premade.update(relayout_maps(mesh, result.layout, plan))
        mesh = without_stale_tangents(mesh, result.layout)
    return ship_asset(mesh.with_uvs(uvs), plan, result.textures, method, premade)


EVERY_MAP_FILTERS = {
    "box": Image.Resampling.BOX,
    "bicubic": Image.Resampling.BICUBIC,
    "lanczos": Image.Resampling.LANCZOS,
}
"""Protocol 2's baselines: every map of every material resized by one Pillow filter."""


def every_map_by(mesh: TexturedMesh, plan: SizePlan, name: str) -> TexturedMesh:
    """``mesh`` with every map of every material resized by the Pillow filter ``name``
    (:data:`EVERY_MAP_FILTERS`) on its stored 8-bit values, channels apart, to its class's
    size, as ``gltf-transform resize`` and image editors do (protocol 2's baselines)."""
    resample = EVERY_MAP_FILTERS[name]
    replacements = {}
    for pixels, places in mesh.images():
        material, slot = places[0]
        kind = COLOR if slot == BASE_COLOR else texture_class(slot)
        size = plan.rule(kind).size(*pixels.shape[:2])
        if size != pixels.shape[:2]:
            replacements[id(pixels)] = resize_channels(pixels, size, resample)
    return mesh.with_images(replacements)


def without_stale_tangents(mesh: TexturedMesh, atlas: Atlas) -> TexturedMesh:
    """``mesh`` without its ``TANGENT`` attribute where the new layout turned or mirrored a
    chart (only charts of materials without a normal map may turn): their tangents no longer
    follow the UVs, and a glTF viewer computes tangents (MikkTSpace) when there are none.
    Where charts only moved and scaled, the tangents still hold and are kept."""
    moved = np.unique(atlas.chart_of_face[atlas.chart_of_face >= 0])
    linear = atlas.linear[moved]
    turned = (linear[:, 0, 1] != 0) | (linear[:, 0, 0] < 0) | (linear[:, 1, 1] < 0)
    if "TANGENT" not in mesh.attributes or not turned.any():
        return mesh
    attributes = {k: v for k, v in mesh.attributes.items() if k != "TANGENT"}
    return replace(mesh, attributes=attributes)
