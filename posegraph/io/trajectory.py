"""Trajectory files in the TUM and KITTI formats: read, write, recognise, match by timestamp.

These are the formats evo (``evo_ape tum …``, ``evo_traj kitti …``) and most SLAM benchmarks read.

* **TUM** (Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012): one
  pose per line, ``timestamp tx ty tz qx qy qz qw``, whitespace-separated; the pose is
  world-from-body (as our vertices), the quaternion Hamilton ``(x, y, z, w)``. Lines starting
  with ``#`` and blank lines are skipped. Written: a ``#`` header line, then one line per vertex
  in id order, the timestamp being the vertex id unless a table gives one
  (:func:`read_timestamp_table`), ``qw ≥ 0``, every float in its shortest exact form (``repr``).
  Read: the quaternion is normalised (a zero one is an error), the rows sorted by timestamp.
* **KITTI** (Geiger et al., odometry benchmark): one pose per line, the 12 entries of the 3×4
  matrix ``[R | t]`` row by row; no timestamps and no ids, line ``k`` is frame ``k``. Written in
  id order. Read: a rotation block farther than :data:`KITTI_ROTATION_TOLERANCE` from a rotation
  is an error, a nearer one is projected onto SO(3) (files carry 6–9 digits).

2D graphs (SE(2) poses ``(n, 3, 3)``) are written embedded at ``z = 0`` by
:func:`posegraph.lie.se2.to_se3` (rotation about z, ``tz = 0``): both formats are 3D.

Every error on a user's file is an :class:`~posegraph.errors.InputError` naming the file, the
line and the reason. Files may be gzip/bzip2/xz-compressed (:mod:`posegraph.io.text_input`).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable

import numpy as np

from posegraph.io.atomic import write_text_atomic
from posegraph.errors import InputError, InputWarning, excerpt
from posegraph.io.text_input import Block, read_blocks, text_blocks
from posegraph.lie import so3
from posegraph.lie.group import embed_in_se3

__all__ = [
    "TUM_HEADER",
    "KITTI_ROTATION_TOLERANCE",
    "QUATERNION_WARN_TOLERANCE",
    "EVO_MAX_TIME_DIFF",
    "format_tum",
    "format_kitti",
    "write_tum",
    "write_kitti",
    "parse_tum",
    "parse_kitti",
    "read_tum",
    "read_kitti",
    "sniff_format",
    "file_format",
    "read_timestamp_table",
    "matching_keys",
]

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw\n"

KITTI_ROTATION_TOLERANCE = 1e-4
"""Largest ``|RᵀR − I|`` entry accepted in a KITTI line (KITTI's own files are written with
``%e``, 7 significant digits, about 1e-6 off); beyond it the line is not a pose."""

QUATERNION_WARN_TOLERANCE = 1e-3
"""A TUM quaternion whose norm is farther than this from 1 is normalised with a warning (a norm
off by less comes from the few digits TUM files are written with, and is normalised silently)."""

EVO_MAX_TIME_DIFF = 0.01
"""Default largest timestamp difference (seconds) of two matched poses, evo's ``--t_max_diff``."""

_TUM_FIELDS = 8
_KITTI_FIELDS = 12


# ---------------------------------------------------------------------------------------------
# writing


def _stamp_texts(stamps: np.ndarray) -> list[str]:
    """Integer-valued stamps (vertex ids) as integers, others in their shortest exact form."""
    stamps = np.asarray(stamps)
    if stamps.dtype.kind in "iu":
        return [str(s) for s in stamps.tolist()]
    return [str(int(s)) if float(s).is_integer() and abs(s) < 2**53 else repr(s) for s in stamps.tolist()]


def format_tum(stamps: np.ndarray, poses: np.ndarray) -> str:
    """TUM text: :data:`TUM_HEADER`, then ``stamp tx ty tz qx qy qz qw`` per pose ``(n, 4, 4)``, in the given order."""
    X = np.asarray(poses, dtype=np.float64)
    values = np.concatenate([X[:, :3, 3], so3.to_quaternion(X[:, :3, :3])], axis=1)
    lines = [stamp + "".join(" " + repr(v) for v in row) for stamp, row in zip(_stamp_texts(stamps), values.tolist())]
    return TUM_HEADER + "".join(line + "\n" for line in lines)


def format_kitti(poses: np.ndarray) -> str:
    """KITTI text: the 12 entries of each pose's ``[R | t]`` ``(n, 4, 4)`` row by row, one line per pose."""
    rows = np.asarray(poses, dtype=np.float64)[:, :3, :].reshape(-1, _KITTI_FIELDS)
    return "".join(" ".join(map(repr, row)) + "\n" for row in rows.tolist())


def write_tum(path, stamps: np.ndarray, poses: np.ndarray) -> None:
    """Write :func:`format_tum` to ``path`` atomically (poses ``(n, 4, 4)`` or ``(n, 3, 3)``)."""
    write_text_atomic(path, format_tum(stamps, embed_in_se3(np.asarray(poses, dtype=np.float64))))


def write_kitti(path, poses: np.ndarray) -> None:
    """Write :func:`format_kitti` to ``path`` atomically (poses ``(n, 4, 4)`` or ``(n, 3, 3)``)."""
    write_text_atomic(path, format_kitti(embed_in_se3(np.asarray(poses, dtype=np.float64))))


# ---------------------------------------------------------------------------------------------
# reading


def _iter_data_lines(source: str | Iterable[Block]):
    """``(1-based line number, tokens)`` of each line that is neither blank nor a ``#`` comment, of text in
    memory or of a file's blocks (:func:`posegraph.io.text_input.read_blocks`, read as they are needed)."""
    for first, lines in text_blocks(source) if isinstance(source, str) else source:
        for number, line in enumerate(lines, start=first):
            tokens = line.split()
            if tokens:
                yield number, tokens


def _data_lines(source: str | Iterable[Block]) -> tuple[list[list[str]], np.ndarray]:
    """Token lists of the data lines (:func:`_iter_data_lines`) and their line numbers ``(k,)``."""
    pairs = list(_iter_data_lines(source))
    return [tokens for _, tokens in pairs], np.array([number for number, _ in pairs], dtype=np.int64)


def _numeric_rows(source, path: str, widths: tuple[int, ...], layout: str) -> tuple[np.ndarray, np.ndarray]:
    """``(values (k, w), line numbers (k,))`` of a file of ``w`` finite numbers per line, ``w`` in ``widths``
    (the first line decides); the first bad line raised as ``path:line: reason``. ``layout`` names the
    fields in messages."""
    rows, numbers = _data_lines(source)
    if not rows:
        raise InputError(f"the file has no data lines (expected {layout})", path)
    width = len(rows[0])
    if width not in widths:
        width = widths[0]
    for row, number in zip(rows, numbers):
        if len(row) != width:
            raise InputError(f"{len(row)} fields, expected {width}: {layout}", path, int(number))
    try:
        values = np.array(rows, dtype=np.float64)
    except ValueError:
        values = None
    bad = _first_non_finite(rows, values)
    if bad is not None:
        k, token = bad
        raise InputError(f"field {excerpt(token)} is not a finite number ({layout})", path, int(numbers[k]))
    return values, numbers


def _first_non_finite(rows: list[list[str]], values: np.ndarray | None) -> tuple[int, str] | None:
    """``(row index, token)`` of the first token that is not a finite number, or None."""
    if values is not None:
        finite = np.isfinite(values)
        if finite.all():
            return None
        k, field = np.argwhere(~finite)[0]
        return int(k), rows[k][field]
    for k, row in enumerate(rows):
        for token in row:
            try:
                float(token)
            except ValueError:
                return k, token
    raise AssertionError("numpy refused a row that float() accepts")  # pragma: no cover


def parse_tum(text: str | Iterable[Block], path: str) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps ``(n,)`` (increasing) and poses ``(n, 4, 4)`` of TUM text (module docstring).

    Raises :class:`InputError` for a malformed line, a zero quaternion or a repeated timestamp.
    """
    layout = "timestamp tx ty tz qx qy qz qw"
    values, numbers = _numeric_rows(text, path, (_TUM_FIELDS,), layout)
    q = values[:, 4:8]
    norm = np.linalg.norm(q, axis=1)
    zero = np.flatnonzero(norm < 1e-12)
    if zero.size:
        raise InputError("the quaternion (qx qy qz qw) is zero: not a rotation", path, int(numbers[zero[0]]))
    far = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_WARN_TOLERANCE)
    if far.size:
        warnings.warn(f"{path}:{numbers[far[0]]}: {far.size} quaternion(s) of norm far from 1 (first "
                      f"{norm[far[0]]:.6g}) normalised", InputWarning, stacklevel=2)
    order = np.argsort(values[:, 0], kind="stable")
    stamps = values[order, 0]
    repeated = np.flatnonzero(np.diff(stamps) == 0)
    if repeated.size:
        first, second = sorted(numbers[order[repeated[0]: repeated[0] + 2]])
        raise InputError(f"timestamp {float(stamps[repeated[0]])!r} repeats the one on line {first}", path, int(second))
    poses = np.tile(np.eye(4), (len(values), 1, 1))
    poses[:, :3, :3] = so3.from_quaternion(q[order] / norm[order, None])
    poses[:, :3, 3] = values[order, 1:4]
    return stamps, poses


def parse_kitti(text: str | Iterable[Block], path: str) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices ``0..n−1`` ``(n,)`` and poses ``(n, 4, 4)`` of KITTI text (module docstring)."""
    layout = "the 12 entries of a 3x4 pose matrix [R | t], row by row"
    values, numbers = _numeric_rows(text, path, (_KITTI_FIELDS,), layout)
    matrices = values.reshape(-1, 3, 4)
    R = matrices[:, :, :3]
    off = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((off > KITTI_ROTATION_TOLERANCE) | (np.linalg.det(R) <= 0))
    if bad.size:
        k = bad[0]
        raise InputError(f"the 3x3 block is not a rotation (|RᵀR − I| up to {off[k]:.3g}, det {np.linalg.det(R[k]):.6g})",
                         path, int(numbers[k]))
    poses = np.tile(np.eye(4), (len(values), 1, 1))
    poses[:, :3, :3] = so3.project(R)
    poses[:, :3, 3] = matrices[:, :, 3]
    return np.arange(len(values), dtype=np.int64), poses


def read_tum(path) -> tuple[np.ndarray, np.ndarray]:
    """:func:`parse_tum` of the file at ``path`` (plain or compressed)."""
    name = os.fspath(path)
    return parse_tum(read_blocks(name, "TUM"), name)


def read_kitti(path) -> tuple[np.ndarray, np.ndarray]:
    """:func:`parse_kitti` of the file at ``path`` (plain or compressed)."""
    name = os.fspath(path)
    return parse_kitti(read_blocks(name, "KITTI"), name)


def sniff_format(text: str | Iterable[Block], path: str) -> str:
    """``"g2o"``, ``"tum"`` or ``"kitti"``, from the first data line of ``text``.

    A line starting with a word is g2o (a tag); a line of 8 numbers is TUM, of 12 numbers KITTI.
    Any other line of numbers is an :class:`InputError` naming the line.
    """
    number, first = next(_iter_data_lines(text), (None, None))
    if first is None:
        return "g2o"  # the g2o reader gives its own message for an empty file
    try:
        float(first[0])
    except ValueError:
        return "g2o"
    formats = {_TUM_FIELDS: "tum", _KITTI_FIELDS: "kitti"}
    if len(first) in formats:
        return formats[len(first)]
    raise InputError(f"{len(first)} numbers on the first line: neither a TUM trajectory (8: timestamp tx ty tz "
                     "qx qy qz qw) nor a KITTI one (12: a 3x4 pose matrix), nor g2o (a tag first)",
                     path, number)


def file_format(path) -> str:
    """:func:`sniff_format` of the file at ``path`` (plain or compressed)."""
    name = os.fspath(path)
    return sniff_format(read_blocks(name, "trajectory"), name)


def read_timestamp_table(path, ids: np.ndarray) -> np.ndarray:
    """Timestamps ``(n,)`` for the vertex ids ``(n,)``, from a table file.

    Two layouts, recognised by the first line: one column, the timestamps of the vertices in id
    order (KITTI's ``times.txt``; exactly ``n`` lines); or two columns ``id timestamp`` (every id
    of the graph present once, other ids ignored). Timestamps must be distinct.
    """
    name = os.fspath(path)
    values, numbers = _numeric_rows(read_blocks(name, "timestamp table"), name, (1, 2),
                                    "one timestamp per vertex in id order, or: id timestamp")
    ids = np.asarray(ids, dtype=np.int64)
    if values.shape[1] == 1:
        if len(values) != len(ids):
            raise InputError(f"{len(values)} timestamps for {len(ids)} vertices (one column: one line per vertex, "
                             "in id order)", name)
        stamps = values[np.argsort(np.argsort(ids, kind="stable"), kind="stable"), 0]
        rows = numbers
    else:
        stamps, rows = _stamps_by_id(values, numbers, ids, name)
    order = np.argsort(stamps, kind="stable")
    repeated = np.flatnonzero(np.diff(stamps[order]) == 0)
    if repeated.size:
        a, b = order[repeated[0]: repeated[0] + 2]
        raise InputError(f"vertices {ids[a]} and {ids[b]} get the same timestamp {float(stamps[a])!r}", name,
                         int(max(rows[a], rows[b])) if values.shape[1] == 2 else None)
    return stamps


def _stamps_by_id(values, numbers, ids, name) -> tuple[np.ndarray, np.ndarray]:
    """Two-column table: timestamps of ``ids`` and the line each came from."""
    table_ids = values[:, 0]
    integer = np.flatnonzero(table_ids != np.round(table_ids))
    if integer.size:
        raise InputError(f"vertex id {float(table_ids[integer[0]])!r} is not an integer", name, int(numbers[integer[0]]))
    table_ids = table_ids.astype(np.int64)
    order = np.argsort(table_ids, kind="stable")
    repeated = np.flatnonzero(np.diff(table_ids[order]) == 0)
    if repeated.size:
        raise InputError(f"vertex id {table_ids[order[repeated[0]]]} is listed twice", name,
                         int(numbers[order[repeated[0] + 1]]))
    where = np.searchsorted(table_ids[order], ids)
    where = np.minimum(where, len(order) - 1)
    missing = np.flatnonzero(table_ids[order][where] != ids)
    if missing.size:
        raise InputError(f"no timestamp for vertex {ids[missing[0]]} ({missing.size} vertices missing)", name)
    return values[order[where], 1], numbers[order[where]]


# ---------------------------------------------------------------------------------------------
# matching


def matching_keys(
    stamps_a: np.ndarray, stamps_b: np.ndarray, max_diff: float = EVO_MAX_TIME_DIFF
) -> tuple[np.ndarray, np.ndarray]:
    """Integer keys ``(n_a,)``, ``(n_b,)`` equal exactly for the poses matched by time, as evo does.

    Integer stamps on both sides (vertex ids, KITTI frames) with ``max_diff < 0.5`` match exactly,
    and the keys are the stamps. Otherwise each stamp of the shorter list is matched to the
    nearest stamp of the other (ties to the earlier) when they differ by at most ``max_diff``
    (evo's ``matching_time_indices``); a stamp claimed twice goes to the nearer one. Keys of the
    longer list are its ranks in time order, so sorting by key walks matched poses in time
    order; an unmatched stamp of the shorter list gets a key no other has.
    """
    a = np.asarray(stamps_a, dtype=np.float64)
    b = np.asarray(stamps_b, dtype=np.float64)
    if max_diff < 0.5 and all(np.all(s == np.round(s)) and np.all(np.abs(s) < 2**53) for s in (a, b)):
        return a.astype(np.int64), b.astype(np.int64)
    if len(a) > len(b):
        keys_b, keys_a = matching_keys(b, a, max_diff)
        return keys_a, keys_b
    order = np.argsort(b, kind="stable")
    sorted_b = b[order]
    above = np.clip(np.searchsorted(sorted_b, a, side="right"), 0, len(b) - 1)
    below = np.maximum(above - 1, 0)
    diff_above = np.abs(sorted_b[above] - a)
    diff_below = np.abs(a - sorted_b[below])
    nearest = np.where(diff_below <= diff_above, below, above)
    diff = np.minimum(diff_below, diff_above)
    matched = diff <= max_diff
    # One partner per stamp of b: the nearest a wins (stable sort keeps the earlier of a tie).
    by_diff = np.argsort(np.where(matched, diff, np.inf), kind="stable")
    _, first = np.unique(nearest[by_diff], return_index=True)
    keep = np.zeros(len(a), dtype=bool)
    keep[by_diff[first]] = True
    matched &= keep
    keys_a = np.where(matched, nearest, len(b) + np.arange(len(a)))
    return keys_a.astype(np.int64), np.argsort(order, kind="stable").astype(np.int64)
