"""Give the C heap's free pages back to the operating system (glibc's ``malloc_trim``).

Parsing a g2o file and the chordal start make and free many small and middle-sized blocks; glibc
keeps the freed pages in its heap, where the large arrays made later (each ``mmap``-ed on its own
above glibc's threshold) cannot reuse them, so they stay resident for the rest of the run and
count in its peak. On a 200,000-pose sphere (``docs/benchmarks.md``, "Memory per pose") trimming
returns 120 MiB after reading and 330 MiB after the chordal start.
"""

from __future__ import annotations

import functools

__all__ = ["release_free_memory"]


@functools.lru_cache(maxsize=1)
def _trim():
    """glibc's ``malloc_trim``, or None (another C library, another system)."""
    import ctypes.util  # here: only a run that reads a file needs it

    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):  # no such library, or not glibc (musl, macOS, Windows)
        return None


def release_free_memory() -> bool:
    """``malloc_trim(0)`` where the C library is glibc; whether it ran (nothing happens elsewhere)."""
    trim = _trim()
    if trim is None:
        return False
    trim(0)
    return True
