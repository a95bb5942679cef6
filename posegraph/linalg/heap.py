"""The process's memory: the C heap's free pages given back to the operating system (glibc's
``malloc_trim``), the memory still available, and whether a Cholesky factor fits in it.

Parsing a g2o file and the chordal start make and free many small and middle-sized blocks; glibc
keeps the freed pages in its heap, where the large arrays made later (each ``mmap``-ed on its own
above glibc's threshold) cannot reuse them, so they stay resident for the rest of the run and
count in its peak. On a 200,000-pose sphere (``docs/benchmarks.md``, "Memory per pose") trimming
returns 120 MiB after reading and 330 MiB after the chordal start.
"""

from __future__ import annotations

import functools

__all__ = ["release_free_memory", "available_bytes", "memory_limit", "FACTOR_MEMORY_SHARE", "factor_exceeds_memory"]


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


def _cgroup_headroom() -> int | None:
    """Bytes this process's cgroup (v2) may still take before its ``memory.max``, or None (no limit)."""
    try:
        with open("/sys/fs/cgroup/memory.max") as limit, open("/sys/fs/cgroup/memory.current") as current:
            maximum, used = limit.read().strip(), current.read().strip()
    except OSError:
        return None
    return max(int(maximum) - int(used), 0) if maximum.isdigit() and used.isdigit() else None


def _address_space_headroom() -> int | None:
    """Bytes of address space this process may still map before its ``RLIMIT_AS`` (``ulimit -v``,
    ``prlimit --as``): the limit less the ``VmSize`` it maps already; None without a limit."""
    import resource

    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit == resource.RLIM_INFINITY:
        return None
    try:
        with open("/proc/self/status") as status:
            size = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
    except (OSError, StopIteration, ValueError, IndexError):
        return None
    return max(limit - size, 0)


def memory_limit() -> tuple[int, str] | None:
    """``(bytes, what limits them)``: the least of the memory a new allocation can still get without
    swapping and the process's own limits, or None where none is known.

    The kernel's ``MemAvailable`` estimate (``/proc/meminfo``: free memory plus the page cache and
    slabs it can reclaim); the cgroup's headroom when a container sets ``memory.max`` (the host's
    meminfo does not see that limit); the address space left under ``RLIMIT_AS``, where an
    allocation beyond it fails (MemoryError) however much memory is free. Linux only.
    """
    found = []
    try:
        with open("/proc/meminfo") as meminfo:
            fields = dict(line.split(":", 1) for line in meminfo if ":" in line)
        found.append((int(fields["MemAvailable"].split()[0]) * 1024, "memory available"))
    except (OSError, KeyError, ValueError):
        pass
    for headroom, what in ((_cgroup_headroom(), "memory left under the cgroup's memory.max"),
                           (_address_space_headroom(), "address space left under the process's limit (ulimit -v)")):
        if headroom is not None:
            found.append((headroom, what))
    return min(found, key=lambda pair: pair[0]) if found else None


def available_bytes() -> int | None:
    """Memory a new allocation can still get, in bytes (:func:`memory_limit`), or None where unknown."""
    limit = memory_limit()
    return None if limit is None else limit[0]


FACTOR_MEMORY_SHARE = 0.75
"""A Cholesky factor is taken to fit when the bytes foreseen for it
(:func:`posegraph.linalg.cholmod.block_factor_bytes`, from the vertex pattern: 3.87 GiB on the 200k-pose
sphere, whose scalar analysis foresees 3.37 GiB and whose numeric factorisation grows the process
by 3.21 GiB) are at most this share of :func:`available_bytes`; the rest is for the arrays beside
it (H, cvxopt's copy of it, an iteration's per-edge temporaries: 1.9 GiB beside that factor)."""


def factor_exceeds_memory(needed: int | None) -> str | None:
    """Why a factor of ``needed`` bytes would not fit (:data:`FACTOR_MEMORY_SHARE`), or None when it
    fits or either size is unknown (then factorising is tried, as it always was)."""
    available = available_bytes()
    if needed is None or available is None or needed <= FACTOR_MEMORY_SHARE * available:
        return None
    limit = memory_limit()  # which limit that was, for the message
    what = limit[1] if limit is not None and limit[0] == available else "memory available"
    return (f"the Cholesky factor of this graph would take {_readable(needed)}, more than "
            f"{FACTOR_MEMORY_SHARE:.0%} of the {_readable(available)} of {what}")  # fmt: skip


def _readable(size: int) -> str:
    """``size`` bytes in GiB, MiB or kiB, whichever leaves at least 1 before the point."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20)):
        if size >= scale:
            return f"{size / scale:.1f} {unit}"
    return f"{size / 2**10:.1f} kiB"
