"""Reading an input text file, compressed or not, as a stream of line blocks: the one way every reader reads.

Public pose-graph datasets are often shipped compressed (``sphere2500.g2o.gz``); the format is
recognised by the file's first bytes (its *magic number*), not by its name, so a renamed file
reads too and a plain file that happens to be called ``.gz`` is read as the text it is. The
standard library decompresses (:mod:`gzip`, :mod:`bz2`, :mod:`lzma`), as a stream. Anything else
that is not text — a zip or zstd archive, an image, a binary g2o file — is refused with one line
naming what was found (an :class:`~posegraph.errors.InputError`), never with the bytes themselves.

"Text" means: no NUL byte, the test ``file``, ``grep`` and git use; UTF-8 is decoded with
invalid bytes replaced (a Latin-1 comment does not stop a file) and a byte-order mark dropped.

Memory follows the data, not the file (:func:`read_blocks`): the file is read
:data:`BLOCK_BYTES` (decompressed) at a time, and the first block decides text or binary, so a
gzip bomb of zeros is refused after one block, not after expanding it. Blank lines and ``#``
comments are dropped as they stream past, so a file of them costs constant memory however long
it is; a FIFO that never ends (``yes '' > fifo``) is read, at constant memory, until it ends or
Ctrl-C, as ``wc`` or ``grep`` would. What is kept is the text of the lines with data, which the
readers turn into the graph. A line whose data (before any ``#``) is longer than
:data:`MAX_LINE_CHARS` is no line of any format read here and is refused at once: otherwise one
endless line without a newline would be held whole.
"""

from __future__ import annotations

import codecs
import os
import sys
from collections.abc import Iterable, Iterator
from typing import NamedTuple

from posegraph.errors import InputError

__all__ = ["Block", "read_blocks", "text_blocks", "COMPRESSIONS", "BLOCK_BYTES", "MAX_LINE_CHARS"]

BLOCK_BYTES = 1 << 20
"""Bytes read (after decompression) at a time: the memory a stream of blank lines costs."""

MAX_LINE_CHARS = 1 << 20
"""Longest data a line may hold (its text before any ``#``). A g2o, TUM or KITTI line is a few hundred
characters; a longer one is not one of theirs, and refusing it bounds what one line can cost."""

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

_MAGIC_BYTES = max(len(magic) for magic in (*COMPRESSIONS, *_OTHER_BINARY))


class Block(NamedTuple):
    """Consecutive lines of a file: ``lines[k]`` is line ``first + k`` (1-based), ``#`` comments cut
    off, without the ``"\\n"``. Blank lines may be among them; a block of only blank lines is not made."""

    first: int
    lines: list[str]


def read_blocks(path: str | os.PathLike, what: str = "g2o") -> Iterator[Block]:
    """The lines of the file at ``path`` (``"-"``: standard input), decompressed if gzip/bzip2/xz, as
    :class:`Block` s in file order (module docstring: memory, blank lines, comments, long lines).

    ``what`` names the expected format in messages (``"not a text g2o file"``). Raises
    :class:`~posegraph.errors.InputError` when the file cannot be opened, its compressed stream is
    corrupt or truncated, it holds a NUL byte (from the first block: binary) or a line too long.
    """
    name = os.fspath(path)
    shown = "<stdin>" if name == "-" else name
    try:
        handle = sys.stdin.buffer if name == "-" else open(name, "rb")
    except OSError as err:
        raise InputError(f"cannot read the file: {err.strerror or err}", name) from err
    try:
        yield from _blocks(handle, shown, what)
    finally:
        if handle is not sys.stdin.buffer:
            handle.close()


def text_blocks(text: str) -> list[Block]:
    """``text`` already in memory as :class:`Block` s, for the parsers that also take a string."""
    lines = text.split("\n")
    if "#" in text:
        lines = [line.partition("#")[0] for line in lines]
    return [Block(1, lines)]


def _blocks(handle, name: str, what: str) -> Iterator[Block]:
    """:func:`read_blocks` of an open binary ``handle``; ``name`` for messages."""
    try:
        head = handle.read(_MAGIC_BYTES)
    except OSError as err:
        raise InputError(f"cannot read the file: {err.strerror or err}", name) from err
    compression = next((kind for magic, kind in COMPRESSIONS.items() if head.startswith(magic)), None)
    stream = _Prefixed(head, handle)
    if compression is not None:
        stream = _decompressing(stream, compression)
    chunks = _chunks(stream, compression, name)
    first = next(chunks, b"")
    if b"\0" in first:
        raise InputError(_binary_reason(first, compression, what), name)
    yield from _lines(_text_chunks(first, chunks, name, what), name, what)


def _chunks(stream, compression: str | None, name: str) -> Iterator[bytes]:
    """``stream`` read :data:`BLOCK_BYTES` at a time; a corrupt or truncated compressed stream refused."""
    import lzma

    while True:
        try:
            chunk = stream.read(BLOCK_BYTES)
        except (OSError, EOFError, ValueError, lzma.LZMAError) as err:  # corrupt or truncated stream
            if compression is None:
                raise InputError(f"cannot read the file: {err.strerror or err}", name) from err
            raise InputError(f"cannot decompress the {compression} file: {err}", name) from err
        if not chunk:
            return
        yield chunk


def _text_chunks(first: bytes, chunks: Iterator[bytes], name: str, what: str) -> Iterator[str]:
    """The decoded text of ``first`` and the ``chunks`` after it; a NUL byte further on refused with its line."""
    decoder = codecs.getincrementaldecoder("utf-8-sig")(errors="replace")  # drops a byte-order mark
    newlines = 0
    chunk = first
    while chunk:
        zero = chunk.find(b"\0")
        if zero >= 0:
            line = newlines + chunk.count(b"\n", 0, zero) + 1
            raise InputError(f"not a text {what} file (a NUL byte, binary data, on this line)", name, line)
        newlines += chunk.count(b"\n")
        yield decoder.decode(chunk)
        chunk = next(chunks, b"")
    yield decoder.decode(b"", final=True)


def _lines(texts: Iterable[str], name: str, what: str) -> Iterator[Block]:
    """Blocks of the lines of the text pieces ``texts``, a line cut across pieces joined.

    The unfinished last line of a piece is carried over with its comment and blank start dropped,
    so that a line of endless blanks or comment costs nothing while it is read.
    """
    number, carried = 1, ""
    for text in texts:
        text = carried + text
        if not text.strip():  # blank lines only (the usual piece of a file of them): counted, not split
            number, carried = number + text.count("\n"), ""
            continue
        lines = text.split("\n")
        carried = _unfinished(lines.pop(), number + len(lines), name, what)
        if lines:
            block = _block(number, lines, "#" in text, name, what)
            if block is not None:
                yield block
            number += len(lines)
    if carried:
        block = _block(number, [carried], "#" in carried, name, what)
        if block is not None:
            yield block


def _unfinished(line: str, number: int, name: str, what: str) -> str:
    """The part of a line still being read that matters: its data before any ``#`` (``#`` kept, to
    mark the rest as comment), nothing if it is blank so far; refused once too long."""
    data, hash_sign, _ = line.partition("#")
    if not data.strip():
        data = ""
    if len(data) > MAX_LINE_CHARS:
        _too_long(number, name, what)
    return data + hash_sign


def _block(number: int, lines: list[str], comments: bool, name: str, what: str) -> Block | None:
    """``Block(number, lines)`` with comments cut off (``comments``: some line has a ``#``); None when
    every line is blank. Long lines refused."""
    if not any(line.strip() for line in lines):  # stops at the first line with data: at once in a data file
        return None
    if comments:
        lines = [line.partition("#")[0] for line in lines]
    if max(map(len, lines)) > MAX_LINE_CHARS:
        _too_long(number + max(range(len(lines)), key=lambda k: len(lines[k])), name, what)
    return Block(number, lines)


def _too_long(number: int, name: str, what: str):
    raise InputError(f"the line holds over {MAX_LINE_CHARS:,} characters of data: no {what} line is that long "
                     "(is this the right file?)", name, number)


class _Prefixed:
    """A binary stream whose first bytes, read already to tell the format, are given back first."""

    def __init__(self, head: bytes, rest) -> None:
        self.head, self.rest = head, rest

    def read(self, size: int = -1) -> bytes:
        if not self.head:
            return self.rest.read(size)
        if size is None or size < 0:
            data, self.head = self.head + self.rest.read(), b""
            return data
        data, self.head = self.head[:size], self.head[size:]
        return data if len(data) == size else data + self.rest.read(size - len(data))


def _decompressing(stream, compression: str):
    """A file object reading ``stream`` decompressed, piece by piece (multi-member files as one)."""
    import bz2
    import gzip
    import lzma

    opener = {"gzip": gzip.GzipFile, "bzip2": bz2.BZ2File, "xz": lzma.LZMAFile}[compression]
    return opener(fileobj=stream) if compression == "gzip" else opener(stream)


def _binary_reason(data: bytes, compression: str | None, what: str) -> str:
    """One line saying the file is binary, and what it looks like when its magic number says."""
    found = next((kind for magic, kind in _OTHER_BINARY.items() if data.startswith(magic)), None)
    if compression is not None:
        inside = f" (the {compression} file holds binary data{', ' + found if found else ''})"
    else:
        inside = f" (it is {found})" if found else " (it holds binary data)"
    return f"not a text {what} file{inside}"
