"""Reading an input text file, compressed or not: gzip, bzip2 and xz are undone transparently.

Public pose-graph datasets are often shipped compressed (``sphere2500.g2o.gz``); the format is
recognised by the file's first bytes (its *magic number*), not by its name, so a renamed file
reads too and a plain file that happens to be called ``.gz`` is read as the text it is. The
standard library decompresses (:mod:`gzip`, :mod:`bz2`, :mod:`lzma`). Anything else that is not
text — a zip or zstd archive, an image, a binary g2o file — is refused with one line naming what
was found (an :class:`~posegraph.errors.InputError`), never with the bytes themselves.

"Text" means: no NUL byte, the test ``file``, ``grep`` and git use; UTF-8 is decoded with
invalid bytes replaced (a Latin-1 comment does not stop a file) and a byte-order mark dropped.
"""

from __future__ import annotations

import os

from posegraph.errors import InputError

__all__ = ["read_text", "COMPRESSIONS"]

COMPRESSIONS = {
    b"\x1f\x8b": "gzip",
    b"BZh": "bzip2",
    b"\xfd7zXZ\x00": "xz",
}
"""Magic number → compression read transparently."""

_OTHER_BINARY = {
    b"PK\x03\x04": "a zip archive",
    b"\x28\xb5\x2f\xfd": "zstd-compressed data",
    b"7z\xbc\xaf\x27\x1c": "a 7-zip archive",
    b"\x89PNG": "a PNG image",
    b"%PDF": "a PDF document",
}
"""Magic numbers of binary files worth naming in the refusal."""


def read_text(path: str | os.PathLike, what: str = "g2o") -> str:
    """The text of the file at ``path``, decompressed if gzip/bzip2/xz (see the module docstring).

    ``what`` names the expected format in messages (``"not a text g2o file"``). Raises
    :class:`~posegraph.errors.InputError` when the file cannot be opened, its compressed stream is
    corrupt or truncated, or its content is not text.
    """
    name = os.fspath(path)
    try:
        with open(name, "rb") as handle:
            data = handle.read()
    except OSError as err:
        raise InputError(f"cannot read the file: {err.strerror or err}", name) from err
    compression = next((kind for magic, kind in COMPRESSIONS.items() if data.startswith(magic)), None)
    if compression is not None:
        data = _decompress(data, compression, name)
    if b"\0" in data:
        raise InputError(_binary_reason(data, compression, what), name)
    # utf-8-sig drops a byte-order mark, which would otherwise glue itself to the first token.
    return data.decode("utf-8-sig", errors="replace")


def _decompress(data: bytes, compression: str, name: str) -> bytes:
    import bz2
    import gzip
    import lzma

    decompress = {"gzip": gzip.decompress, "bzip2": bz2.decompress, "xz": lzma.decompress}[compression]
    try:
        return decompress(data)
    except (OSError, EOFError, ValueError, lzma.LZMAError) as err:  # corrupt or truncated stream
        raise InputError(f"cannot decompress the {compression} file: {err}", name) from err


def _binary_reason(data: bytes, compression: str | None, what: str) -> str:
    """One line saying the file is binary, and what it looks like when its magic number says."""
    found = next((kind for magic, kind in _OTHER_BINARY.items() if data.startswith(magic)), None)
    if compression is not None:
        inside = f" (the {compression} file holds binary data{', ' + found if found else ''})"
    else:
        inside = f" (it is {found})" if found else " (it holds binary data)"
    return f"not a text {what} file{inside}"
