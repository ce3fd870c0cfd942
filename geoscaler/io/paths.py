"""Path safety: which files GeoScaler reads, and which it agrees to write.

Reading: a mesh may only reference files inside its own folder (:func:`resolve_reference`).

Writing: :func:`check_outputs` is the one output-safety check, used by
:func:`geoscaler.io.save_mesh` and by every command before it starts work. It refuses writing
over an input file, an existing output without ``force``, a missing folder and a folder that is
not writable, one message per mistake, and touches nothing while it looks: only its last step,
asked for by the last check before long work, tries a file in each folder (see ``probe``).
:func:`prepare_folder` creates an output folder.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import string
import tempfile
import unicodedata
from collections.abc import Iterable
from pathlib import Path

from geoscaler.errors import GeoscalerError

SUPPORTED_SUFFIXES = (".obj", ".gltf", ".glb")
"""Mesh file types GeoScaler reads and writes."""
FORMAT_NAMES = {".obj": "Wavefront OBJ", ".gltf": "glTF 2.0", ".glb": "binary glTF (GLB)"}
SAFE_CHARACTERS = frozenset(string.ascii_letters + string.digits + "-._")
"""What the names of side files are made of: a URI, an MTL statement and a shell hold them as
they are (no percent-encoding, no spaces, no quoting)."""


def check_suffix(path: Path) -> str:
    """The lower-case suffix of a mesh file name; ``GeoscalerError`` when not supported."""
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise GeoscalerError(
            f"{path}: unsupported file type {suffix or '(none)'!r}. GeoScaler reads and writes "
            f"{', '.join(SUPPORTED_SUFFIXES)}; convert the mesh to one of them (e.g. in Blender)."
        )
    return suffix


# ----------------------------------------------------------------------------- reading


def resolve_reference(ref: str, base: Path, root: Path, owner: Path, what: str) -> Path:
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


# ----------------------------------------------------------------------------- writing


def safe_characters(text: str) -> str:
    """``text`` in :data:`SAFE_CHARACTERS`: accents dropped (``ö`` -> ``o``), each run of
    other characters replaced by one ``_``."""
    ascii_text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()
    return re.sub(r"[^A-Za-z0-9._-]+", "_", ascii_text)


def side_file(path: Path, suffix: str) -> Path:
    """The file written beside the mesh file ``path`` whose name ends in ``suffix``
    (``".bin"``, ``".mtl"``, ``"_albedo.png"``), named so that readers find it whatever the
    mesh file is called (the mesh file keeps its name): ``path``'s stem where it is made of
    :data:`SAFE_CHARACTERS`, else the stem in them (:func:`safe_characters`, at most 64) and
    8 hex digits of its SHA-1, so different stems keep different side files
    (``öut ☃ 雪.gltf`` -> ``out_`` and 8 digits ``.bin``)."""
    stem = path.stem
    if not stem or safe_characters(stem) != stem:
        digest = hashlib.sha1(stem.encode("utf-8", "surrogateescape")).hexdigest()[:8]
        words = safe_characters(stem).strip("_")[:64]
        stem = f"{words}_{digest}" if words else digest
    return path.parent / (stem + suffix)


def check_outputs(
    paths: Iterable[str | Path],
    *,
    force: bool,
    inputs: Iterable[str | Path] = (),
    probe: bool = False,
) -> list[Path]:
    """Refuse, before any work is done, output files that cannot or must not be written.

    Refused, with a :class:`GeoscalerError` that says what to do:

    - an output that is one of ``inputs`` (the same path once links are resolved, or the same
      file under another name), even with ``force``;
    - an output that is a folder, a device, a pipe or a socket;
    - outputs that exist (all of them named) unless ``force``;
    - an output whose folder is missing, a system folder or not writable.

    Every check only looks (names, ``stat``, ``os.access``) until all have passed; a refused
    output leaves no trace in any folder, not even a file made and removed again.

    Parameters
    ----------
    paths : iterable of str or Path
        Every file about to be written (e.g. :func:`geoscaler.io.output_files`).
    force : bool
        Replace existing outputs (``--force`` on the command line, ``overwrite`` in Python).
    inputs : iterable of str or Path
        Files the outputs are made from (e.g. ``TexturedMesh.source_files``).
    probe : bool
        Then also create a file in each folder, as writing will, so that a folder
        ``os.access`` wrongly calls writable (a file system or server that refuses later) is
        refused before long work: an unnamed file (``O_TMPFILE``), which never appears in
        the folder, or where the file system cannot make one, a named file removed at once.
        Ask for it only in the last check before long work, once nothing else can refuse.
        Without it, the write itself is the test (:mod:`geoscaler.io.atomic`).

    Returns
    -------
    list of Path
        ``paths``, in order.
    """
    targets = [Path(p) for p in paths]
    for target in targets:
        _check_name(target)
    try:
        _check_outputs(targets, force, [Path(p).resolve() for p in inputs])
        folders = _check_folders(targets)
    except OSError as error:  # a folder on the way cannot be searched, a name is too long...
        name = printable_path(error.filename) if error.filename else "an output"
        raise GeoscalerError(
            f"{name}: cannot be checked for writing ({error.strerror}); choose another output"
        ) from error
    for folder, target in folders.items() if probe else ():
        problem = _cannot_create(folder)
        if problem is not None:
            raise _not_writable(target, folder, problem)
    return targets


def _check_outputs(targets: list[Path], force: bool, sources: list[Path]) -> None:
    for target in targets:
        same = target.resolve() in sources or (
            target.exists() and any(s.exists() and os.path.samefile(s, target) for s in sources)
        )
        if same:
            raise GeoscalerError(
                f"{target}: refusing to overwrite the input file (the mesh was read from it); "
                "choose another output name or folder"
            )
        if target.is_dir():
            raise GeoscalerError(f"{target}: is a folder; give an output file name")
        if target.exists() and not target.is_file():
            raise GeoscalerError(
                f"{target}: is not a regular file (a device, pipe or socket); give an output "
                "file name"
            )
    existing = [str(t) for t in targets if t.exists() or t.is_symlink()]
    if existing and not force:
        one = len(existing) == 1
        raise GeoscalerError(
            f"{', '.join(existing)}: already exist{'s' if one else ''}; pass --force to "
            f"replace {'it' if one else 'them'} (overwrite=True in Python), or choose another "
            "output name"
        )


def _check_folders(targets: list[Path]) -> dict[Path, Path]:
    """Each output folder (existing, not a system folder, writable by ``os.access``) and the
    last output in it."""
    last_in_folder = {target.resolve().parent: target for target in targets}
    for folder, target in last_in_folder.items():
        if not folder.is_dir():
            raise GeoscalerError(f"{target}: folder {folder} does not exist; create it first")
        if folder.parts[1:2] in (("proc",), ("sys",)) or (
            folder.parts[1:2] == ("dev",) and folder.parts[2:3] != ("shm",)
        ):
            raise GeoscalerError(
                f"{target}: folder {folder} is a system folder (/proc, /sys, /dev), not for "
                "files; choose another output folder"
            )
        if not os.access(folder, os.W_OK | os.X_OK):
            raise _not_writable(target, folder)
    return last_in_folder


def _not_writable(target: Path, folder: Path, problem: str | None = None) -> GeoscalerError:
    why = f" ({problem})" if problem else ""
    return GeoscalerError(
        f"{target}: folder {folder} is not writable{why}; choose another output folder"
    )


def _check_name(target: Path) -> None:
    """Refuse a file name or path longer than the file system takes (ENAMETOOLONG later)."""
    folder = target.absolute().parent
    while folder != folder.parent and not _exists(folder):
        folder = folder.parent
    try:
        name_max = os.pathconf(folder, "PC_NAME_MAX")
        path_max = os.pathconf(folder, "PC_PATH_MAX")
    except OSError:
        name_max, path_max = 255, 4096
    longest = max((len(os.fsencode(part)) for part in target.parts), default=0)
    whole = len(os.fsencode(target.absolute()))
    if longest > name_max or whole >= path_max:
        limit = (
            f"{longest} bytes in one name, at most {name_max}"
            if longest > name_max
            else f"{whole} bytes in all, at most {path_max - 1}"
        )
        raise GeoscalerError(
            f"{printable_path(target)}: the name is too long for the file system ({limit}); "
            "choose a shorter output name"
        )


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except OSError:  # too long, or a folder on the way cannot be searched
        return False


_NO_TMPFILE = (errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL)
"""What ``open(O_TMPFILE)`` fails with where the kernel or the file system has no unnamed
files (NFS, FAT, older kernels)."""


def _cannot_create(folder: Path) -> str | None:
    """Why no file can be made in ``folder``, or None when one can: an unnamed file, which
    never appears in the folder, or where there are none, a named one removed at once."""
    flag = getattr(os, "O_TMPFILE", None)
    if flag is not None:
        try:
            os.close(os.open(folder, flag | os.O_WRONLY, 0o600))
            return None
        except OSError as error:
            if error.errno not in _NO_TMPFILE:
                return error.strerror
    try:
        fd, name = tempfile.mkstemp(prefix=".geoscaler-probe-", dir=folder)
    except OSError as error:
        return error.strerror
    os.close(fd)
    os.unlink(name)
    return None


def printable_path(path: str | Path | bytes) -> str:
    """A path for a message, shortened to its first and last 60 characters when longer."""
    text = os.fsdecode(path) if isinstance(path, bytes) else str(path)
    return text if len(text) <= 130 else f"{text[:60]}...{text[-60:]}"


def check_output(
    path: str | Path, *, force: bool, inputs: Iterable[str | Path] = (), probe: bool = False
) -> Path:
    """:func:`check_outputs` for one file; returns it as a Path."""
    return check_outputs([path], force=force, inputs=inputs, probe=probe)[0]


def prepare_folder(path: str | Path, flag: str = "--out") -> Path:
    """Create an output folder (and parents) or explain, as ``flag``, why it cannot be."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise GeoscalerError(f"{flag} {folder}: is a file; give a folder for the outputs")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise GeoscalerError(f"{flag} {folder}: cannot create the folder ({error})") from error
    return folder
