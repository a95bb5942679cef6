"""Compressed inputs read as the plain file; binary inputs refused in one printable line."""

from __future__ import annotations

import bz2
import gzip
import lzma
import zipfile

import numpy as np
import pytest

from posegraph.errors import InputError
from posegraph.io.g2o import read_g2o
from posegraph.io.text_input import read_blocks

COMPRESS = {".gz": gzip.compress, ".bz2": bz2.compress, ".xz": lzma.compress}


def data_lines(path, what: str = "g2o") -> list[str]:
    """The lines with data that :func:`read_blocks` gives for ``path``, in order."""
    return [line for block in read_blocks(path, what) for line in block.lines if line.strip()]


def assert_same_graph(a, b):
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.edge_from, b.edge_from)
    np.testing.assert_array_equal(a.edge_to, b.edge_to)
    np.testing.assert_array_equal(a.measurements, b.measurements)
    np.testing.assert_array_equal(a.information, b.information)
    np.testing.assert_array_equal(a.fixed, b.fixed)


@pytest.mark.parametrize("suffix", sorted(COMPRESS))
def test_compressed_g2o_reads_as_the_plain_file(tmp_path, shared_dataset, suffix):
    plain = shared_dataset("smallGrid3D")
    packed = tmp_path / f"smallGrid3D.g2o{suffix}"
    packed.write_bytes(COMPRESS[suffix](plain.read_bytes()))
    assert packed.read_bytes()[:2] != plain.read_bytes()[:2]
    assert_same_graph(read_g2o(packed), read_g2o(plain))


def test_format_is_recognised_by_content_not_name(tmp_path):
    text = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
    misnamed_plain = tmp_path / "plain.g2o.gz"
    misnamed_plain.write_text(text)
    renamed_xz = tmp_path / "packed.g2o"
    renamed_xz.write_bytes(lzma.compress(text.encode()))
    assert data_lines(misnamed_plain) == data_lines(renamed_xz) == text.splitlines()


def test_byte_order_mark_is_dropped_inside_a_compressed_file(tmp_path):
    path = tmp_path / "bom.g2o.gz"
    path.write_bytes(gzip.compress(b"\xef\xbb\xbfVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"))
    assert data_lines(path)[0].startswith("VERTEX_SE3:QUAT")


def _zip_bytes(tmp_path) -> bytes:
    archive = tmp_path / "a.zip"
    with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("graph.g2o", "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n" * 50)
    return archive.read_bytes()


BINARY_CASES = {
    "raw binary": (lambda tmp: bytes(range(256)) * 4, "not a text g2o file (it holds binary data)"),
    "gzip of binary": (lambda tmp: gzip.compress(bytes(range(256))), "not a text g2o file (the gzip file holds binary data)"),
    "zip archive": (_zip_bytes, "not a text g2o file (it is a zip archive)"),
    "truncated gzip": (lambda tmp: gzip.compress(b"VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n" * 100)[:30],
                       "cannot decompress the gzip file"),
    "truncated xz": (lambda tmp: lzma.compress(b"VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n" * 100)[:40],
                     "cannot decompress the xz file"),
}


@pytest.mark.parametrize("case", sorted(BINARY_CASES))
def test_binary_input_is_refused_in_one_printable_line(tmp_path, case):
    make, reason = BINARY_CASES[case]
    path = tmp_path / "input.g2o.gz"
    path.write_bytes(make(tmp_path))
    with pytest.raises(InputError) as info:
        read_g2o(path)
    message = str(info.value)
    assert info.value.path == str(path) and info.value.line is None
    assert message.startswith(f"{path}: {reason}"), message
    assert message.isprintable() and "\n" not in message


def test_the_expected_format_is_named(tmp_path):
    path = tmp_path / "t.txt"
    path.write_bytes(b"\x00\x01")
    with pytest.raises(InputError, match="not a text TUM file"):
        data_lines(path, "TUM")


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="cannot read the file"):
        data_lines(tmp_path / "absent.g2o")
