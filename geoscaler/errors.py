"""The one exception type users see: a message that says what, where and what to do."""

from __future__ import annotations

import errno
from pathlib import Path


class GeoscalerError(Exception):
    """A problem with the user's input or environment, explained in plain words.

    The CLI prints the message and exits with status 2 instead of showing a traceback.
    """


NO_SPACE = (errno.ENOSPC, errno.EDQUOT)
NOT_ALLOWED = (errno.EACCES, errno.EPERM, errno.EROFS)


class WriteError(GeoscalerError):
    """Writing the output file ``path`` failed with ``error`` (an OSError): no space left, no
    permission, a failing device. The writer has removed what it had begun."""

    def __init__(self, path: str | Path, error: OSError):
        self.path, self.error = Path(path), error
        super().__init__(f"{self.path}: {write_failure(error)}")

    def moved(self, staging: Path, folder: Path) -> WriteError:
        """The same failure named at its final place: ``path`` under ``staging`` (a folder the
        file was to be renamed from) as under ``folder``; other paths are kept."""
        if staging not in self.path.parents:
            return self
        return WriteError(folder / self.path.relative_to(staging), self.error)


def write_failure(error: OSError) -> str:
    """Why a write failed and what to do, in plain words (no path)."""
    if error.errno in NO_SPACE:
        return "no space left on the device; free space or choose another output folder"
    if error.errno in NOT_ALLOWED:
        return (
            f"not allowed to write it ({error.strerror}); check the folder's permissions or "
            "choose another output folder"
        )
    reason = error.strerror or str(error) or type(error).__name__
    return f"writing it failed ({reason}); check the device or choose another output folder"
