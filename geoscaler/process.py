"""Process-wide settings for busy machines and large CPU buffers, made by the entry points
before torch loads (so no torch import here)."""

from __future__ import annotations

import importlib
import os
import signal
from collections.abc import Callable


def configure_process() -> None:
    """Idle OpenMP threads sleep instead of spinning (README, "Busy machines"; only where torch
    is not imported yet, and where the user set no policy), and numpy asks for no huge pages
    (:func:`without_numpy_hugepages`)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    without_numpy_hugepages()


def without_numpy_hugepages() -> None:
    """Stop numpy advising the kernel to back large arrays with transparent huge pages.

    Where the kernel compacts memory on that advice (``/sys/kernel/mm/transparent_hugepage/
    defrag`` set to ``madvise``, as on the development and CI machines), the first touch of a
    new large array can stall for seconds: decoding a 4096 x 4096 texture took 6.6 s with the
    advice and 0.28 s without, in a fresh process. The entry points (command line, a batch
    worker) call this once; numpy versions without the switch are left as they are.
    """
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            switch = getattr(importlib.import_module(name), "_set_madvise_hugepage", None)
        except ImportError:
            continue
        if switch is not None:
            switch(False)
            return


def exit_status_kept(command: Callable[[], int]) -> int:
    """Run ``command`` as the process's command line and return its exit status, which a late
    Ctrl-C can no longer change: SIGINT is ignored from the moment the command has ended.

    Without this, a Ctrl-C that comes after the command's own handling (e.g. the second of
    two, while the interpreter shuts down: Python then puts SIGINT's default action back) kills
    the process by SIGINT instead of letting it exit with the status the command chose (130
    after an interruption). A KeyboardInterrupt that escapes ``command`` ends it with 130.
    """
    status = 130
    try:
        status = command()
    except KeyboardInterrupt:  # between the command's own handling and here
        pass
    finally:
        while True:  # a Ctrl-C pending here is raised by signal.signal's own check: again
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
                break
            except KeyboardInterrupt:
                status = 130
    return status
