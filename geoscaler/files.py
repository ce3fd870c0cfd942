"""Safe output files: checked before any work is done, written atomically, inputs never touched."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from PIL import Image

from geoscaler.errors import GeoscalerError


def check_output(path: str | Path, *, force: bool, inputs: Iterable[Path] = ()) -> Path:
    """Validate an output path before work starts.

    Refuses, with a :class:`GeoscalerError` that says what to do: writing over an input file
    (even with ``force``), an existing output without ``force``, and a folder that is missing
    or not writable.
    """
    path = Path(path)
    resolved = path.resolve()
    for source in inputs:
        if Path(source).resolve() == resolved:
            raise GeoscalerError(
                f"{path}: refusing to overwrite the input file; choose another name"
            )
    if path.is_dir():
        raise GeoscalerError(f"{path}: is a folder; give a file name")
    if path.exists() and not force:
        raise GeoscalerError(f"{path}: already exists; pass --force to replace it")
    folder = resolved.parent
    if not folder.is_dir():
        raise GeoscalerError(f"{path}: folder {folder} does not exist; create it first")
    if not os.access(folder, os.W_OK):
        raise GeoscalerError(f"{path}: folder {folder} is not writable")
    return path


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


def write_atomically(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it into place.

    Readers see either the old file or the complete new one, never a partial write.
    """
    path = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def save_png(path: str | Path, image: np.ndarray) -> Path:
    """Write an ``(H, W, C)`` uint8 image as PNG, atomically."""
    return write_atomically(path, lambda tmp: Image.fromarray(image).save(tmp, format="PNG"))
