"""posegraph.heap: freed C-heap pages go back to the system."""

from __future__ import annotations

import ctypes
import platform
from pathlib import Path

import pytest

from posegraph import heap


def _resident_kib() -> int:
    fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
    return int(fields["VmRSS"].split()[0])


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_freed_heap_pages_are_returned():
    libc = ctypes.CDLL(None)
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    blocks, pins = [], []
    for _ in range(3000):  # ~190 MiB in the heap (below glibc's mmap threshold, as a parser's blocks)
        blocks.append(libc.malloc(64 * 1024))
        pins.append(libc.malloc(32))  # between the blocks: freed, they cannot merge into the heap's top
        ctypes.memset(blocks[-1], 1, 64 * 1024)
    for block in blocks:
        libc.free(block)
    before = _resident_kib()
    assert heap.release_free_memory() is True
    assert before - _resident_kib() > 100 * 1024  # most of the 190 MiB handed back
    for pin in pins:
        libc.free(pin)


def test_elsewhere_nothing_happens(monkeypatch):
    monkeypatch.setattr(heap, "_trim", lambda: None)
    assert heap.release_free_memory() is False
