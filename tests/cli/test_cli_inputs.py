"""Inputs that would exhaust memory, read by the command line in a child whose address space is
capped (RLIMIT_AS): each ends with exit 2 and one line, never MemoryError (exit 3), nothing written."""

from __future__ import annotations

import errno
import gzip
import os
import resource
import subprocess
import sys
import threading

import pytest

from tests.cli.conftest import CLI, Run, assert_one_error_line

ADDRESS_SPACE = 640 << 20
"""The child's cap: room for Python, numpy and the reader (about 300 MB of address space here), far
less than any of the inputs below would need if held whole (512 MiB, expanded or streamed)."""

EXPANDED = 512 << 20
"""What each compressed or streamed input below amounts to."""


def run_capped(*args, timeout=300) -> Run:
    """``python cli.py ARGS…`` in a child limited to :data:`ADDRESS_SPACE` bytes of address space."""

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))

    argv = [sys.executable, str(CLI), *map(str, args)]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")  # threads' buffers: not the input's
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=env, preexec_fn=cap)
    return Run(argv, proc.returncode, proc.stdout, proc.stderr)


def write_gzip_bomb(path, byte: bytes, total: int) -> None:
    """A gzip file expanding to ``total`` bytes of ``byte``: one 16 MiB member compressed once and
    repeated (gzip readers read concatenated members as one stream), so nothing big is ever held."""
    member = gzip.compress(byte * (16 << 20), compresslevel=9)
    with open(path, "wb") as out:
        for _ in range(total // (16 << 20)):
            out.write(member)


class FifoFeeder(threading.Thread):
    """Writes ``piece`` into the FIFO at ``path`` ``count`` times (None: until the reader leaves), then
    closes it. The FIFO is opened without blocking, retried, so a reader that never comes cannot hang it."""

    def __init__(self, path, piece: bytes, count: int | None) -> None:
        super().__init__(daemon=True)
        self.path, self.piece, self.count = path, piece, count
        self.stop = threading.Event()
        self.written = 0

    def run(self) -> None:
        fd = self._open()
        if fd is None:
            return
        try:
            while not self.stop.is_set() and (self.count is None or self.written < self.count * len(self.piece)):
                self.written += os.write(fd, self.piece)
        except BrokenPipeError:  # the reader closed its end: what an endless feed ends with
            pass
        finally:
            os.close(fd)

    def _open(self) -> int | None:
        while not self.stop.wait(0.01):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)
            except OSError as err:
                if err.errno != errno.ENXIO:  # ENXIO: no reader yet
                    raise
                continue
            os.set_blocking(fd, True)
            return fd
        return None


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "feed.g2o"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("name, byte, message", [
    ("bomb.g2o.gz", b"\0", "not a text g2o file (the gzip file holds binary data)"),  # refused at its first block
    ("blank.g2o.gz", b"\n", "there is no pose graph to read"),  # read at constant memory
], ids=["zeros", "newlines"])  # fmt: skip
def test_a_gzip_bomb_ends_in_one_line_and_bounded_memory(tmp_path, name, byte, message):
    bomb = tmp_path / name
    write_gzip_bomb(bomb, byte, EXPANDED)
    run = run_capped("optimize", bomb, "-o", tmp_path / "out.g2o")
    assert_one_error_line(run, str(bomb), message)
    assert sorted(os.listdir(tmp_path)) == [name]


def _optimize_fed(fifo, out, piece: bytes, count: int | None):
    """``(run, feeder)``: ``optimize`` reading the FIFO while a :class:`FifoFeeder` writes into it, stopped after."""
    feeder = FifoFeeder(fifo, piece, count)
    feeder.start()
    try:
        return run_capped("optimize", fifo, "-o", out), feeder
    finally:
        feeder.stop.set()
        feeder.join(10)


def test_a_fifo_of_blank_lines_is_read_to_its_end_at_constant_memory(tmp_path, fifo):
    """``yes '' > fifo``, stopped after 512 MiB: every blank line read, none kept."""
    run, feeder = _optimize_fed(fifo, tmp_path / "out.g2o", b"\n" * (1 << 20), EXPANDED >> 20)
    assert feeder.written == EXPANDED  # the reader took it all, to the end
    assert_one_error_line(run, str(fifo), "there is no pose graph to read")
    assert sorted(os.listdir(tmp_path)) == ["feed.g2o"]


def test_an_endless_fifo_of_zeros_is_refused_at_its_first_block(tmp_path, fifo):
    run, _ = _optimize_fed(fifo, tmp_path / "out.g2o", b"\0" * (1 << 16), None)
    assert_one_error_line(run, str(fifo), "not a text g2o file (it holds binary data)")
    assert sorted(os.listdir(tmp_path)) == ["feed.g2o"]
