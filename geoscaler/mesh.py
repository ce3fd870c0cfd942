"""Textured meshes: the one in-memory form every module works on, and its file formats.

Conventions (used everywhere in the project):

- UVs follow OpenGL/OBJ: ``v = 0`` is the bottom row of the texture image. Texture arrays
  are stored as images are, row 0 at the top, so texel row ``y`` holds ``v = 1 - (y + 0.5) / H``.
- Vertices are split at UV seams: one row of ``positions``/``uvs``/``normals`` per distinct
  (position, UV) pair. ``vertex_to_point`` welds them back to 3D points by position.

Files: :func:`load_mesh` reads OBJ (+ MTL), glTF (external or embedded buffers and images) and
GLB through trimesh, applies the scene graph and joins every part into one mesh with per-face
materials. :func:`save_mesh` writes OBJ (+ MTL + PNG), glTF (+ .bin + PNG) or GLB. Only files
inside the mesh's folder are ever read, and the input files are never written.
"""

from __future__ import annotations

import copy
import io
import json
import os
import shutil
import struct
import tempfile
import urllib.parse
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
import trimesh
from PIL import Image

from .errors import GeoscalerError
from .texture import linear_to_srgb, srgb_to_linear

SUPPORTED_SUFFIXES = (".obj", ".gltf", ".glb")
_FORMAT_NAMES = {".obj": "Wavefront OBJ", ".gltf": "glTF 2.0", ".glb": "binary glTF (GLB)"}


@dataclass
class Material:
    """A material as far as rendering needs it, plus the loader's object for export.

    Attributes:
        name: material name from the file.
        base_color_texture: ``(H, W, C)`` uint8 sRGB, ``C`` 3 or 4, row 0 at the top; None when
            the material has no base-colour map.
        base_color_factor: ``(4,)`` float32 linear RGBA multiplier (1 where the texture is the
            colour, as for OBJ ``map_Kd``).
        source: the loader's material (e.g. a trimesh ``PBRMaterial``), kept so that export can
            preserve every other map and property untouched. Its images are the maps other
            than base colour (normal, occlusion, emissive, metallic-roughness); its base-colour
            slot is left empty: ``base_color_texture`` is the one truth.
        properties: the glTF material object (JSON) without image indices: every texture slot
            keeps its fields (``scale``, ``strength``, ``texCoord``, ``extensions``) and the
            texture's sampler under ``"sampler"``. Export writes it back. Empty for plain OBJ.
    """

    name: str
    base_color_texture: np.ndarray | None
    base_color_factor: np.ndarray = field(default_factory=lambda: np.ones(4, dtype=np.float32))
    source: Any = None
    properties: dict[str, Any] = field(default_factory=dict)


@dataclass
class TexturedMesh:
    """A triangle mesh with per-vertex UVs and base-colour textures.

    Attributes:
        positions: ``(V, 3)`` float32, scene-graph transforms applied, file units.
        faces: ``(F, 3)`` int64 indices into ``positions``/``uvs``/``normals``, CCW front faces.
        uvs: ``(V, 2)`` float32 texture coordinates (OpenGL convention, may lie outside [0, 1]).
        normals: ``(V, 3)`` float32 unit vertex normals.
        vertex_to_point: ``(V,)`` int64 index of the welded 3D point of each vertex.
        face_material: ``(F,)`` int64 index into ``materials``.
        materials: the materials, at least one with a base-colour texture.
        source_path: the file it was loaded from, if any.
        source_files: every file read to build it (mesh, MTL, buffers, textures), resolved;
            :func:`save_mesh` refuses to write over any of them.
    """

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    normals: np.ndarray
    vertex_to_point: np.ndarray
    face_material: np.ndarray
    materials: list[Material]
    source_path: Path | None = None
    source_files: list[Path] = field(default_factory=list)

    @property
    def num_points(self) -> int:
        """Number of welded 3D points."""
        return int(self.vertex_to_point.max()) + 1 if len(self.vertex_to_point) else 0

    def points(self) -> np.ndarray:
        """``(P, 3)`` float32 welded 3D points (the position of each point's vertices)."""
        out = np.zeros((self.num_points, 3), dtype=np.float32)
        out[self.vertex_to_point] = self.positions
        return out

    def normalization(self) -> tuple[np.ndarray, float]:
        """PROTOCOL.md scene normalisation as ``(centre (3,), scale)``.

        ``normalized = (positions - centre) * scale`` puts the bounding-box centre at the
        origin and the farthest vertex at distance 1.
        """
        lo, hi = self.positions.min(axis=0), self.positions.max(axis=0)
        centre = ((lo + hi) / 2).astype(np.float64)
        radius = float(np.linalg.norm(self.positions - centre, axis=1).max())
        return centre.astype(np.float32), (1.0 / radius if radius > 0 else 1.0)

    def normalized_positions(self) -> np.ndarray:
        """``(V, 3)`` float32 positions in the protocol's unit scene."""
        centre, scale = self.normalization()
        return ((self.positions - centre) * scale).astype(np.float32)

    def with_texture(
        self, material_index: int, texture: np.ndarray, uvs: np.ndarray | None = None
    ) -> TexturedMesh:
        """A copy with a new base-colour texture for one material, and optionally new UVs.

        Parameters
        ----------
        material_index : int
            Which material gets ``texture``.
        texture : (H, W, C) uint8
            sRGB texels, ``C`` 3 or 4, row 0 at the top. Kept by reference, not copied.
        uvs : (V, 2) float, optional
            New texture coordinates of every vertex (OpenGL convention).

        Returns
        -------
        TexturedMesh
            Shares every unchanged array with ``self``; factor, other maps, properties and
            source files carry over, so :func:`save_mesh` still protects the input files.
        """
        if not 0 <= material_index < len(self.materials):
            raise ValueError(
                f"material_index {material_index} out of range for {len(self.materials)} materials"
            )
        _check_texture_array(texture, f"texture for material {material_index}")
        materials = list(self.materials)
        materials[material_index] = replace(materials[material_index], base_color_texture=texture)
        new_uvs = self.uvs
        if uvs is not None:
            new_uvs = np.asarray(uvs, dtype=np.float32)
            if new_uvs.shape != self.uvs.shape:
                raise ValueError(f"uvs must have shape {self.uvs.shape}, got {new_uvs.shape}")
        return replace(self, uvs=new_uvs, materials=materials)

    def validate(self) -> None:
        """Raise ``ValueError`` when the arrays disagree in shape or index range."""
        count = len(self.positions)
        shapes = {
            "positions": (self.positions, (count, 3)),
            "uvs": (self.uvs, (count, 2)),
            "normals": (self.normals, (count, 3)),
            "vertex_to_point": (self.vertex_to_point, (count,)),
            "faces": (self.faces, (len(self.faces), 3)),
            "face_material": (self.face_material, (len(self.faces),)),
        }
        for name, (array, shape) in shapes.items():
            if np.shape(array) != shape:
                raise ValueError(f"{name} has shape {np.shape(array)}, expected {shape}")
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= count):
            raise ValueError("faces index vertices out of range")
        if len(self.faces) and (
            self.face_material.min() < 0 or self.face_material.max() >= len(self.materials)
        ):
            raise ValueError("face_material indexes materials out of range")
        for material in self.materials:
            if material.base_color_texture is not None:
                _check_texture_array(material.base_color_texture, f"material {material.name!r}")
            if np.shape(material.base_color_factor) != (4,):
                raise ValueError(f"material {material.name!r}: base_color_factor must be (4,)")


def _check_texture_array(texture: np.ndarray, what: str) -> None:
    """Raise ``ValueError`` unless ``texture`` is ``(H, W, 3 or 4)`` uint8."""
    if not isinstance(texture, np.ndarray) or texture.dtype != np.uint8:
        raise ValueError(f"{what}: texture must be a uint8 numpy array")
    if texture.ndim != 3 or texture.shape[2] not in (3, 4) or 0 in texture.shape[:2]:
        raise ValueError(f"{what}: texture must have shape (H, W, 3 or 4), got {texture.shape}")


# ----------------------------------------------------------------------------- textures


def image_to_texture(image: Image.Image) -> np.ndarray:
    """Convert a Pillow image to the texture layout: ``(H, W, 3 or 4)`` uint8, row 0 at the top.

    Grey (``1``, ``L``) becomes RGB, grey with alpha (``LA``) RGBA, palette (``P``) RGB or RGBA
    when it has transparency, 16-bit grey (``I;16*``, and ``I`` as Pillow reads 16-bit PNGs)
    is scaled by 255/65535 and rounded. Raises ``ValueError`` for float (``F``) images.
    """
    mode = image.mode
    if mode in ("RGB", "RGBA"):
        array = np.asarray(image)
    elif mode in ("1", "L"):
        array = _grey_to_rgb(np.asarray(image.convert("L")))
    elif mode == "LA":
        grey_alpha = np.asarray(image)
        array = np.concatenate([_grey_to_rgb(grey_alpha[..., 0]), grey_alpha[..., 1:]], axis=2)
    elif mode.startswith("I;16") or mode == "I":
        wide = np.asarray(image).astype(np.float64)
        array = _grey_to_rgb(np.round(np.clip(wide, 0, 65535) * (255 / 65535)).astype(np.uint8))
    elif mode in ("P", "PA"):
        transparent = mode == "PA" or "transparency" in image.info
        transparent = transparent or (image.palette is not None and image.palette.mode == "RGBA")
        array = np.asarray(image.convert("RGBA" if transparent else "RGB"))
    elif mode in ("RGBa", "La"):
        array = np.asarray(image.convert("RGBA"))
    elif mode in ("RGBX", "CMYK", "YCbCr", "LAB", "HSV"):
        array = np.asarray(image.convert("RGB"))
    else:
        raise ValueError(f"pixel mode {mode!r} is not supported")
    return np.ascontiguousarray(array, dtype=np.uint8)


def _grey_to_rgb(grey: np.ndarray) -> np.ndarray:
    """``(H, W)`` -> ``(H, W, 3)`` by repeating the channel."""
    return np.repeat(grey[..., None], 3, axis=2)


def _decode_texture(image: Image.Image, label: str, owner: Path) -> np.ndarray:
    """:func:`image_to_texture` with decoding problems reported as ``GeoscalerError``."""
    try:
        image.load()
        return image_to_texture(image)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise GeoscalerError(
            f"{owner}: texture {label} could not be decoded ({exc}). "
            "Re-save it as an 8-bit PNG or JPEG."
        ) from exc


def _open_image(path: Path, owner: Path) -> Image.Image:
    """Open and fully decode an image file, errors as ``GeoscalerError``."""
    try:
        with Image.open(path) as image:
            image.load()
        return image
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise GeoscalerError(
            f"{owner}: texture {path} could not be read as an image ({exc}). "
            "Re-save it as an 8-bit PNG or JPEG."
        ) from exc


def bake_color_factor(texture: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """Multiply an sRGB texture by a linear RGB(A) factor, as a renderer would.

    Parameters
    ----------
    texture : (H, W, C) uint8
        sRGB colour, ``C`` 3 or 4 (alpha is linear).
    factor : (4,) float
        Linear RGBA multiplier; alpha is applied only when the texture has an alpha channel.

    Returns
    -------
    (H, W, C) uint8
    """
    encoded = torch.from_numpy(texture[..., :3] / 255.0)
    linear = srgb_to_linear(encoded) * torch.as_tensor(np.asarray(factor[:3], dtype=np.float64))
    out = texture.copy()
    out[..., :3] = np.round(linear_to_srgb(linear).numpy() * 255)
    if texture.shape[2] == 4:
        out[..., 3] = np.round(np.clip(texture[..., 3] * float(factor[3]), 0, 255))
    return out


# ----------------------------------------------------------------------------- references


def _resolve_reference(ref: str, base: Path, root: Path, owner: Path, what: str) -> Path:
    """Resolve a file reference written in ``owner``; it must stay inside ``root``.

    ``base`` is the folder relative references start from. Windows separators are accepted.
    Symbolic links are followed before the check, so a link out of the folder is refused too.
    """
    clean = ref.strip()
    if not clean:
        raise GeoscalerError(f"{owner}: an empty {what} reference; fix it in {owner.name}")
    if "://" in clean:
        raise GeoscalerError(
            f"{owner}: {what} {clean!r} is a URL; GeoScaler reads local files only. "
            f"Download it into {root} and reference it by a relative path."
        )
    candidates = [clean] + ([clean.replace("\\", "/")] if "\\" in clean else [])
    target = base
    for candidate in candidates:
        target = (base / candidate).resolve()
        if not target.is_relative_to(root):
            raise GeoscalerError(
                f"{owner}: {what} {clean!r} points outside the mesh's folder {root} "
                f"(to {target}). GeoScaler reads only files inside that folder: copy the "
                "file there and reference it by a relative path."
            )
        if target.is_file():
            return target
    raise GeoscalerError(
        f"{owner}: {what} {clean!r} was not found (looked for {target}). Put the file "
        f"there or correct the reference in {owner.name}."
    )


class _ReadOnlyResolver(trimesh.resolvers.Resolver):
    """A trimesh resolver that never writes."""

    def write(self, name: str, data: Any) -> None:
        raise GeoscalerError("reading a mesh never writes files")

    def namespaced(self, namespace: str) -> _ReadOnlyResolver:
        return self

    def keys(self) -> list[str]:
        return []


class _FolderResolver(_ReadOnlyResolver):
    """Serves only files inside the mesh's folder; glTF URIs are percent-decoded."""

    def __init__(self, owner: Path, root: Path):
        self.owner, self.root = owner, root

    def get(self, name: str) -> bytes:
        ref = urllib.parse.unquote(name)
        target = _resolve_reference(ref, self.owner.parent, self.root, self.owner, "file")
        return target.read_bytes()


class _ConstantResolver(_ReadOnlyResolver):
    """Serves the same bytes whatever is asked: the material library trimesh's OBJ reader wants."""

    def __init__(self, data: bytes):
        self.data = data

    def get(self, name: str) -> bytes:
        return self.data


# ----------------------------------------------------------------------------- loading


class _Part(NamedTuple):
    """One placed geometry of a trimesh scene, in world space."""

    positions: np.ndarray  # (n, 3) float64
    faces: np.ndarray  # (m, 3) int64
    uvs: np.ndarray | None  # (n, 2) float64
    normals: np.ndarray | None  # (n, 3) float64, from the file
    material: int | None  # index into the loader's material list; None: no material


MaterialBuilder = Callable[[], Material]


def load_mesh(path: str | Path) -> TexturedMesh:
    """Load an OBJ (+ MTL), glTF or GLB file as one :class:`TexturedMesh`.

    Scene-graph transforms are applied (mirroring ones flip the winding back to CCW), every
    part is joined, vertices are welded by exact (position, UV) and points by exact position.
    Normals come from the file where it has them, else they are area-weighted over the welded
    points. Only materials used by faces are kept, grouped in file order, faces sorted by
    material.

    Raises
    ------
    GeoscalerError
        Missing, unreadable or corrupt file, unsupported format, a referenced file missing or
        outside the mesh's folder, no UVs on textured faces, no base-colour texture at all.
    """
    path = Path(path)
    suffix = _check_suffix(path)
    if not path.is_file():
        raise GeoscalerError(f"{path}: no such file. Check the path and the file name.")
    loader = _load_obj if suffix == ".obj" else _load_gltf
    try:
        return _assemble(path, *loader(path))
    except GeoscalerError as exc:
        if str(path) in str(exc):
            raise
        raise GeoscalerError(f"{path}: {exc}") from exc  # a problem in its MTL
    except Exception as exc:
        raise GeoscalerError(
            f"{path}: could not be read as {_FORMAT_NAMES[suffix]} "
            f"({type(exc).__name__}: {exc}). The file may be corrupt or truncated: "
            "re-export it from your 3D tool."
        ) from exc


def _check_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise GeoscalerError(
            f"{path}: unsupported file type {suffix or '(none)'!r}. GeoScaler reads and writes "
            f"{', '.join(SUPPORTED_SUFFIXES)}; convert the mesh to one of them (e.g. in Blender)."
        )
    return suffix


def _scene_parts(scene: trimesh.Scene, material_of: Callable[[Any], int | None]) -> list[_Part]:
    """Every triangle geometry of ``scene`` placed by its node transform."""
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry[name]
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
            parts.append(_place(geometry, np.asarray(transform, dtype=np.float64), material_of))
    return parts


def _place(
    geometry: trimesh.Trimesh, transform: np.ndarray, material_of: Callable[[Any], int | None]
) -> _Part:
    """Apply a 4x4 transform to a trimesh geometry and read its UVs and file normals."""
    linear = transform[:3, :3]
    positions = np.asarray(geometry.vertices, dtype=np.float64) @ linear.T + transform[:3, 3]
    faces = np.asarray(geometry.faces, dtype=np.int64)
    if np.linalg.det(linear) < 0:
        faces = faces[:, ::-1]
    uvs = getattr(geometry.visual, "uv", None)
    if uvs is not None and np.shape(uvs) != (len(positions), 2):
        uvs = None
    normals = None
    # trimesh caches normals given by the file; asking for them otherwise computes them.
    if "vertex_normals" in geometry._cache and abs(np.linalg.det(linear)) > 0:
        normals = np.asarray(geometry.vertex_normals, dtype=np.float64) @ np.linalg.inv(linear)
    material = getattr(geometry.visual, "material", None)
    return _Part(positions, faces, uvs, normals, material_of(material))


# ---------------------------------------------------------------- OBJ


@dataclass
class _MtlEntry:
    """What GeoScaler reads from one ``newmtl`` block."""

    name: str
    owner: Path
    diffuse: tuple[float, float, float] | None = None
    dissolve: float | None = None
    emissive: tuple[float, float, float] | None = None
    maps: dict[str, Path] = field(default_factory=dict)


# MTL keywords of the maps GeoScaler keeps, by slot; the first one found wins.
_MTL_MAPS = {
    "map_kd": "baseColorTexture",
    "norm": "normalTexture",
    "map_bump": "normalTexture",
    "bump": "normalTexture",
    "map_ke": "emissiveTexture",
}
# Options of MTL map statements and how many values they take (-o/-s/-t: up to three).
_MTL_OPTIONS = {
    "-blendu": 1, "-blendv": 1, "-boost": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3,
    "-texres": 1, "-clamp": 1, "-bm": 1, "-imfchan": 1, "-type": 1, "-cc": 1,
}  # fmt: skip
_OBJ_TAG = "geoscaler_index"


def _load_obj(path: Path) -> tuple[list[_Part], list[MaterialBuilder], list[Path]]:
    root = path.parent.resolve()
    data = path.read_bytes()
    libraries = _obj_libraries(_decode_text(data), path, root)
    entries: dict[str, _MtlEntry] = {}
    for library in libraries:
        for entry in _parse_mtl(library, root):
            entries[entry.name] = entry
    ordered = list(entries.values())
    # trimesh only needs the names to group faces; a tag tells its materials apart.
    names_only = "".join(f"newmtl {e.name}\n{_OBJ_TAG} {i}\n" for i, e in enumerate(ordered))
    resolver = _ConstantResolver(names_only.encode())
    scene = trimesh.load_scene(io.BytesIO(data), file_type="obj", resolver=resolver, process=False)
    parts = _scene_parts(scene, _obj_material_index)
    builders = [lambda e=entry: _obj_material(e) for entry in ordered]
    files = [path.resolve(), *libraries, *(p for e in ordered for p in e.maps.values())]
    return parts, builders, files


def _decode_text(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _obj_material_index(material: Any) -> int | None:
    tag = (getattr(material, "kwargs", None) or {}).get(_OBJ_TAG)
    return int(tag[0]) if tag else None


def _obj_libraries(text: str, path: Path, root: Path) -> list[Path]:
    """The MTL files named by ``mtllib`` lines (one name with spaces, or several names)."""
    libraries: list[Path] = []
    for line in text.splitlines():
        words = line.split(None, 1)
        if len(words) < 2 or words[0] != "mtllib":
            continue
        rest = words[1].strip()
        names = [rest] if (path.parent / rest).is_file() else rest.split()
        for name in names:
            library = _resolve_reference(name, path.parent, root, path, "material library")
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
        elif entries:
            _read_mtl_statement(entries[-1], key, rest, root)
    return entries


def _read_mtl_statement(entry: _MtlEntry, key: str, rest: str, root: Path) -> None:
    if key == "kd":
        entry.diffuse = _mtl_color(rest)
    elif key == "ke":
        entry.emissive = _mtl_color(rest)
    elif key == "d":
        value = _mtl_color(rest)
        entry.dissolve = None if value is None else min(max(value[0], 0.0), 1.0)
    elif key in _MTL_MAPS and _MTL_MAPS[key] not in entry.maps:
        slot, name = _MTL_MAPS[key], _mtl_map_file(rest)
        base = entry.owner.parent
        if slot == "baseColorTexture":
            entry.maps[slot] = _resolve_reference(name, base, root, entry.owner, "texture")
            return
        try:
            entry.maps[slot] = _resolve_reference(name, base, root, entry.owner, "texture")
        except GeoscalerError as exc:
            warnings.warn(f"{exc} The map is skipped.", stacklevel=6)


def _mtl_color(rest: str) -> tuple[float, float, float] | None:
    """``r g b`` or a single value; None for spectral/xyz forms or garbage."""
    try:
        values = [float(word) for word in rest.split()[:3]]
    except ValueError:
        return None
    if not values:
        return None
    return (values[0], values[0], values[0]) if len(values) < 3 else tuple(values)


def _mtl_map_file(rest: str) -> str:
    """The file name of an MTL map statement, after its options (names may contain spaces)."""
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
    return " ".join(words[i:])


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _obj_material(entry: _MtlEntry) -> Material:
    """Decode an MTL entry's maps; with ``map_Kd`` the texture is the colour (factor 1)."""
    alpha = 1.0 if entry.dissolve is None else entry.dissolve
    texture = None
    if "baseColorTexture" in entry.maps:
        image = _open_image(entry.maps["baseColorTexture"], entry.owner)
        texture = _decode_texture(image, str(entry.maps["baseColorTexture"]), entry.owner)
        factor = (1.0, 1.0, 1.0, alpha)
    else:
        factor = (*(entry.diffuse or (1.0, 1.0, 1.0)), alpha)
    extra = {
        slot: _open_image(file, entry.owner)
        for slot, file in entry.maps.items()
        if slot != "baseColorTexture"
    }
    normal = extra.get("normalTexture")
    if normal is not None and normal.mode not in ("RGB", "RGBA", "P"):
        warnings.warn(
            f"{entry.owner}: {entry.maps['normalTexture'].name} of material {entry.name!r} is "
            "a grey bump (height) map, not a normal map; it is not carried over.",
            stacklevel=5,
        )
        del extra["normalTexture"]
    source = trimesh.visual.material.PBRMaterial(
        name=entry.name, emissiveFactor=entry.emissive, **extra
    )
    properties = {slot: {} for slot in extra}
    if entry.emissive is not None:
        properties["emissiveFactor"] = list(entry.emissive)
    return Material(entry.name, texture, np.array(factor, np.float32), source, properties)


# ---------------------------------------------------------------- glTF / GLB

_GLTF_TAG = "geoscaler-material-"
# Texture slots of a glTF material: JSON path and trimesh PBRMaterial attribute.
_SLOTS = {
    "baseColorTexture": ("pbrMetallicRoughness", "baseColorTexture"),
    "metallicRoughnessTexture": ("pbrMetallicRoughness", "metallicRoughnessTexture"),
    "normalTexture": ("normalTexture",),
    "occlusionTexture": ("occlusionTexture",),
    "emissiveTexture": ("emissiveTexture",),
}
# Required extensions this loader honours (KHR_texture_transform: refused on base colour).
_REQUIRED_OK = {
    "EXT_texture_webp",
    "KHR_texture_transform",
    "KHR_materials_unlit",
    "KHR_materials_emissive_strength",
    "KHR_materials_pbrSpecularGlossiness",
}


def _load_gltf(path: Path) -> tuple[list[_Part], list[MaterialBuilder], list[Path]]:
    root = path.parent.resolve()
    data = path.read_bytes()
    binary = path.suffix.lower() == ".glb"
    doc, chunk = _split_glb(data, path) if binary else (_parse_json(data, path), None)
    files = [path.resolve(), *_check_gltf(doc, path, root)]
    tagged = copy.deepcopy(doc)
    for index, material in enumerate(tagged.get("materials", [])):
        material["name"] = f"{_GLTF_TAG}{index}"
    payload = _pack_glb(tagged, chunk) if binary else json.dumps(tagged).encode()
    scene = trimesh.load_scene(
        io.BytesIO(payload), file_type=path.suffix.lower()[1:],
        resolver=_FolderResolver(path, root), process=False,
    )  # fmt: skip
    loaded: dict[int, Any] = {}

    def material_of(material: Any) -> int | None:
        name = getattr(material, "name", "") if material is not None else ""
        if not isinstance(name, str) or not name.startswith(_GLTF_TAG):
            return None
        loaded[int(name[len(_GLTF_TAG) :])] = material
        return int(name[len(_GLTF_TAG) :])

    parts = _scene_parts(scene, material_of)
    builders = [
        lambda i=i: _gltf_material(path, doc, i, loaded[i])
        for i in range(len(doc.get("materials", [])))
    ]
    return parts, builders, files


def _parse_json(data: bytes, path: Path) -> dict:
    try:
        doc = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise GeoscalerError(
            f"{path}: not valid glTF JSON ({exc}). The file may be corrupt or truncated: "
            "re-export it from your 3D tool."
        ) from exc
    if not isinstance(doc, dict):
        raise GeoscalerError(f"{path}: not a glTF document (the JSON is not an object)")
    return doc


def _split_glb(data: bytes, path: Path) -> tuple[dict, bytes | None]:
    """The JSON document and the BIN chunk of a GLB file."""
    if len(data) < 20 or data[:4] != b"glTF":
        raise GeoscalerError(
            f"{path}: not a GLB file (no 'glTF' header). It may be corrupt, or a glTF JSON "
            "file: then name it .gltf."
        )
    version = struct.unpack_from("<I", data, 4)[0]
    if version != 2:
        raise GeoscalerError(f"{path}: GLB version {version}; only glTF 2.0 is supported")
    doc, chunk, offset = None, None, 12
    while offset + 8 <= len(data):
        size, kind = struct.unpack_from("<I4s", data, offset)
        body = data[offset + 8 : offset + 8 + size]
        if len(body) < size:
            raise GeoscalerError(f"{path}: truncated GLB file; re-export or re-download it")
        if kind == b"JSON" and doc is None:
            doc = _parse_json(body, path)
        elif kind == b"BIN\x00" and chunk is None:
            chunk = body
        offset += 8 + size
    if doc is None:
        raise GeoscalerError(f"{path}: GLB file without a JSON chunk; it is corrupt")
    return doc, chunk


def _pack_glb(doc: dict, chunk: bytes | None) -> bytes:
    """A GLB file from a JSON document and an optional BIN chunk."""
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text
    if chunk is not None:
        chunk = chunk + b"\x00" * (-len(chunk) % 4)
        body += struct.pack("<I4s", len(chunk), b"BIN\x00") + chunk
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def _check_gltf(doc: dict, path: Path, root: Path) -> list[Path]:
    """Check version, required extensions and external files; return the files referenced."""
    version = str(doc.get("asset", {}).get("version", ""))
    if not version.startswith("2"):
        raise GeoscalerError(
            f"{path}: glTF version {version or '(missing)'}; only glTF 2.0 is supported. "
            "Re-export it as glTF 2.0."
        )
    unknown = sorted(set(doc.get("extensionsRequired", [])) - _REQUIRED_OK)
    if unknown:
        raise GeoscalerError(
            f"{path}: requires glTF extension(s) {', '.join(unknown)}, which GeoScaler cannot "
            "read (compressed geometry or textures). Re-export it without compression."
        )
    files = []
    for index, buffer in enumerate(doc.get("buffers", [])):
        if _is_external(buffer):
            what = f"buffer #{index}"
            files.append(_resolve_reference(_unquote(buffer["uri"]), path.parent, root, path, what))
    base_images = _base_color_images(doc)
    for index, image in enumerate(doc.get("images", [])):
        if not _is_external(image):
            continue
        try:
            ref = _unquote(image["uri"])
            files.append(_resolve_reference(ref, path.parent, root, path, f"image #{index}"))
        except GeoscalerError as exc:
            if index in base_images:
                raise
            warnings.warn(f"{exc} The map is skipped.", stacklevel=5)
    return files


def _is_external(item: dict) -> bool:
    uri = item.get("uri")
    return isinstance(uri, str) and not uri.startswith("data:")


def _unquote(uri: str) -> str:
    return urllib.parse.unquote(uri)


def _texture_image_index(doc: dict, texture_index: int) -> int | None:
    """The image a glTF texture shows (its source, or an extension's source)."""
    texture = doc.get("textures", [])[texture_index]
    extensions = texture.get("extensions", {})
    if "source" in extensions.get("EXT_texture_webp", {}):
        return extensions["EXT_texture_webp"]["source"]
    if "source" in texture:
        return texture["source"]
    sources = [e["source"] for e in extensions.values() if isinstance(e, dict) and "source" in e]
    return sources[0] if sources else None


def _base_color_images(doc: dict) -> set[int]:
    images = set()
    for material in doc.get("materials", []):
        info = material.get("pbrMetallicRoughness", {}).get("baseColorTexture")
        if isinstance(info, dict) and "index" in info:
            images.add(_texture_image_index(doc, info["index"]))
    return images


def _image_label(doc: dict, texture_index: int, path: Path) -> str:
    image_index = _texture_image_index(doc, texture_index)
    image = doc.get("images", [])[image_index] if image_index is not None else {}
    if _is_external(image):
        return repr(_unquote(image["uri"]))
    return f"image #{image_index} embedded in {path.name}"


def _gltf_material(path: Path, doc: dict, index: int, pbr: Any) -> Material:
    """Build a Material from the glTF JSON (exact factor, checks) and trimesh's images."""
    raw = doc["materials"][index]
    name = raw.get("name") or f"material_{index}"
    pbr_json = raw.get("pbrMetallicRoughness", {})
    info = pbr_json.get("baseColorTexture")
    if isinstance(info, dict):
        _check_base_color_info(info, path, name)
    texture = None
    if pbr.baseColorTexture is not None:
        label = _image_label(doc, info["index"], path) if isinstance(info, dict) else name
        texture = _decode_texture(pbr.baseColorTexture, label, path)
    elif isinstance(info, dict):
        raise GeoscalerError(
            f"{path}: the base-colour image {_image_label(doc, info['index'], path)} of "
            f"material {name!r} could not be decoded. Re-save it as PNG or JPEG."
        )
    if "baseColorFactor" in pbr_json:
        factor = np.asarray(pbr_json["baseColorFactor"], dtype=np.float32)
    elif pbr.baseColorFactor is not None:
        factor = (np.asarray(pbr.baseColorFactor, dtype=np.float32) / 255).reshape(4)
    else:
        factor = np.ones(4, dtype=np.float32)
    pbr.name, pbr.baseColorTexture = name, None
    return Material(name, texture, factor, pbr, _gltf_properties(doc, raw, path))


def _check_base_color_info(info: dict, path: Path, name: str) -> None:
    if info.get("texCoord", 0) != 0:
        raise GeoscalerError(
            f"{path}: material {name!r} maps its base colour with TEXCOORD_{info['texCoord']}; "
            "GeoScaler supports TEXCOORD_0 only. Re-export with one UV set."
        )
    if "KHR_texture_transform" in info.get("extensions", {}):
        raise GeoscalerError(
            f"{path}: material {name!r} transforms its base-colour UVs "
            "(KHR_texture_transform), which GeoScaler does not support. Apply the transform "
            "to the UVs in your 3D tool and re-export."
        )


def _gltf_properties(doc: dict, raw: dict, path: Path) -> dict[str, Any]:
    """The material JSON with each texture index replaced by that texture's sampler."""
    properties = copy.deepcopy(raw)
    properties.pop("name", None)
    for keys in _SLOTS.values():
        info = _get_path(properties, keys)
        if isinstance(info, dict) and "index" in info:
            texture = doc.get("textures", [])[info.pop("index")]
            if "sampler" in texture:
                info["sampler"] = copy.deepcopy(doc["samplers"][texture["sampler"]])
    extensions = properties.get("extensions", {})
    for key in [k for k, v in extensions.items() if _has_texture_reference(v)]:
        warnings.warn(
            f"{path}: material extension {key} refers to textures GeoScaler does not carry; "
            "it is left out of saved files.",
            stacklevel=6,
        )
        del extensions[key]
    return properties


def _get_path(tree: dict, keys: tuple[str, ...]) -> Any:
    for key in keys:
        if not isinstance(tree, dict):
            return None
        tree = tree.get(key)
    return tree


def _has_texture_reference(value: Any) -> bool:
    if isinstance(value, dict):
        return "index" in value or any(_has_texture_reference(v) for v in value.values())
    if isinstance(value, list):
        return any(_has_texture_reference(v) for v in value)
    return False


# ---------------------------------------------------------------- assembling


def _assemble(
    path: Path, parts: list[_Part], builders: list[MaterialBuilder], files: list[Path]
) -> TexturedMesh:
    """Join placed parts into one welded TexturedMesh with the materials the faces use."""
    if not parts:
        raise GeoscalerError(f"{path}: contains no triangles; GeoScaler needs a triangle mesh")
    used = sorted({p.material for p in parts if p.material is not None})
    slot = {m: i for i, m in enumerate(used)}
    materials = [builders[m]() for m in used]
    if any(p.material is None for p in parts):
        slot[None] = len(materials)
        materials.append(Material("default", None))
    _check_textures(path, parts, materials, slot)
    parts = sorted(parts, key=lambda p: slot[p.material])
    positions, uvs, normals, faces, face_material = _concatenate(parts, slot)
    _check_finite(path, positions, uvs)
    group, first = _first_occurrence_groups(np.concatenate([positions, uvs], axis=1))
    faces = group[faces]
    keep = np.zeros(len(first), dtype=bool)
    keep[faces] = True
    renumber = np.cumsum(keep) - 1
    faces, first = renumber[faces], first[keep]
    positions, uvs = positions[first], uvs[first]
    vertex_to_point, _ = _first_occurrence_groups(positions)
    file_normals = _merge_normals(normals, group, keep)
    computed = compute_vertex_normals(positions, faces, vertex_to_point)
    has = np.isfinite(file_normals).all(axis=1)
    return TexturedMesh(
        positions=positions,
        faces=faces.astype(np.int64),
        uvs=uvs,
        normals=np.where(has[:, None], file_normals, computed).astype(np.float32),
        vertex_to_point=vertex_to_point,
        face_material=face_material,
        materials=materials,
        source_path=path,
        source_files=list(dict.fromkeys(files)),
    )


def _check_textures(path: Path, parts: list[_Part], materials: list[Material], slot) -> None:
    if all(m.base_color_texture is None for m in materials):
        raise GeoscalerError(
            f"{path}: none of its materials has a base-colour texture (map_Kd in the MTL, "
            "baseColorTexture in glTF), so there is nothing to downsample. Assign an image "
            "texture to the mesh's material and re-export."
        )
    for part in parts:
        material = materials[slot[part.material]]
        if part.uvs is None and material.base_color_texture is not None:
            raise GeoscalerError(
                f"{path}: faces with the textured material {material.name!r} have no texture "
                "coordinates (vt in OBJ, TEXCOORD_0 in glTF). UV-unwrap the mesh and re-export."
            )


def _concatenate(parts: list[_Part], slot: dict) -> tuple[np.ndarray, ...]:
    """Stack parts: float32 positions/uvs, float64 normals (NaN where the file has none)."""
    offsets = np.cumsum([0] + [len(p.positions) for p in parts])
    positions = np.concatenate([p.positions for p in parts]).astype(np.float32)
    uvs = np.concatenate(
        [p.uvs if p.uvs is not None else np.zeros((len(p.positions), 2)) for p in parts]
    ).astype(np.float32)
    normals = np.concatenate(
        [p.normals if p.normals is not None else np.full((len(p.positions), 3), np.nan)
         for p in parts]
    )  # fmt: skip
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=False)])
    face_material = np.concatenate(
        [np.full(len(p.faces), slot[p.material], dtype=np.int64) for p in parts]
    )
    return positions, uvs, normals, faces, face_material


def _check_finite(path: Path, positions: np.ndarray, uvs: np.ndarray) -> None:
    if not (np.isfinite(positions).all() and np.isfinite(uvs).all()):
        raise GeoscalerError(
            f"{path}: has NaN or infinite vertex positions or UVs; repair the mesh and re-export"
        )


def _first_occurrence_groups(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group identical rows (bitwise, with -0 == 0), numbered in order of first occurrence.

    Parameters
    ----------
    rows : (N, K) float32

    Returns
    -------
    group : (N,) int64
        Group of each row.
    first : (G,) int64
        Index of the first row of each group.
    """
    rows = np.ascontiguousarray(rows + np.float32(0))  # -0.0 + 0.0 == +0.0
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[inverse.ravel()].astype(np.int64), first[order].astype(np.int64)


def weld_points(positions: np.ndarray) -> np.ndarray:
    """``(V,)`` int64 point index of each vertex: equal positions share a point.

    Points are numbered in order of first occurrence; ``positions`` is ``(V, 3)`` float32.
    """
    return _first_occurrence_groups(np.asarray(positions, dtype=np.float32))[0]


def _merge_normals(normals: np.ndarray, group: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Average the file normals of the rows welded into each kept vertex (NaN: none)."""
    has = np.isfinite(normals).all(axis=1)
    unit = np.zeros_like(normals)
    unit[has] = _normalize(normals[has], np.zeros(3))
    count = len(keep)
    summed = np.stack(
        [np.bincount(group[has], weights=unit[has, k], minlength=count) for k in range(3)], axis=1
    )
    length = np.linalg.norm(summed, axis=1)
    merged = np.full((count, 3), np.nan)
    good = length > 1e-12
    merged[good] = summed[good] / length[good, None]
    return merged[keep]


def _normalize(vectors: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Unit rows; rows of zero or non-finite length become ``fallback``."""
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    good = np.isfinite(length) & (length > 1e-20)
    return np.where(good, vectors / np.where(good, length, 1.0), fallback)


def compute_vertex_normals(
    positions: np.ndarray, faces: np.ndarray, vertex_to_point: np.ndarray
) -> np.ndarray:
    """Area-weighted normals over welded points, so UV seams do not crease the shading.

    Parameters
    ----------
    positions : (V, 3) float
    faces : (F, 3) int, CCW front faces
    vertex_to_point : (V,) int

    Returns
    -------
    (V, 3) float32 unit normals; vertices of no or degenerate faces get +Z.
    """
    corners = np.asarray(positions, dtype=np.float64)[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    point_of_corner = vertex_to_point[faces].ravel()
    count = int(vertex_to_point.max()) + 1 if len(vertex_to_point) else 0
    weights = np.repeat(face_normals, 3, axis=0)
    summed = np.stack(
        [np.bincount(point_of_corner, weights=weights[:, k], minlength=count) for k in range(3)],
        axis=1,
    )
    return _normalize(summed[vertex_to_point], np.array([0.0, 0.0, 1.0])).astype(np.float32)


# ----------------------------------------------------------------------------- saving


class _ImageOut(NamedTuple):
    """One image file (or GLB image) to write, shared by the slots that show it."""

    name: str
    material: Material
    slot: str
    source: Any  # the texture array or the PIL image of the map

    def png(self, suffix: str) -> bytes:
        return _png_bytes(_map_pixels(self.material, self.slot, self.source, suffix))


# The map slots MTL can express, and their keywords.
_MTL_SLOT_KEYWORDS = {
    "baseColorTexture": "map_Kd",
    "normalTexture": "norm",
    "emissiveTexture": "map_Ke",
}
_SLOT_FILE_NAMES = {
    "baseColorTexture": "basecolor",
    "metallicRoughnessTexture": "metallicroughness",
    "normalTexture": "normal",
    "occlusionTexture": "occlusion",
    "emissiveTexture": "emissive",
}


def save_mesh(mesh: TexturedMesh, path: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Write ``mesh`` as ``.obj`` (+ MTL + PNGs), ``.gltf`` (+ .bin + PNGs) or ``.glb``.

    Every map and glTF material property the mesh carries is written (OBJ/MTL keeps base
    colour, normal and emissive maps and warns about the rest). The base-colour factor is
    always written explicitly; for OBJ, where ``map_Kd`` is the colour, a factor other than 1
    is baked into the texture. All files are first written into a temporary folder beside
    ``path`` and then renamed into place, the main file last.

    Returns
    -------
    list of Path
        The files written, the main file last.

    Raises
    ------
    GeoscalerError
        Unsupported suffix; a file to write is one the mesh was read from (even with
        ``overwrite``); an output exists and ``overwrite`` is False; the folder is missing or
        not writable.
    """
    path = Path(path)
    suffix = _check_suffix(path)
    mesh.validate()
    used = [m for m in range(len(mesh.materials)) if (mesh.face_material == m).any()]
    if not used:
        raise ValueError("the mesh has no faces; there is nothing to save")
    images, slots = _plan_images(mesh, used, path.stem, suffix)
    main = [path.stem + ".mtl"] if suffix == ".obj" else []
    main += [path.stem + ".bin"] if suffix == ".gltf" else []
    names = ([] if suffix == ".glb" else [i.name for i in images]) + main + [path.name]
    _check_targets(mesh, [path.parent / name for name in names], overwrite)
    if suffix == ".obj":
        files = _obj_files(mesh, used, images, slots, path)
    else:
        files = _gltf_files(mesh, used, images, slots, path)
    return _write_files(path.parent, files)


def _plan_images(
    mesh: TexturedMesh, used: list[int], stem: str, suffix: str
) -> tuple[list[_ImageOut], dict[tuple[int, str], int]]:
    """Images to write and which image each (material, slot) shows; shared images once."""
    images: list[_ImageOut] = []
    by_identity: dict[tuple, int] = {}
    slots: dict[tuple[int, str], int] = {}
    for m in used:
        material = mesh.materials[m]
        for slot, pixels_source in _material_maps(material, suffix).items():
            baked = slot == "baseColorTexture" and suffix == ".obj"
            key = (id(pixels_source), tuple(material.base_color_factor) if baked else None)
            if key not in by_identity:
                by_identity[key] = len(images)
                name = f"{stem}_{m}_{_SLOT_FILE_NAMES[slot]}.png"
                images.append(_ImageOut(name, material, slot, pixels_source))
            slots[(m, slot)] = by_identity[key]
    return images, slots


def _material_maps(material: Material, suffix: str) -> dict[str, Any]:
    """The maps of a material that the format can hold: slot -> array or PIL image."""
    maps: dict[str, Any] = {}
    if material.base_color_texture is not None:
        maps["baseColorTexture"] = material.base_color_texture
    for slot in _SLOTS:
        image = getattr(material.source, slot, None) if slot != "baseColorTexture" else None
        if image is None:
            continue
        if suffix == ".obj" and slot not in _MTL_SLOT_KEYWORDS:
            warnings.warn(
                f"material {material.name!r}: OBJ/MTL cannot express its {slot}; it is not "
                "written. Save as .glb or .gltf to keep it.",
                stacklevel=4,
            )
            continue
        maps[slot] = image
    return maps


def _map_pixels(material: Material, slot: str, source: Any, suffix: str) -> np.ndarray:
    """``(H, W, C)`` uint8 pixels to write for a map (OBJ base colour: factor baked in)."""
    if slot != "baseColorTexture":
        return image_to_texture(source)
    factor = np.asarray(material.base_color_factor, dtype=np.float64)
    if suffix == ".obj" and not np.allclose(factor[:3], 1.0):
        return bake_color_factor(source, np.array([*factor[:3], 1.0]))
    return source


def _png_bytes(pixels: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


def _check_targets(mesh: TexturedMesh, targets: list[Path], overwrite: bool) -> None:
    """Refuse inputs as outputs, existing outputs without ``overwrite``, bad folders."""
    inputs = [Path(p).resolve() for p in mesh.source_files]
    if mesh.source_path is not None:
        inputs.append(Path(mesh.source_path).resolve())
    for target in targets:
        resolved = target.resolve()
        same = resolved in inputs or (
            target.exists() and any(p.exists() and os.path.samefile(p, target) for p in inputs)
        )
        if same:
            raise GeoscalerError(
                f"{target}: is a file the mesh was read from; GeoScaler never overwrites its "
                "input. Choose another output name or folder."
            )
        if target.is_dir():
            raise GeoscalerError(f"{target}: is a folder; give an output file name")
    existing = [str(t) for t in targets if t.exists() or t.is_symlink()]
    if existing and not overwrite:
        raise GeoscalerError(
            f"{', '.join(existing)}: already exist(s). Choose another output name, or "
            "allow replacing them (overwrite=True; --force on the command line)."
        )
    folder = targets[-1].parent
    if not folder.is_dir():
        raise GeoscalerError(f"{targets[-1]}: folder {folder} does not exist; create it first")
    if not os.access(folder, os.W_OK):
        raise GeoscalerError(
            f"{targets[-1]}: folder {folder} is not writable; choose another output folder"
        )


def _write_files(folder: Path, files: dict[str, bytes]) -> list[Path]:
    """Write every file into a temporary folder in ``folder``, then rename them into place."""
    try:
        staging = Path(tempfile.mkdtemp(prefix=".geoscaler-", dir=folder))
    except OSError as exc:
        raise GeoscalerError(
            f"{folder}: cannot write into this folder ({exc.strerror}); choose a writable "
            "output folder."
        ) from exc
    try:
        for name, data in files.items():
            (staging / name).write_bytes(data)
        written = []
        for name in files:
            os.replace(staging / name, folder / name)
            written.append(folder / name)
        return written
    except OSError as exc:
        raise GeoscalerError(
            f"{folder}: writing the output failed ({exc}); check free space and permissions."
        ) from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)


# ---------------------------------------------------------------- OBJ writer


def _obj_files(
    mesh: TexturedMesh, used: list[int], images: list[_ImageOut], slots: dict, path: Path
) -> dict[str, bytes]:
    names = _unique_names([mesh.materials[m].name for m in used])
    files = {image.name: image.png(".obj") for image in images}
    mtl_name = path.stem + ".mtl"
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
    mesh: TexturedMesh, used: list[int], names: list[str], images: list[_ImageOut], slots: dict
) -> str:
    lines = ["# written by GeoScaler"]
    for m, name in zip(used, names, strict=True):
        material = mesh.materials[m]
        factor = np.asarray(material.base_color_factor, dtype=np.float64)
        textured = (m, "baseColorTexture") in slots
        diffuse = (1.0, 1.0, 1.0) if textured else factor[:3]
        lines += ["", f"newmtl {name}", "Kd {:.9g} {:.9g} {:.9g}".format(*diffuse)]
        if factor[3] != 1:
            lines.append(f"d {factor[3]:.9g}")
        emissive = getattr(material.source, "emissiveFactor", None)
        if emissive is not None:
            lines.append("Ke {:.9g} {:.9g} {:.9g}".format(*np.asarray(emissive).reshape(3)))
        for slot, keyword in _MTL_SLOT_KEYWORDS.items():
            if (m, slot) in slots:
                lines.append(f"{keyword} {images[slots[(m, slot)]].name}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- glTF writer


class _BinaryBuffer:
    """Accumulates buffer views and accessors of one glTF buffer."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, blob: bytes, target: int | None = None) -> int:
        self.data += b"\x00" * (-len(self.data) % 4)
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(blob)}
        if target is not None:
            view["target"] = target
        self.data += blob
        self.views.append(view)
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, bounds: bool = False) -> int:
        component = 5125 if array.dtype == np.uint32 else 5126
        accessor = {
            "bufferView": self.view(np.ascontiguousarray(array).tobytes(), target),
            "componentType": component,
            "count": len(array),
            "type": kind,
        }
        if bounds:
            accessor["min"] = array.min(axis=0).tolist()
            accessor["max"] = array.max(axis=0).tolist()
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _gltf_files(
    mesh: TexturedMesh, used: list[int], images: list[_ImageOut], slots: dict, path: Path
) -> dict[str, bytes]:
    binary = path.suffix.lower() == ".glb"
    buffer = _BinaryBuffer()
    attributes = {
        "POSITION": buffer.accessor(mesh.positions.astype(np.float32), "VEC3", 34962, True),
        "NORMAL": buffer.accessor(mesh.normals.astype(np.float32), "VEC3", 34962),
        "TEXCOORD_0": buffer.accessor(_gltf_uvs(mesh.uvs), "VEC2", 34962),
    }
    primitives = [
        {
            "attributes": attributes,
            "indices": buffer.accessor(
                mesh.faces[mesh.face_material == m].astype(np.uint32).ravel(), "SCALAR", 34963
            ),
            "material": k,
        }
        for k, m in enumerate(used)
    ]
    files: dict[str, bytes] = {}
    image_json = []
    for image in images:
        png = image.png(path.suffix.lower())
        if binary:
            image_json.append({"bufferView": buffer.view(png), "mimeType": "image/png"})
        else:
            files[image.name] = png
            image_json.append({"uri": urllib.parse.quote(image.name), "mimeType": "image/png"})
    doc = _gltf_document(mesh, used, slots, primitives, image_json, path.stem)
    doc["accessors"], doc["bufferViews"] = buffer.accessors, buffer.views
    doc["buffers"] = [{"byteLength": len(buffer.data)}]
    if binary:
        files[path.name] = _pack_glb(doc, bytes(buffer.data))
        return files
    doc["buffers"][0]["uri"] = urllib.parse.quote(path.stem + ".bin")
    files[path.stem + ".bin"] = bytes(buffer.data)
    files[path.name] = json.dumps(doc, indent=1).encode()
    return files


def _gltf_uvs(uvs: np.ndarray) -> np.ndarray:
    """OpenGL UVs to glTF's (v down from the top of the image), ``(V, 2)`` float32."""
    out = np.asarray(uvs, dtype=np.float32).copy()
    out[:, 1] = 1.0 - out[:, 1]
    return out


def _gltf_document(
    mesh: TexturedMesh, used: list[int], slots: dict, primitives: list, images: list, stem: str
) -> dict:
    textures: list[dict] = []
    samplers: list[dict] = []
    materials = []
    for m in used:
        material = _gltf_material_json(mesh.materials[m], m, slots, textures, samplers)
        materials.append(material)
    doc: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "GeoScaler"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": stem}],
        "meshes": [{"name": stem, "primitives": primitives}],
        "materials": materials,
    }
    for key, value in (("textures", textures), ("samplers", samplers), ("images", images)):
        if value:
            doc[key] = value
    used_extensions = sorted(_extension_names(materials))
    if used_extensions:
        doc["extensionsUsed"] = used_extensions
    return doc


def _gltf_material_json(
    material: Material, m: int, slots: dict, textures: list, samplers: list
) -> dict:
    """The material's saved properties with texture slots pointing at the written images."""
    out = copy.deepcopy(material.properties)
    out["name"] = material.name
    pbr = out.setdefault("pbrMetallicRoughness", {})
    pbr["baseColorFactor"] = [float(x) for x in material.base_color_factor]
    for slot, keys in _SLOTS.items():
        parent = out if len(keys) == 1 else out.setdefault(keys[0], {})
        info = parent.pop(keys[-1], None)
        if (m, slot) not in slots:
            continue
        info = dict(info) if isinstance(info, dict) else {}
        sampler = info.pop("sampler", None)
        texture = {"source": slots[(m, slot)]}
        if sampler is not None:
            if sampler not in samplers:
                samplers.append(sampler)
            texture["sampler"] = samplers.index(sampler)
        if texture not in textures:
            textures.append(texture)
        info["index"] = textures.index(texture)
        parent[keys[-1]] = info
    return out


def _extension_names(value: Any) -> set[str]:
    """Names of every ``extensions`` entry inside a JSON value."""
    names: set[str] = set()
    if isinstance(value, dict):
        if isinstance(value.get("extensions"), dict):
            names.update(value["extensions"])
        for item in value.values():
            names |= _extension_names(item)
    elif isinstance(value, list):
        for item in value:
            names |= _extension_names(item)
    return names
