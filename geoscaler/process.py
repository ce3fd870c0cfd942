"""Process-wide settings for busy machines and large CPU buffers, made by the entry points
before torch loads (so no torch import here)."""

from __future__ import annotations

import ctypes
import functools
import importlib
import os
import signal
from collections.abc import Callable

KEPT_MMAP_THRESHOLD = 2_000_000_000
"""Bytes below which glibc serves an allocation from its heap instead of a fresh mapping."""
KEPT_TRIM_THRESHOLD = 2**31 - 1
"""Free bytes at the heap's top past which glibc gives memory back (mallopt takes an int)."""
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's malloc.h
_MALLOC_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


def configure_process() -> None:
    """Idle OpenMP threads sleep instead of spinning (README, "Busy machines"; only where torch
    is not imported yet, and where the user set no policy), numpy asks for no huge pages
    (:func:`without_numpy_hugepages`) and glibc keeps freed memory (:func:`keep_freed_memory`)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    without_numpy_hugepages()
    keep_freed_memory()


def keep_freed_memory() -> bool:
    """Make glibc keep freed buffers for reuse instead of unmapping them, as the Makefile's
    ``MALLOC_MMAP_THRESHOLD_`` and ``MALLOC_TRIM_THRESHOLD_`` do; True where it was set here.

    By default glibc maps every buffer over its threshold afresh and unmaps it when freed, so
    every training step pays for page faults on tens of MB: CPU steps ran 5-50 times slower at
    random. Kept memory also makes the resident size the most the process has held so far,
    which the loop's memory limit reads (:func:`resident_bytes`). Left alone where the user set
    either variable, and off glibc."""
    glibc = _glibc()
    if glibc is None or any(name in os.environ for name in _MALLOC_VARIABLES):
        return False
    kept = glibc.mallopt(_M_MMAP_THRESHOLD, KEPT_MMAP_THRESHOLD) == 1
    return glibc.mallopt(_M_TRIM_THRESHOLD, KEPT_TRIM_THRESHOLD) == 1 and kept


def release_free_memory() -> bool:
    """Give the pages of freed buffers back to the system (glibc's ``malloc_trim``); True
    where it could. With freed memory kept (:func:`keep_freed_memory`), buffers of different
    sizes freed and made again step after step leave holes that only grow the resident size;
    this returns them, and the next buffers there cost their page faults once."""
    glibc = _glibc()
    if glibc is None:
        return False
    glibc.malloc_trim(0)
    return True


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The C library where it is glibc (None elsewhere)."""
    try:
        version = os.confstr("CS_GNU_LIBC_VERSION")
    except (AttributeError, ValueError, OSError):
        return None
    if not version or not version.startswith("glibc"):
        return None
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return None


def resident_bytes() -> int | None:
    """The process's resident set size in bytes, from ``/proc/self/statm`` (None where the
    system has no such file)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


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
