"""Unary edges of a pose graph: pose priors and position priors, stored as small arrays.

A prior is an edge with one vertex. Two kinds, each its own set of arrays so that the binary edges
(:class:`posegraph.model.graph.PoseGraph`) and their solver path stay as they are:

* a **pose prior** on vertex ``k`` measures ``Z ≈ X_k · O`` (``O`` an offset, the identity unless
  g2o's ``PARAMS_SE3OFFSET`` says otherwise); residual ``e = Log(Z⁻¹ X_k O)`` in the group's
  tangent order, information Ω ``(d, d)`` in that order — gtsam's ``PriorFactorPose3`` /
  ``PriorFactorPose2`` when ``O = I``. g2o: ``EDGE_SE3_PRIOR``, ``EDGE_PRIOR_SE2``.
* a **position prior** measures ``z ≈ t(X_k)`` ``(r,)``; residual ``e = t(X_k) − z``, information
  ``(r, r)`` — gtsam's ``GPSFactor`` (3D) and ``PoseTranslationPrior2D`` (2D). g2o:
  ``EDGE_SE3_XYZ_PRIOR`` (whose offset parameter g2o reads but does not use in the error; neither
  do we), ``EDGE_PRIOR_SE2_XY``.

The cost of the graph is ``½ Σ eᵀΩe`` over binary and unary edges alike.

Gauge: priors tie a connected component to the world. A component *anchored by priors* — one with a
pose prior, or with position priors whose measured points span at least a line (3D: not all
collinear; 2D: not all equal), which leaves no rigid motion free — holds no vertex
(:func:`posegraph.model.graph.held_vertices`). A component no prior reaches keeps its anchor. A component
whose position priors leave a rotation free (one point in 3D or 2D, collinear points in 3D) holds
no vertex either: its remaining gauge (rotation about the points) is left to the damping of
Levenberg-Marquardt, so that the optimum is the cost's own.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["Priors", "anchored_components", "prior_vertices", "prior_poses"]


@dataclass(frozen=True, eq=False)
class Priors:
    """Pose priors (``a`` of them) and position priors (``b``) on the vertices of a graph (by index).

    ``k``, ``d``, ``r``: the group's matrix size, tangent dimension and space dimension.
    """

    pose_vertex: np.ndarray
    """``(a,)`` int64 — vertex index of each pose prior."""
    pose_measurements: np.ndarray
    """``(a, k, k)`` — the measured poses ``Z``."""
    pose_offsets: np.ndarray
    """``(a, k, k)`` — the offsets ``O`` (residual ``Log(Z⁻¹ X O)``); identities in 2D."""
    pose_information: np.ndarray
    """``(a, d, d)`` — Ω in the tangent order (``[ω; v]`` for SE(3))."""
    position_vertex: np.ndarray
    """``(b,)`` int64 — vertex index of each position prior."""
    position_measurements: np.ndarray
    """``(b, r)`` — the measured positions ``z``."""
    position_information: np.ndarray
    """``(b, r, r)`` — Ω of ``t(X) − z``."""
    pose_offset_ids: np.ndarray | None = None
    """``(a,)`` int64 — g2o's parameter id of each pose prior's offset (3D files), else None."""
    position_offset_ids: np.ndarray | None = None
    """``(b,)`` int64 — g2o's parameter id on each ``EDGE_SE3_XYZ_PRIOR`` line (3D files), else None."""
    offsets: dict = field(default_factory=dict)
    """g2o's ``PARAMS_SE3OFFSET`` parameters by id: ``{id: (4, 4) matrix}``."""
    pose_lines: np.ndarray | None = None
    """``(a,)`` 1-based line of each pose prior in its file (for messages), or None."""
    position_lines: np.ndarray | None = None
    """``(b,)`` the same for the position priors."""
    text: tuple | None = field(default=None, repr=False)
    """``(lines, checksum)``: the ``PARAMS_SE3OFFSET`` and prior lines as read (each ``"TAG rest"``,
    file order) and :meth:`checksum` at reading, for a writer to copy while they still hold."""

    @property
    def num_pose(self) -> int:
        return int(self.pose_vertex.shape[0])

    @property
    def num_position(self) -> int:
        return int(self.position_vertex.shape[0])

    def __len__(self) -> int:
        return self.num_pose + self.num_position

    def checksum(self, ids: np.ndarray) -> int:
        """CRC-32 of every array that defines the priors, with the ids of the vertices they name."""
        crc = 0
        arrays = (
            ids[self.pose_vertex], ids[self.position_vertex], self.pose_measurements, self.pose_offsets,
            self.pose_information, self.position_measurements, self.position_information,
        )  # fmt: skip
        for array in arrays:
            crc = zlib.crc32(np.ascontiguousarray(array, dtype=np.float64).data, crc)
        return crc

    def copied_text(self, ids: np.ndarray) -> list | None:
        """The lines as read, while the priors and the ids they name are unchanged; else None."""
        if self.text is None or self.text[1] != self.checksum(ids):
            return None
        return self.text[0]

    def remapped(self, vertex_map: np.ndarray) -> "Priors":
        """The priors on other vertex indices: ``vertex_map[k]`` is the new index of vertex ``k``."""
        return replace(
            self, pose_vertex=vertex_map[self.pose_vertex], position_vertex=vertex_map[self.position_vertex],
            text=None,
        )  # fmt: skip

    @classmethod
    def empty(cls, group) -> "Priors":
        """No priors, shaped for ``group``."""
        k, d, r = group.matrix_size, group.dim, group.space_dim
        return cls(
            np.zeros(0, np.int64), np.zeros((0, k, k)), np.zeros((0, k, k)), np.zeros((0, d, d)),
            np.zeros(0, np.int64), np.zeros((0, r)), np.zeros((0, r, r)),
        )  # fmt: skip


def prior_poses(graph) -> tuple[np.ndarray, np.ndarray]:
    """``(vertex (a + b,), poses (a + b, k, k))``: the vertex of each prior and the pose the prior gives it.

    A pose prior measuring ``Z ≈ X O`` gives ``X = Z O⁻¹``; a position prior gives its point ``z``
    as the translation, with the rotation of the vertex's current pose (it says nothing about it).
    Pose priors first; empty without priors.
    """
    priors, group = graph.priors, graph.group
    if priors is None:
        k = group.matrix_size
        return np.zeros(0, np.int64), np.zeros((0, k, k))
    r = group.space_dim
    positions = np.array(graph.poses[priors.position_vertex], copy=True)
    positions[:, :r, r] = priors.position_measurements
    poses = np.concatenate([priors.pose_measurements @ group.inverse(priors.pose_offsets), positions])
    return np.concatenate([priors.pose_vertex, priors.position_vertex]), poses


def prior_vertices(priors: Priors | None, n: int) -> np.ndarray:
    """``(n,)`` bool: the vertices at least one prior names."""
    reached = np.zeros(n, dtype=bool)
    if priors is not None:
        reached[priors.pose_vertex] = True
        reached[priors.position_vertex] = True
    return reached


def anchored_components(priors: Priors | None, labels: np.ndarray, count: int) -> np.ndarray:
    """``(count,)`` bool: the components (``labels`` ``(n,)`` in ``[0, count)``) that a prior reaches.

    Every such component holds no anchor (module docstring). Those whose priors leave a rotation
    free are :func:`underdetermined_components`.
    """
    reached = np.zeros(count, dtype=bool)
    if priors is not None:
        reached[labels[prior_vertices(priors, labels.shape[0])]] = True
    return reached


def underdetermined_components(priors: Priors | None, labels: np.ndarray, count: int) -> np.ndarray:
    """``(count,)`` bool: components reached only by position priors whose points leave a rotation free.

    The measured points ``z`` of a component fix its rotation when, centred, they have rank at least
    ``r − 1`` (3D: not collinear; 2D: not all the same point); a pose prior fixes it always.
    """
    out = np.zeros(count, dtype=bool)
    if priors is None or priors.num_position == 0:
        return out
    with_pose = np.zeros(count, dtype=bool)
    with_pose[labels[priors.pose_vertex]] = True
    component = labels[priors.position_vertex]
    r = priors.position_measurements.shape[1]
    for c in np.unique(component[~with_pose[component]]).tolist():  # one pass per such component, few
        points = priors.position_measurements[component == c]
        centred = points - points.mean(axis=0)
        scale = max(float(np.abs(points).max()), 1.0)
        rank = int(np.sum(np.linalg.svd(centred, compute_uv=False) > 1e-9 * scale)) if len(points) > 1 else 0
        out[c] = rank < r - 1
    return out
