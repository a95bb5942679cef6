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
    import ctypes  # here, and not ctypes.util (which imports shutil, tempfile, random: startup time)

    try:
        return ctypes.CDLL(None).malloc_trim  # the symbols the process has loaded: glibc's, on Linux
    except (OSError, AttributeError, TypeError):  # not glibc (musl, macOS), or Windows (no CDLL(None))
        return None


def release_free_memory() -> bool:
    """``malloc_trim(0)`` where the C library is glibc; whether it ran (nothing happens elsewhere)."""
    trim = _trim()
    if trim is None:
        return False
    trim(0)
    return True
