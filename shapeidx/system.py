"""Process-wide settings for the long-running entry points: memory reuse, the core count."""

from __future__ import annotations

import ctypes
import os
import sys

# glibc's mallopt parameters
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_memory(limit: int = 1 << 30) -> bool:
    """Ask glibc to keep freed blocks up to ``limit`` bytes for reuse instead of unmapping them.

    A signature allocates some 20 MB of short-lived numpy temporaries. By default glibc
    hands every block above its mmap threshold back to the kernel when freed, so the next
    signature pays page faults on all of it again: measured by scripts/bench.py, keeping
    them makes cleaning and signatures 1.2 to 2 times faster. Called by the command line
    and by build workers, never on import. Returns False where glibc is not the allocator.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        try:  # glibc's usual name first: find_library runs ldconfig, a cost on every start-up
            libc = ctypes.CDLL("libc.so.6")
        except OSError:
            from ctypes.util import find_library  # imports subprocess, tempfile, bz2, lzma: only if needed

            libc = ctypes.CDLL(find_library("c") or "libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, limit)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, 2 * limit))
    except (OSError, AttributeError):
        return False


def available_cores() -> int:
    """Cores this process may use (its CPU affinity, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1
