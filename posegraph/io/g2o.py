"""Read and write 3D and 2D pose graphs in g2o's text format: the public names, from the modules that own them.

``VERTEX_SE3:QUAT`` / ``EDGE_SE3:QUAT`` / ``FIX`` lines, gtsam's older ``VERTEX3`` / ``EDGE3``, and
2D ``VERTEX_SE2`` / ``EDGE_SE2``;
the format, the checks (``file:line: reason`` errors), the repairs and the writer's guarantees are
described in ``docs/g2o.md``, the one reference. The work is split by job:

* :mod:`posegraph.io.g2o_format` — tags, field layouts (:data:`~posegraph.io.g2o_format.RECORDS`,
  one entry per tag) and the information permutation;
* :mod:`posegraph.io.g2o_lines` — tokenising: lines grouped by tag and parsed, bad lines diagnosed;
* :mod:`posegraph.io.g2o_checks` — checks on what was read: values, quaternions, information
  matrices (and their repair), topology;
* :mod:`posegraph.io.g2o_read` — :func:`read_g2o`: the stages in order, the graph built;
* :mod:`posegraph.io.g2o_write` — :func:`write_g2o` and :func:`format_g2o`.
"""

from __future__ import annotations

from posegraph.io.g2o_checks import (
    PSD_TOLERANCE, QUATERNION_NORM_TOLERANCE, REPAIR_EIGENVALUE_FLOOR, SINGULAR_TOLERANCE, ZERO_QUATERNION_NORM,
)
from posegraph.io.g2o_format import (
    EDGE3_TAG, EDGE_SE2_TAG, EDGE_TAG, FIX_TAG, G2O_TO_TANGENT, VERTEX3_TAG, VERTEX_SE2_TAG, VERTEX_TAG,
)
from posegraph.io.g2o_read import read_g2o, rotations_from_roll_pitch_yaw
from posegraph.io.g2o_write import format_g2o, write_g2o

__all__ = [
    "read_g2o",
    "write_g2o",
    "format_g2o",
    "VERTEX_TAG",
    "EDGE_TAG",
    "VERTEX3_TAG",
    "EDGE3_TAG",
    "VERTEX_SE2_TAG",
    "EDGE_SE2_TAG",
    "FIX_TAG",
    "G2O_TO_TANGENT",
    "QUATERNION_NORM_TOLERANCE",
    "ZERO_QUATERNION_NORM",
    "PSD_TOLERANCE",
    "SINGULAR_TOLERANCE",
    "REPAIR_EIGENVALUE_FLOOR",
    "rotations_from_roll_pitch_yaw",
]
