"""Loading a mesh file: the format is chosen by suffix, every failure is a ``GeoscalerError``."""

from __future__ import annotations

from pathlib import Path

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh

from .assemble import assemble
from .gltf import load_gltf
from .obj import load_obj
from .paths import FORMAT_NAMES, check_suffix, printable_path


def load_mesh(path: str | Path) -> TexturedMesh:
    """Load an OBJ (+ MTL), glTF or GLB file as one :class:`TexturedMesh`.

    Scene-graph transforms are applied (mirroring ones flip the winding back to CCW), every
    part is joined, vertices are welded by exact (position, UV, TANGENT, COLOR_0, TEXCOORD_1)
    and points by exact position. Normals come from the file where it has them, else they are
    area-weighted over the welded points. Only materials used by faces are kept, grouped in
    file order, faces sorted by material. Every texture map is decoded, each image once: the
    slots and materials that show one image share one read-only array
    (:meth:`geoscaler.mesh.TexturedMesh.images`). Only files inside the mesh's folder are read.

    Raises
    ------
    GeoscalerError
        Missing, unreadable or corrupt file, unsupported format, a referenced file missing or
        outside the mesh's folder, no UVs on textured faces, no base-colour texture at all;
        what GeoScaler could not write back (animations, skins, morph targets, vertex
        attributes other than POSITION, NORMAL, TANGENT, TEXCOORD_0/1 and COLOR_0).
    """
    path = Path(path)
    suffix = check_suffix(path)
    try:
        found = path.is_file()
    except OSError as exc:  # a folder on the way that cannot be searched, a name too long
        raise GeoscalerError(
            f"{printable_path(path)}: cannot be read ({exc.strerror}). Check the path and the "
            "permissions of its folders."
        ) from exc
    if not found:
        raise GeoscalerError(f"{path}: no such file. Check the path and the file name.")
    loader = load_obj if suffix == ".obj" else load_gltf
    try:
        return assemble(path, *loader(path))
    except GeoscalerError as exc:
        if str(path) in str(exc):
            raise
        raise GeoscalerError(f"{path}: {exc}") from exc  # a problem in its MTL
    except Exception as exc:
        if isinstance(exc, OSError) and exc.filename is not None:  # a file, not its content
            raise GeoscalerError(
                f"{path}: {printable_path(exc.filename)} cannot be read ({exc.strerror}). "
                "Check that the file and its folder are readable."
            ) from exc
        raise GeoscalerError(
            f"{path}: could not be read as {FORMAT_NAMES[suffix]} "
            f"({type(exc).__name__}: {exc}). The file may be corrupt or truncated: "
            "re-export it from your 3D tool."
        ) from exc
