"""Tokenising g2o text: lines grouped by tag, each tag's lines parsed at once, the first bad line diagnosed.

The syntax of each line (field count, numbers, integer ids) is checked here; what the values
mean is checked by :mod:`posegraph.io.g2o_checks`.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from posegraph.errors import G2oFormatError, excerpt
from posegraph.io.g2o_format import FIX_TAG, Record
from posegraph.io.text_input import Block

_INTEGER = re.compile(r"[+-]?[0-9]+")


class Lines(NamedTuple):
    """The lines of one tag: 1-based line numbers and the text after the tag."""

    numbers: np.ndarray
    rests: list[str]


def group_lines(blocks: Iterable[Block]) -> tuple[dict[str, Lines], dict[str, int]]:
    """Group the lines of ``blocks`` (:func:`posegraph.io.text_input.read_blocks`, comments cut off) by
    tag, blank lines dropped: ``({tag: Lines}, {tag: first line number})``. Only the lines with data are
    kept, so the memory is the graph's, not the file's."""
    numbers: dict[str, list[int]] = {}
    rests: dict[str, list[str]] = {}
    for first, lines in blocks:
        # Lines end at "\n" only: str.splitlines would also break on \x0b, \x1c… and shift line numbers.
        # A trailing "\r" (CRLF) is whitespace to str.split and to numpy's parser alike.
        for number, line in enumerate(lines, start=first):
            # Fast path for "TAG fields…"; str.split handles leading blanks, tabs and a bare tag.
            tag, _, rest = line.partition(" ")
            if not tag or not tag.isprintable():
                parts = line.split(None, 1)
                if not parts:
                    continue
                tag = parts[0]
                rest = parts[1] if len(parts) > 1 else ""
            try:
                numbers[tag].append(number)
                rests[tag].append(rest)
            except KeyError:
                numbers[tag] = [number]
                rests[tag] = [rest]
    groups = {tag: Lines(np.array(numbers[tag], dtype=np.int64), rests[tag]) for tag in numbers}
    first_line = {tag: numbers[tag][0] for tag in numbers}
    return groups, first_line


def parse_records(lines: Lines, tag: str, record: Record, path: str) -> tuple[np.ndarray, G2oFormatError | None]:
    """Parse all lines of one tag into ``record.dtype`` records with one call to numpy's C parser.

    Only when that fails is the first offending line searched for, by bisection
    (about two more parses of the group), and its fields examined one by one.
    """
    dtype = record.dtype
    if not lines.rests:
        return np.zeros(0, dtype=dtype), None
    records, reason = _load(lines.rests, dtype)
    if records is not None:
        return records, None
    lo, hi = 0, len(lines.rests)  # lines [0, lo) parse; the first bad line is in [lo, hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _load(lines.rests[lo:mid], dtype)[0] is not None:
            lo = mid
        else:
            hi = mid
    number = int(lines.numbers[lo])
    error = _diagnose_line(lines.rests[lo], number, tag, record.fields, record.n_ints, path)
    if error is None:  # the token checks disagree with numpy: report what numpy said
        error = G2oFormatError(f"{tag} line could not be parsed: {reason}", path, number)
    return np.zeros(0, dtype=dtype), error


def _load(rests: list[str], dtype: np.dtype) -> tuple[np.ndarray | None, str]:
    """``(records, "")`` if every line parses into one record, else ``(None, reason)``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data" when every line is empty
            records = np.loadtxt(rests, dtype=dtype, comments=None, ndmin=1)
    except ValueError as err:
        return None, str(err)
    if records.shape != (len(rests),):  # numpy skips blank lines: a tag without fields
        return None, "a line has no fields"
    return records, ""


def _diagnose_line(
    rest: str, number: int, tag: str, fields: tuple[str, ...], n_ints: int, path: str
) -> G2oFormatError | None:
    """The problem with one line's fields (count, then each field's syntax)."""
    tokens = rest.split()
    if len(tokens) != len(fields):
        return G2oFormatError(
            f"{tag} needs {len(fields)} fields after the tag ({_describe_fields(fields)}), found {len(tokens)}",
            path,
            number,
        )
    for k, token in enumerate(tokens):
        if k < n_ints:
            if not _is_integer(token):
                reason = f"{tag} field {k + 1} ({fields[k]}) is {excerpt(token)}, not an integer id"
                return G2oFormatError(reason, path, number)
        elif not _is_number(token):
            return G2oFormatError(f"{tag} field {k + 1} ({fields[k]}) is {excerpt(token)}, not a number", path, number)
    return None


def _describe_fields(fields: tuple[str, ...]) -> str:
    entries = sum(name.startswith("information(") for name in fields)
    if entries > 6:  # a 3D edge's 21 information entries come last
        return " ".join(fields[: len(fields) - entries]) + f" and the {entries} upper-triangular information entries"
    return " ".join(fields)


def _is_integer(token: str) -> bool:
    """Decimal digits with an optional sign, within int64 (Python's int() would also take "1_0")."""
    return bool(_INTEGER.fullmatch(token)) and -(2**63) <= int(token) < 2**63


def _is_number(token: str) -> bool:
    # The same parser as the fast path, so that the scan finds what it rejected
    # (Python's float() would accept "1_0", which numpy's parser does not).
    try:
        np.loadtxt([token], dtype=np.float64, comments=None, ndmin=1)
    except ValueError:
        return False
    return True


def parse_fix(lines: Lines, path: str) -> tuple[np.ndarray, np.ndarray, G2oFormatError | None]:
    """Ids of ``FIX`` lines and the line each came from (there are few such lines)."""
    ids: list[int] = []
    numbers: list[int] = []
    for number, rest in zip(lines.numbers.tolist(), lines.rests):
        tokens = rest.split()
        if not tokens:
            error = G2oFormatError(f"{FIX_TAG} needs at least one vertex id", path, number)
            return np.zeros(0, np.int64), np.zeros(0, np.int64), error
        for k, token in enumerate(tokens):
            if not _is_integer(token):
                error = G2oFormatError(f"{FIX_TAG} field {k + 1} is {excerpt(token)}, not an integer id", path, number)
                return np.zeros(0, np.int64), np.zeros(0, np.int64), error
            ids.append(int(token))
            numbers.append(number)
    return np.array(ids, dtype=np.int64), np.array(numbers, dtype=np.int64), None
