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

from posegraph.lie import se2, so3

VERTEX_TAG = "VERTEX_SE3:QUAT"
EDGE_TAG = "EDGE_SE3:QUAT"
FIX_TAG = "FIX"
VERTEX3_TAG = "VERTEX3"
"""gtsam's older 3D vertex: ``VERTEX3 id x y z roll pitch yaw``."""
EDGE3_TAG = "EDGE3"
"""gtsam's older 3D edge: ``EDGE3 i j x y z roll pitch yaw`` and 21 information entries in ``[ω; v]`` order."""
VERTEX_SE2_TAG = "VERTEX_SE2"
"""g2o's 2D vertex: ``VERTEX_SE2 id x y θ``."""
EDGE_SE2_TAG = "EDGE_SE2"
"""g2o's 2D edge: ``EDGE_SE2 i j dx dy dθ`` and 6 information entries in ``[x, y, θ]`` order."""
VERTEX2_TAG = "VERTEX2"
"""TORO's 2D vertex, as ``VERTEX_SE2``."""
ODOMETRY_TAG = "ODOMETRY"
"""iSAM's 2D edge, as ``EDGE_SE2`` but for its 6 entries: the square-root information, unless told
otherwise (:mod:`posegraph.io.g2o_isam`)."""
EDGE2_TAG = "EDGE2"
"""TORO's 2D edge, as ``EDGE_SE2`` but for the order of its 6 information entries, which is told
per file (:mod:`posegraph.io.g2o_toro`; ``RECORDS`` reads them in g2o's order, after conversion)."""

G2O_TO_TANGENT = np.array([3, 4, 5, 0, 1, 2])
"""Index permutation from g2o's ``[t; R]`` order to ``[ω; v]`` (its own inverse)."""

UPPER_ROWS, UPPER_COLS = np.triu_indices(6)
"""Row and column of each of the 21 upper-triangular information entries, in the file's order (row by row)."""
UPPER_ROWS_2D, UPPER_COLS_2D = np.triu_indices(3)
"""The same for the 6 entries of a 2D edge's 3×3 information."""


def _entry_of_upper(size: int) -> np.ndarray:
    """``(size, size)``: which upper-triangular entry (row by row) each element of the symmetric matrix is."""
    rows, cols = np.triu_indices(size)
    entry = np.empty((size, size), dtype=np.int64)
    entry[rows, cols] = np.arange(rows.size)
    entry[cols, rows] = np.arange(rows.size)
    return entry


# (36,) indices into the 21 entries giving the 6×6 matrix row-major: permuted from g2o's [t; R]
# to [ω; v] (EDGE_SE3:QUAT), or as is (EDGE3, whose entries gtsam reads in its own [ω; v] order).
TANGENT_FROM_UPPER = _entry_of_upper(6)[G2O_TO_TANGENT][:, G2O_TO_TANGENT].reshape(-1)
SYMMETRIC_FROM_UPPER = _entry_of_upper(6).reshape(-1)
# (9,) the same for EDGE_SE2: g2o's [x, y, θ] is already the se(2) tangent order, nothing to permute.
SYMMETRIC_FROM_UPPER_2D = _entry_of_upper(3).reshape(-1)


def _information_fields(size: int) -> tuple[str, ...]:
    return tuple(f"information({r + 1},{c + 1})" for r, c in zip(*np.triu_indices(size)))


_INFORMATION_FIELDS = _information_fields(6)


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
    """``"quaternion"`` (field ``q``: ``qx qy qz qw``), ``"euler"`` (field ``rpy``: roll pitch yaw,
    radians) or ``"angle"`` (field ``theta``: the planar angle, radians)."""
    information_from_upper: np.ndarray | None = None
    """Edges: ``(d², )`` indices into the upper-triangular entries giving the tangent-order matrix, row-major."""
    space_dim: int = 3
    """3 for the 3D tags (SE(3)), 2 for the planar ones (SE(2)); a file holds tags of one only."""


_VERTEX_2D = Record(
    "vertex", np.dtype([("id", np.int64), ("t", np.float64, (2,)), ("theta", np.float64)]),
    ("id", "x", "y", "theta"), 1, "angle", space_dim=2,
)
_EDGE_2D = Record(
    "edge",
    np.dtype([("ids", np.int64, (2,)), ("t", np.float64, (2,)), ("theta", np.float64), ("info", np.float64, (6,))]),
    ("id_from", "id_to", "dx", "dy", "dtheta") + _information_fields(3), 2, "angle", SYMMETRIC_FROM_UPPER_2D,
    space_dim=2,
)

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
    VERTEX_SE2_TAG: _VERTEX_2D,
    EDGE_SE2_TAG: _EDGE_2D,
    VERTEX2_TAG: _VERTEX_2D,  # TORO's, the same layout
    EDGE2_TAG: _EDGE_2D,  # its information converted to g2o's order first (posegraph.io.g2o_toro)
    ODOMETRY_TAG: _EDGE_2D,  # iSAM's: its entries turned into g2o's information first (posegraph.io.g2o_isam)
}
"""The vertex and edge tags read, in the order their checks run (vertices before edges)."""

PRIMARY_EDGE_TAG = {3: EDGE_TAG, 2: EDGE_SE2_TAG}
"""The edge tag the writer writes per space dimension (and whose lines it copies when unchanged)."""
PRIMARY_VERTEX_TAG = {3: VERTEX_TAG, 2: VERTEX_SE2_TAG}
"""The vertex tag the writer writes per space dimension."""


def records_of(space_dim: int) -> dict[str, Record]:
    """The entries of :data:`RECORDS` for 3D (``space_dim=3``) or 2D (``2``) files, in order."""
    return {tag: record for tag, record in RECORDS.items() if record.space_dim == space_dim}


READ_TAGS = frozenset(RECORDS) | {FIX_TAG}
"""Every tag the reader reads; lines with other tags are skipped with a warning."""


def pose_values(poses: np.ndarray, planar: bool) -> np.ndarray:
    """``(k, 3)`` ``x y θ`` of SE(2) matrices, or ``(k, 7)`` ``x y z qx qy qz qw`` of SE(3) ones: the pose
    fields of a vertex, an edge or a prior line."""
    if planar:
        return se2.to_xytheta(poses)
    return np.concatenate([poses[:, :3, 3], so3.to_quaternion(poses[:, :3, :3])], axis=1)
