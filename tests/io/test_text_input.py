"""The streaming reader: lines across block boundaries, binary refused from the first block, memory
bounded by the data (blank lines, comments, gzip bombs, an endless line)."""

from __future__ import annotations

import gzip
import io
import os
import threading
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posegraph.errors import G2oFormatError, InputError
from posegraph.io import text_input
from posegraph.io.g2o import read_g2o
from posegraph.io.text_input import BLOCK_BYTES, MAX_LINE_CHARS

VERTEX = "VERTEX_SE3:QUAT {i} {i} 0 0 0 0 0 1"
STREAM_PATIENCE = 30.0
"""Seconds a test's FIFO writer waits for the reader's refusal before it ends the stream (a timeout, not a
measurement: the refusal comes within a few MiB)."""
EDGE = "EDGE_SE3:QUAT {i} {j} 1 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"


def graph_text(n: int = 3) -> str:
    return "".join(VERTEX.format(i=i) + "\n" for i in range(n)) + "".join(
        EDGE.format(i=i, j=i + 1) + "\n" for i in range(n - 1))


def numbered_data(blocks) -> list[tuple[int, str]]:
    """``(line number, line)`` of every line with data the blocks hold."""
    return [(number, line.split()) for first, lines in blocks for number, line in enumerate(lines, start=first)
            if line.strip()]


def expected_data(text: str) -> list[tuple[int, str]]:
    """What the reader must give for ``text``: lines split at "\\n", comments cut, blank lines left out."""
    lines = [line.partition("#")[0] for line in text.split("\n")]
    return [(number, line.split()) for number, line in enumerate(lines, start=1) if line.strip()]


def write_gzip_of(path, piece: bytes, total: int) -> None:
    """A gzip file expanding to ``total`` bytes of ``piece`` repeated, compressed piece by piece: the
    expanded data is never held (a 1 GiB bomb of zeros costs 16 MiB at a time, and ~1 MB on disk)."""
    packer = zlib.compressobj(9, zlib.DEFLATED, 31)  # wbits 31: the gzip container
    chunk = piece * ((1 << 24) // len(piece))
    with open(path, "wb") as out:
        for _ in range(total // len(chunk)):
            out.write(packer.compress(chunk))
        out.write(packer.flush())


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.sampled_from(["", " ", "\t", "#", "# c", "VERTEX_SE3:QUAT", " 1 2", "x#y", "é", "\r", "  ##"]),
             max_size=40).map("".join).map(lambda s: s.replace("VERTEX_SE3:QUAT", "\nVERTEX_SE3:QUAT")),
    st.integers(1, 9),
)
def test_lines_are_the_same_whatever_the_block_size(text, block):
    """A line cut by a block boundary (or several), a comment or blank run across blocks, a two-byte
    character split in two: the lines with data, their tokens and numbers are those of the whole text."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(text_input, "BLOCK_BYTES", block)
        blocks = text_input._blocks(io.BytesIO(text.encode()), "t.g2o", "g2o")
        assert numbered_data(blocks) == expected_data(text)


def test_line_numbers_survive_megabytes_of_blank_lines_and_comments(tmp_path):
    blank = "\n" * (3 * BLOCK_BYTES)  # blocks of nothing but blank lines: counted, not kept
    comments = "# a comment\n" * (BLOCK_BYTES // 6)
    text = graph_text() + blank + comments + "VERTEX_SE3:QUAT 9 oops 0 0 0 0 0 1\n"
    path = tmp_path / "g.g2o"
    path.write_text(text)
    bad_line = text.count("\n")
    with pytest.raises(G2oFormatError) as info:
        read_g2o(path)
    assert info.value.line == bad_line and "'oops'" in str(info.value)


def test_a_gzip_bomb_of_zeros_is_refused_after_its_first_block(tmp_path, monkeypatch):
    """256 MiB of zeros in 256 kB: refused as binary having expanded one block, not the whole."""
    bomb = tmp_path / "bomb.g2o.gz"
    write_gzip_of(bomb, b"\0", 256 << 20)
    expanded = []
    real = text_input._decompressing

    def counting(stream, compression):
        unpacked = real(stream, compression)

        class Counted:
            def read(self, size=-1):
                data = unpacked.read(size)
                expanded.append(len(data))
                return data

        return Counted()

    monkeypatch.setattr(text_input, "_decompressing", counting)
    with pytest.raises(InputError) as info:
        read_g2o(bomb)
    assert str(info.value) == f"{bomb}: not a text g2o file (the gzip file holds binary data)"
    assert sum(expanded) <= BLOCK_BYTES


def test_a_nul_byte_further_on_is_refused_with_its_line(tmp_path):
    path = tmp_path / "late.g2o"
    path.write_bytes(graph_text().encode() + b"\n" * (2 * BLOCK_BYTES) + b"EDGE\0\n")
    with pytest.raises(InputError) as info:
        read_g2o(path)
    assert info.value.line == graph_text().count("\n") + 2 * BLOCK_BYTES + 1
    assert "not a text g2o file (a NUL byte" in info.value.reason


def test_an_endless_line_of_data_is_refused_when_it_outgrows_any_line(tmp_path):
    path = tmp_path / "long.g2o"
    path.write_text(graph_text() + "VERTEX_SE3:QUAT " + "1" * (MAX_LINE_CHARS + 10))  # no newline at all
    with pytest.raises(InputError) as info:
        read_g2o(path)
    assert info.value.line == 6 and "characters of data: no g2o line is that long" in info.value.reason
    assert len(str(info.value)) < 200


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="FIFOs are POSIX")
def test_an_endless_line_streamed_through_a_fifo_is_refused_while_it_streams(tmp_path):
    """A writer that never ends its line nor the stream: the reader must refuse the line once it outgrows
    MAX_LINE_CHARS, while the writer is still writing — at the end of the stream (the finite file's case)
    is too late, since that end never comes. The writer gives up after 8 × MAX_LINE_CHARS and a wait of
    STREAM_PATIENCE seconds (so that a reader without the bound fails instead of hanging), then closes."""
    fifo = tmp_path / "endless.g2o"
    os.mkfifo(fifo)
    refused, gave_up = threading.Event(), threading.Event()

    def write() -> None:
        try:
            with open(fifo, "wb") as out:
                out.write((graph_text() + "VERTEX_SE3:QUAT ").encode())
                for _ in range(8 * MAX_LINE_CHARS // 65536):
                    out.write(b"1" * 65536)
                if not refused.wait(STREAM_PATIENCE):
                    gave_up.set()
        except BrokenPipeError:  # the reader refused and closed its end: the expected way out
            pass

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    with pytest.raises(InputError) as info:
        read_g2o(fifo)
    refused.set()
    writer.join(STREAM_PATIENCE)
    assert not gave_up.is_set(), "refused only when the stream ended"
    assert info.value.line == 6 and "characters of data: no g2o line is that long" in info.value.reason


def test_a_long_comment_or_blank_line_is_no_data(tmp_path):
    """A 3 MiB comment, and 3 MiB of spaces on one line, cost nothing and are not refused."""
    path = tmp_path / "comment.g2o"
    path.write_text("#" + "c" * (3 * MAX_LINE_CHARS) + "\n" + " " * (3 * MAX_LINE_CHARS) + "\n" + graph_text())
    graph = read_g2o(path)
    assert graph.num_vertices == 3 and graph.edge_lines.tolist() == [6, 7]


def test_a_gzip_of_blank_lines_then_a_graph_reads(tmp_path):
    path = tmp_path / "g.g2o.gz"
    with gzip.open(path, "wb") as out:
        out.write(b"\n" * (5 * BLOCK_BYTES // 2) + graph_text().encode())
    graph = read_g2o(path)
    assert graph.num_edges == 2 and graph.edge_lines.tolist() == [5 * BLOCK_BYTES // 2 + 4, 5 * BLOCK_BYTES // 2 + 5]
