"""Process-wide settings: glibc keeps freed memory until told to give it back, and the
resident size the loop reads."""

import os
import platform
import subprocess
import sys

import pytest

linux_glibc = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
    reason="mallopt and /proc/self/statm are glibc's and Linux's",
)

FREE_A_BUFFER = """
import sys
import numpy as np
from geoscaler.process import keep_freed_memory, release_free_memory, resident_bytes
kept = keep_freed_memory()
before = resident_bytes()
buffer = np.ones(200_000_000 // 8)  # 200 MB, touched
held = resident_bytes()
del buffer
after = resident_bytes()
release_free_memory()
print(kept, held - before, after - before, resident_bytes() - before)
"""


def _free_a_buffer(**environment: str) -> tuple[str, int, int, int]:
    """``(kept, grown while held, grown after freeing, grown after releasing free memory)``
    in a fresh process."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    done = subprocess.run(
        [sys.executable, "-c", FREE_A_BUFFER],
        env={**env, **environment},
        capture_output=True,
        text=True,
        check=True,
    )
    kept, held, after, released = done.stdout.split()
    return kept, int(held), int(after), int(released)


@linux_glibc
def test_glibc_keeps_a_freed_buffer_for_reuse_once_told_to():
    kept, held, after, released = _free_a_buffer()
    assert kept == "True"
    assert held >= 190_000_000 and after >= 190_000_000  # still resident: reused, not re-mapped
    assert released < 50_000_000  # until given back on purpose


@linux_glibc
def test_a_users_own_malloc_settings_are_left_as_they_are():
    kept, held, after, _ = _free_a_buffer(MALLOC_MMAP_THRESHOLD_="131072")
    assert kept == "False"
    assert held >= 190_000_000 and after < 50_000_000  # glibc's way: unmapped when freed
