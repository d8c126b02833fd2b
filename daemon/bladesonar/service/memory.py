"""The daemon's heap kept small (glibc; on other C libraries these do nothing).

A long-running process that allocates and frees numpy arrays block after block lets glibc
keep what it freed: its mmap threshold rises to the largest array ever freed (the
reference's tables at start), after which arrays of up to that size come from the heap
and leave it fragmented, and a freed heap is given back only from its top. Measured on
the daemon in steady state (tools/bench_daemon, ALSA loopback): 52.8 MiB resident with
glibc's defaults, 49.6 MiB with the threshold fixed, no change in CPU that shows.
"""

from __future__ import annotations

import ctypes
from typing import Any

#: mallopt's parameter number for the mmap threshold (malloc.h: M_MMAP_THRESHOLD).
M_MMAP_THRESHOLD = -3
#: Allocations from this size on are mapped and unmapped on their own (glibc's initial
#: default, held there: setting it turns the dynamic threshold off).
MMAP_THRESHOLD = 128 * 1024


def _libc(name: str) -> Any:
    try:
        return getattr(ctypes.CDLL(None), name)   # the process's own symbols: its libc
    except (OSError, AttributeError):             # not glibc (musl has neither)
        return None


def fix_mmap_threshold() -> bool:
    """Hold glibc's mmap threshold at MMAP_THRESHOLD; True if it was set."""
    f = _libc("mallopt")
    if f is None:
        return False
    f.argtypes, f.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(f(M_MMAP_THRESHOLD, MMAP_THRESHOLD))


def give_back_memory() -> None:
    """Return freed heap pages to the system (glibc's malloc_trim). Folding 20 s into a
    reference peaks near 100 MiB in the worker thread's arena, and glibc keeps a freed
    arena's pages: the daemon stayed at 122 MiB after learning."""
    f = _libc("malloc_trim")
    if f is None:
        return
    f.argtypes, f.restype = [ctypes.c_size_t], ctypes.c_int
    f(0)
