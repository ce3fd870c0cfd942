"""The asset as it ships: every map of every material at the size asked for its class.

The job's method makes the base colours (optimised through the renderer, or a filter); every
other map is resized here by what it holds (:func:`geoscaler.maps.resize_map`: colour in linear
light, normals as vectors, data channel by channel) at the size its class's rule gives
(:class:`geoscaler.sizes.SizePlan`), from the full-resolution original. A texture that several
slots or materials show is resized once and stays shared (sharing is by array identity, as
the loader gives it); one the rule does not shrink ships as it came, bytes and all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from geoscaler.maps import METHOD_NAMES, resize_map, texture_class
from geoscaler.mesh import Material, SourceImage, TexturedMesh
from geoscaler.protocol import BYTES_PER_TEXEL
from geoscaler.sizes import COLOR, SizePlan

BASE_COLOR = "baseColorTexture"
LOSSLESS = "image/png"


@dataclass
class ShippedMap:
    """One distinct texture of the asset, before and after.

    Attributes:
        slots: ``"material/slot"`` of every place that shows it.
        kind: its class (:data:`geoscaler.sizes.TEXTURE_CLASSES`).
        method: how it was made ("kept" when its rule does not shrink it).
        size_before, size_after: ``(h, w)`` texels.
        bytes_before: bytes of its encoded image in the input (0: unknown).
        bytes_after: bytes of its encoded image in the output (set once written).
        pixels: the array that ships.
        source: how the input image came in (its format is the output's, unless asked).
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


def with_lossless_base_colors(mesh: TexturedMesh) -> TexturedMesh:
    """``mesh`` with every base colour's image marked PNG (sharing kept): the base colour ships
    as the job validated it, 8-bit, and a lossy re-encoding (a JPEG or WebP input's format)
    would ship something else (JPEG q90 took 2.7 dB off the stool's optimised 256 x 256
    texture). Its other maps keep their input's format."""
    marked: dict[int, SourceImage] = {}
    materials = []
    for material in mesh.materials:
        source = material.sources.get(BASE_COLOR)
        if source is not None and source.mime != LOSSLESS:
            png = marked.setdefault(id(source), replace(source, mime=LOSSLESS))
            material = replace(material, sources={**material.sources, BASE_COLOR: png})
        materials.append(material)
    return replace(mesh, materials=materials)


def ship_asset(
    mesh: TexturedMesh,
    plan: SizePlan,
    base_colors: Sequence[np.ndarray | None],
    base_color_method: str,
) -> tuple[TexturedMesh, list[ShippedMap]]:
    """The mesh as it ships, and what happened to each of its textures.

    Args:
        mesh: the loaded asset (its textures the originals).
        plan: the size rule of each texture class.
        base_colors: per material the method's ``(h, w, C)`` uint8 base colour (None: the
            material has none); materials sharing one base-colour image get the first one's.
        base_color_method: how the base colours were made, for the report.

    Returns:
        The mesh to write (every texture replaced by its shipped array, sharing kept; base
        colours marked lossless, :func:`with_lossless_base_colors`) and one
        :class:`ShippedMap` per distinct texture, in :meth:`TexturedMesh.images` order.
    """
    mesh = with_lossless_base_colors(mesh)
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
        shipped.append(ShippedMap(names, kind, method, *sizes, before, out, source))
    return mesh.with_images(replacements), shipped
