"""Atomic writes: an output file, or a set of files, appears complete or not at all.

Readers see either the old file or the complete new one, never a partial write. Check the
paths first with :func:`geoscaler.io.paths.check_outputs`; nothing here refuses a path.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image

from geoscaler.errors import GeoscalerError, WriteError


def write_atomically(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it into place.

    Readers see either the old file or the complete new one, never a partial write.
    """
    path = Path(path)
    # A short name of its own: the output's name may be as long as the file system allows.
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=".geoscaler-", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise WriteError(path, exc) from exc
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise WriteError(path, exc) from exc
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


def write_files(folder: Path, files: dict[str, bytes]) -> list[Path]:
    """Write every file into a temporary folder in ``folder``, then rename them into place.

    Parameters
    ----------
    folder : Path
        Where the files go; the temporary folder is made inside it, so renames stay on one
        file system.
    files : dict of str to bytes
        File name -> content, renamed in this order (put the main file last).

    Returns
    -------
    list of Path
        The files written, in the order of ``files``.

    Raises
    ------
    WriteError
        A file could not be written or renamed (no space left, no permission...); it names
        that file in ``folder``, and none of the set is left there.
    """
    try:
        staging = Path(tempfile.mkdtemp(prefix=".geoscaler-", dir=folder))
    except OSError as exc:
        raise GeoscalerError(
            f"{folder}: cannot write into this folder ({exc.strerror}); choose a writable "
            "output folder."
        ) from exc
    name, written = next(iter(files), ""), []
    try:
        for name, data in files.items():
            (staging / name).write_bytes(data)
        for name in files:
            os.replace(staging / name, folder / name)
            written.append(folder / name)
        return written
    except OSError as exc:
        for path in written:  # the set appears whole or not at all
            path.unlink(missing_ok=True)
        raise WriteError(folder / name, exc) from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)
