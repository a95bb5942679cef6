"""The g2o records posegraph reads and writes: tags, field layouts and the information permutation.

One entry of :data:`RECORDS` per vertex or edge tag says how its lines are parsed (one numpy
structured record per line), what its fields are called in messages, and how its rotation and
information are stored; the reader (:mod:`posegraph.io.g2o_read`) and the writer
(:mod:`posegraph.io.g2o_write`) take the layouts from here. The format itself is described in
``docs/g2o.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

VERTEX_TAG = "VERTEX_SE3:QUAT"
EDGE_TAG = "EDGE_SE3:QUAT"
FIX_TAG = "FIX"
VERTEX3_TAG = "VERTEX3"
"""gtsam's older 3D vertex: ``VERTEX3 id x y z roll pitch yaw``."""
EDGE3_TAG = "EDGE3"
"""gtsam's older 3D edge: ``EDGE3 i j x y z roll pitch yaw`` and 21 information entries in ``[ω; v]`` order."""
# 2D tags of g2o and of the older TORO/gtsam formats: refused, not skipped,
# because skipping them would silently leave an empty or partial graph.
TWO_D_TAGS = frozenset({"VERTEX_SE2", "EDGE_SE2", "VERTEX2", "EDGE2"})

G2O_TO_TANGENT = np.array([3, 4, 5, 0, 1, 2])
"""Index permutation from g2o's ``[t; R]`` order to ``[ω; v]`` (its own inverse)."""

UPPER_ROWS, UPPER_COLS = np.triu_indices(6)
"""Row and column of each of the 21 upper-triangular information entries, in the file's order (row by row)."""


def _entry_of_upper() -> np.ndarray:
    """``(6, 6)``: which of the 21 upper-triangular entries (row by row) each element of the symmetric matrix is."""
    entry = np.empty((6, 6), dtype=np.int64)
    entry[UPPER_ROWS, UPPER_COLS] = np.arange(21)
    entry[UPPER_COLS, UPPER_ROWS] = np.arange(21)
    return entry


# (36,) indices into the 21 entries giving the 6×6 matrix row-major: permuted from g2o's [t; R]
# to [ω; v] (EDGE_SE3:QUAT), or as is (EDGE3, whose entries gtsam reads in its own [ω; v] order).
TANGENT_FROM_UPPER = _entry_of_upper()[G2O_TO_TANGENT][:, G2O_TO_TANGENT].reshape(-1)
SYMMETRIC_FROM_UPPER = _entry_of_upper().reshape(-1)

_INFORMATION_FIELDS = tuple(f"information({r + 1},{c + 1})" for r, c in zip(UPPER_ROWS, UPPER_COLS))


class Record(NamedTuple):
    """How the lines of one vertex or edge tag are read."""

    kind: str
    """``"vertex"`` or ``"edge"``."""
    dtype: np.dtype
    """One structured record per line: ``id`` (vertex) or ``ids (2,)`` (edge), ``t (3,)``, the
    rotation field, and for edges ``info (21,)``."""
    fields: tuple[str, ...]
    """The names of the fields after the tag, for messages."""
    n_ints: int
    """How many leading fields are integer ids (1 for a vertex, 2 for an edge)."""
    rotation: str
    """``"quaternion"`` (field ``q``: ``qx qy qz qw``) or ``"euler"`` (field ``rpy``: roll pitch yaw, radians)."""
    information_from_upper: np.ndarray | None = None
    """Edges: ``(36,)`` indices into the 21 entries giving the ``[ω; v]`` matrix, row-major."""


RECORDS = {
    VERTEX_TAG: Record(
        "vertex", np.dtype([("id", np.int64), ("t", np.float64, (3,)), ("q", np.float64, (4,))]),
        ("id", "x", "y", "z", "qx", "qy", "qz", "qw"), 1, "quaternion",
    ),
    VERTEX3_TAG: Record(
        "vertex", np.dtype([("id", np.int64), ("t", np.float64, (3,)), ("rpy", np.float64, (3,))]),
        ("id", "x", "y", "z", "roll", "pitch", "yaw"), 1, "euler",
    ),
    EDGE_TAG: Record(
        "edge",
        np.dtype([("ids", np.int64, (2,)), ("t", np.float64, (3,)), ("q", np.float64, (4,)),
                  ("info", np.float64, (21,))]),
        ("id_from", "id_to", "x", "y", "z", "qx", "qy", "qz", "qw") + _INFORMATION_FIELDS, 2, "quaternion",
        TANGENT_FROM_UPPER,
    ),
    EDGE3_TAG: Record(
        "edge",
        np.dtype([("ids", np.int64, (2,)), ("t", np.float64, (3,)), ("rpy", np.float64, (3,)),
                  ("info", np.float64, (21,))]),
        ("id_from", "id_to", "x", "y", "z", "roll", "pitch", "yaw") + _INFORMATION_FIELDS, 2, "euler",
        SYMMETRIC_FROM_UPPER,
    ),
}
"""The vertex and edge tags read, in the order their checks run (vertices before edges)."""

READ_TAGS = frozenset(RECORDS) | {FIX_TAG}
"""Every tag the reader reads; lines with other tags are skipped with a warning (2D tags refused)."""
