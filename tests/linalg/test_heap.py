"""posegraph.linalg.heap: freed C-heap pages go back to the system."""

from __future__ import annotations

import platform
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from posegraph.linalg import heap

# In a fresh interpreter (the test process's own heap is whatever the tests before left): ~190 MiB of
# 64 KiB blocks (below glibc's mmap threshold, as a parser's are), each followed by a small block so
# that, freed, they cannot merge into the heap's top and be returned by free() itself.
CHILD = """
    import ctypes, sys
    from posegraph.linalg import heap

    def resident_kib():
        return int(next(l for l in open("/proc/self/status") if l.startswith("VmRSS")).split()[1])

    libc = ctypes.CDLL(None)
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    # M_TRIM_THRESHOLD (-1) out of reach: free() itself never gives the heap's top back, which it did
    # when the small pins landed in older holes and the freed blocks merged into the top (then
    # nothing was left for malloc_trim, and the test failed by the heap's history, e.g. the env's size)
    libc.mallopt(-1, 1 << 30)
    blocks, pins = [], []
    for _ in range(3000):
        blocks.append(libc.malloc(64 * 1024))
        pins.append(libc.malloc(32))
        ctypes.memset(blocks[-1], 1, 64 * 1024)
    for block in blocks:
        libc.free(block)
    freed = resident_kib()
    ran = heap.release_free_memory()
    print(ran, freed - resident_kib())
"""


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_freed_heap_pages_are_returned():
    child = subprocess.run([sys.executable, "-c", textwrap.dedent(CHILD)], capture_output=True, text=True, timeout=60,
                           cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert child.returncode == 0, child.stderr
    ran, returned_kib = child.stdout.split()
    assert ran == "True"
    assert int(returned_kib) > 100 * 1024  # most of the 190 MiB handed back (free() alone returns none of it)


def test_elsewhere_nothing_happens(monkeypatch):
    monkeypatch.setattr(heap, "_trim", lambda: None)
    assert heap.release_free_memory() is False


@pytest.mark.skipif(platform.system() != "Linux", reason="/proc/meminfo is Linux's")
def test_available_memory_is_positive_and_at_most_the_total(monkeypatch):
    total = int(next(line for line in open("/proc/meminfo") if line.startswith("MemTotal")).split()[1]) * 1024
    available = heap.available_bytes()
    assert 0 < available <= total
    monkeypatch.setattr(heap, "_cgroup_headroom", lambda: 12345)  # a container's limit caps it
    assert heap.available_bytes() == 12345


def test_available_memory_is_unknown_without_meminfo(monkeypatch):
    import builtins

    real_open = builtins.open

    def no_meminfo(path, *args, **kwargs):
        if str(path) == "/proc/meminfo":
            raise FileNotFoundError(path)
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", no_meminfo)
    monkeypatch.setattr(heap, "_cgroup_headroom", lambda: None)
    monkeypatch.setattr(heap, "_address_space_headroom", lambda: None)
    assert heap.available_bytes() is None
    monkeypatch.setattr(heap, "_address_space_headroom", lambda: 4321)  # the process's own limit is still known
    assert heap.memory_limit() == (4321, "address space left under the process's limit (ulimit -v)")


@pytest.mark.skipif(platform.system() != "Linux", reason="/proc/self/status is Linux's")
def test_the_address_space_limit_caps_the_memory_a_factor_may_take():
    """Under ``prlimit --as`` (RLIMIT_AS) an allocation beyond the limit fails however much memory the
    machine has free: the limit, less what the process maps already, is what a factor may take."""
    import subprocess
    import sys

    cap = 3 << 30
    code = ("from posegraph.linalg import heap; size, what = heap.memory_limit(); print(size); print(what); "
            "print(heap.factor_exceeds_memory(int(2.5 * 2**30)))")

    def limited():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          preexec_fn=limited, cwd=str(__import__("pathlib").Path(__file__).resolve().parents[2]))
    size, what, reason = proc.stdout.splitlines()
    assert proc.returncode == 0, proc.stderr
    if heap.available_bytes() is not None and heap.available_bytes() < int(size):  # pragma: no cover - a small machine
        pytest.skip("this machine has less memory available than the limit set")
    assert 0 < int(size) < cap and what == "address space left under the process's limit (ulimit -v)"
    assert reason.startswith("the Cholesky factor of this graph would take 2.5 GiB, more than 75% of the ")
    assert reason.endswith(" of address space left under the process's limit (ulimit -v)")
