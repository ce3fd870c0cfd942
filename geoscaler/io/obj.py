"""Wavefront OBJ: the OBJ + MTL reader and the OBJ + MTL + images writer.

Reading: the MTL libraries are parsed here (colours, dissolve, every map of
:data:`geoscaler.io.slots.MTL_MAPS` with its options, other scalar statements), each map
resolved inside the mesh's folder and decoded once however many materials show it;
:mod:`geoscaler.io.obj_geometry` reads the triangles and groups them by material name.
Writing: MTL holds base colour, normal and emissive maps and its own (``map_Ks``, ``map_Ns``,
``map_d``...), each with the keyword and options it was read with; ``map_Kd`` is the colour,
so a base-colour factor other than 1 is baked into the written texture by
:mod:`geoscaler.io.save`.
"""

from __future__ import annotations

import codecs
import io
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import BASE_COLOR, Material, SourceImage, TexturedMesh

from .assemble import MaterialBuilder, Part
from .images import open_image, source_image
from .obj_geometry import obj_parts
from .paths import resolve_reference, side_file
from .slots import MTL_KEYWORDS, MTL_MAPS, MTL_PREFIX, MTL_PROPERTIES

if TYPE_CHECKING:
    from .save import ImageOut

# ----------------------------------------------------------------------------- reading


@dataclass
class _MtlEntry:
    """What GeoScaler reads from one ``newmtl`` block."""

    name: str
    owner: Path
    diffuse: tuple[float, float, float] | None = None
    dissolve: float | None = None
    emissive: tuple[float, float, float] | None = None
    maps: dict[str, tuple[Path, str]] = field(default_factory=dict)  # keyword: (file, options)
    statements: list[str] = field(default_factory=list)


_MTL_KEYWORDS = {keyword.lower(): keyword for keyword in MTL_MAPS}
# Scalar statements written back as they were read (Kd, Ke and d are read; Tr is ignored).
_KEPT_STATEMENTS = {"ka", "ks", "ns", "ni", "illum", "tf", "pr", "pm", "ps", "pc", "pcr"}
_KEPT_STATEMENTS |= {"aniso", "anisor", "sharpness"}
# Options of MTL map statements and how many values they take (-o/-s/-t: up to three).
_MTL_OPTIONS = {
    "-blendu": 1, "-blendv": 1, "-boost": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3,
    "-texres": 1, "-clamp": 1, "-bm": 1, "-imfchan": 1, "-type": 1, "-cc": 1,
}  # fmt: skip


def load_obj(path: Path) -> tuple[list[Part], list[MaterialBuilder], list[Path]]:
    """Read an OBJ file and its MTL libraries, for :func:`geoscaler.io.assemble.assemble`.

    Returns
    -------
    parts : list of Part
        The placed geometries; ``Part.material`` indexes ``builders``.
    builders : list of MaterialBuilder
        One per MTL material (the last definition of a name wins), decoding its maps.
    files : list of Path
        The OBJ, the MTL libraries and every map they reference, resolved.
    """
    root = path.parent.resolve()
    data = path.read_bytes().removeprefix(codecs.BOM_UTF8)  # editors on Windows write one
    text = _decode_text(data)
    libraries = _obj_libraries(text, path, root)
    entries: dict[str, _MtlEntry] = {}
    for library in libraries:
        for entry in _parse_mtl(library, root):
            entries[entry.name] = entry
    ordered = list(entries.values())
    parts = obj_parts(text, {entry.name: i for i, entry in enumerate(ordered)}, path)
    decoded: dict[Path, tuple[SourceImage, bool]] = {}  # per file: its image, whether grey
    builders = [lambda e=entry: _obj_material(e, decoded) for entry in ordered]
    files = [path.resolve(), *libraries, *(f for e in ordered for f, _ in e.maps.values())]
    return parts, builders, files


def _decode_text(data: bytes) -> str:
    """Text of an OBJ or MTL file: UTF-8 (a leading byte-order mark dropped), else Latin-1."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


_MENTIONS_MTLLIB = re.compile(r"^.*mtllib.*$", re.MULTILINE)


def _obj_libraries(text: str, path: Path, root: Path) -> list[Path]:
    """The MTL files named by ``mtllib`` lines (one name with spaces, or several names)."""
    libraries: list[Path] = []
    lines = (line for found in _MENTIONS_MTLLIB.findall(text) for line in found.splitlines())
    for line in lines:  # only the lines that mention it: a large OBJ has a million others
        words = line.split(None, 1)
        if len(words) < 2 or words[0] != "mtllib":
            continue
        rest = words[1].strip()
        names = [rest] if (path.parent / rest).is_file() else rest.split()
        for name in names:
            library = resolve_reference(name, path.parent, root, path, "material library")
            if library not in libraries:
                libraries.append(library)
    return libraries


def _parse_mtl(library: Path, root: Path) -> list[_MtlEntry]:
    """Read the materials of an MTL file; ``Tr`` is ignored (MeshLab writes ``Tr 1`` opaque)."""
    entries: list[_MtlEntry] = []
    for line in _decode_text(library.read_bytes()).splitlines():
        words = line.strip().split(None, 1)
        if len(words) < 2 or words[0].startswith("#"):
            continue
        key, rest = words[0].lower(), words[1].strip()
        if key == "newmtl":
            entries.append(_MtlEntry(name=" ".join(rest.split()), owner=library))
        elif entries and key in _KEPT_STATEMENTS:
            entries[-1].statements.append(f"{words[0]} {rest}")
        elif entries:
            _read_mtl_statement(entries[-1], key, rest, root)
    return entries


def _read_mtl_statement(entry: _MtlEntry, key: str, rest: str, root: Path) -> None:
    """One statement of a ``newmtl`` block; colours and dissolve are clamped to [0, 1]."""
    if key in ("kd", "ke", "d"):
        value = _mtl_color(rest)
        if value is not None and not all(math.isfinite(x) for x in value):
            raise GeoscalerError(
                f"{entry.owner}: material {entry.name!r}: '{key} {rest}' is not a finite "
                "number; fix the MTL file"
            )
        value = None if value is None else tuple(min(max(x, 0.0), 1.0) for x in value)
        if key == "kd":
            entry.diffuse = value
        elif key == "ke":
            entry.emissive = value
        else:
            entry.dissolve = None if value is None else value[0]
    elif key in _MTL_KEYWORDS and _MTL_KEYWORDS[key] not in entry.maps:
        keyword, (options, name) = _MTL_KEYWORDS[key], _mtl_map_file(rest)
        base = entry.owner.parent
        if keyword == "map_Kd":
            file = resolve_reference(name, base, root, entry.owner, "texture")
            entry.maps[keyword] = (file, options)
            return
        try:
            file = resolve_reference(name, base, root, entry.owner, "texture")
        except GeoscalerError as exc:
            warnings.warn(f"{exc} The map is skipped.", stacklevel=6)
            return
        entry.maps[keyword] = (file, options)


def _mtl_color(rest: str) -> tuple[float, float, float] | None:
    """``r g b`` or a single value; None for spectral/xyz forms or garbage."""
    try:
        values = [float(word) for word in rest.split()[:3]]
    except ValueError:
        return None
    if not values:
        return None
    return (values[0], values[0], values[0]) if len(values) < 3 else tuple(values)


def _mtl_map_file(rest: str) -> tuple[str, str]:
    """The options and the file name of an MTL map statement (names may contain spaces)."""
    words = rest.split()
    i = 0
    while i < len(words) and words[i].lower() in _MTL_OPTIONS:
        count = _MTL_OPTIONS[words[i].lower()]
        i += 1
        if count == 3:
            while count and i < len(words) - 1 and _is_number(words[i]):
                i, count = i + 1, count - 1
        else:
            i += count
    return " ".join(words[:i]), " ".join(words[i:])


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _obj_material(entry: _MtlEntry, decoded: dict[Path, tuple[SourceImage, bool]]) -> Material:
    """Decode an MTL entry's maps; with ``map_Kd`` the texture is the colour (factor 1).

    A ``bump``/``map_bump``/``norm`` map in colour is the normal map (the first one wins); in
    grey it is a height map, kept as ``"mtl:" + keyword``, as is every map glTF has no slot
    for. ``properties`` gets ``emissiveFactor`` (Ke) and, under ``"mtl"``, each map's keyword
    and options and the other statements, so that saving as OBJ writes them back.
    """
    textures: dict[str, np.ndarray] = {}
    sources: dict[str, SourceImage] = {}
    keywords: dict[str, str] = {}
    options: dict[str, str] = {}
    for keyword, (file, option) in entry.maps.items():
        if file not in decoded:
            image, data = open_image(file, entry.owner)
            grey = image.mode not in ("RGB", "RGBA", "P", "PA")
            decoded[file] = source_image(image, data, str(file), entry.owner, file.name), grey
        source, grey = decoded[file]
        slot = MTL_MAPS[keyword]
        if slot == "normalTexture" and (grey or slot in textures):
            slot = MTL_PREFIX + keyword  # a height map, or a second normal map
        if slot in textures:
            continue
        textures[slot], sources[slot] = source.pixels, source
        keywords[slot], options[slot] = keyword, option
    alpha = 1.0 if entry.dissolve is None else entry.dissolve
    texture = textures.pop(BASE_COLOR, None)
    if texture is not None:
        factor = (1.0, 1.0, 1.0, alpha)
    else:
        factor = (*(entry.diffuse or (1.0, 1.0, 1.0)), alpha)
    properties: dict[str, Any] = {}
    if entry.emissive is not None:
        properties["emissiveFactor"] = list(entry.emissive)
    record = {"keywords": keywords, "options": options, "statements": entry.statements}
    properties[MTL_PROPERTIES] = record
    factor_array = np.array(factor, np.float32)
    return Material(entry.name, texture, factor_array, properties, textures, sources)


# ----------------------------------------------------------------------------- writing


def obj_files(
    mesh: TexturedMesh,
    used: list[int],
    images: list[ImageOut],
    encoded: list[tuple[bytes, str]],
    slots: dict[tuple[int, str], int],
    path: Path,
) -> dict[str, bytes]:
    """The files of ``mesh`` saved as ``path``: image files, the MTL library, the OBJ last.

    ``used`` are the materials that faces use, ``images`` the images to write with their
    ``encoded`` bytes, and ``slots`` which image each ``(material, slot)`` shows (see
    :mod:`geoscaler.io.save`).
    """
    names = _unique_names([mesh.materials[m].name for m in used])
    files = {image.name: data for image, (data, _) in zip(images, encoded, strict=True)}
    mtl_name = side_file(path, ".mtl").name
    files[mtl_name] = _mtl_text(mesh, used, names, images, slots).encode()
    files[path.name] = _obj_text(mesh, used, names, mtl_name).encode()
    return files


def _unique_names(names: list[str]) -> list[str]:
    """Material names usable in MTL: no whitespace, not empty, no duplicates."""
    out: list[str] = []
    for i, name in enumerate(names):
        clean = "_".join(name.split()) or f"material_{i}"
        candidate, k = clean, 1
        while candidate in out:
            candidate, k = f"{clean}_{k}", k + 1
        out.append(candidate)
    return out


def _obj_text(mesh: TexturedMesh, used: list[int], names: list[str], mtl_name: str) -> str:
    out = io.StringIO()
    out.write(f"# written by GeoScaler\nmtllib {mtl_name}\n")
    np.savetxt(out, mesh.positions.astype(np.float64), fmt="v %.9g %.9g %.9g")
    np.savetxt(out, mesh.uvs.astype(np.float64), fmt="vt %.9g %.9g")
    np.savetxt(out, mesh.normals.astype(np.float64), fmt="vn %.9g %.9g %.9g")
    corner = "%d/%d/%d"
    for m, name in zip(used, names, strict=True):
        out.write(f"usemtl {name}\n")
        faces = mesh.faces[mesh.face_material == m] + 1
        np.savetxt(out, np.repeat(faces, 3, axis=1), fmt=f"f {corner} {corner} {corner}")
    return out.getvalue()


def _mtl_text(
    mesh: TexturedMesh, used: list[int], names: list[str], images: list[ImageOut], slots: dict
) -> str:
    """Each material's colour, dissolve, emission, kept statements, then its maps in slot
    order, each with the keyword and options it was read with."""
    lines = ["# written by GeoScaler"]
    for m, name in zip(used, names, strict=True):
        material = mesh.materials[m]
        record = material.properties.get(MTL_PROPERTIES)
        record = record if isinstance(record, dict) else {}
        factor = np.asarray(material.base_color_factor, dtype=np.float64)
        textured = (m, BASE_COLOR) in slots
        diffuse = (1.0, 1.0, 1.0) if textured else factor[:3]
        lines += ["", f"newmtl {name}", "Kd {:.9g} {:.9g} {:.9g}".format(*diffuse)]
        if factor[3] != 1:
            lines.append(f"d {factor[3]:.9g}")
        emissive = material.properties.get("emissiveFactor")
        if emissive is not None:
            lines.append("Ke {:.9g} {:.9g} {:.9g}".format(*np.asarray(emissive, float).ravel()))
        lines += [str(line) for line in record.get("statements", [])]
        for (k, slot), image in slots.items():
            if k != m:
                continue
            keyword = record.get("keywords", {}).get(slot)
            keyword = keyword or MTL_KEYWORDS.get(slot) or slot.removeprefix(MTL_PREFIX)
            options = record.get("options", {}).get(slot, "")
            lines.append(" ".join(w for w in (keyword, options, images[image].name) if w))
    return "\n".join(lines) + "\n"
