"""Landmarks: point variables beside the poses, and the measurements of them, stored as arrays.

A landmark graph holds, besides its poses (:class:`posegraph.model.graph.PoseGraph`), ``L`` points
``p_l`` in the space of its group (``s = 2`` for SE(2) graphs, ``s = 3`` for SE(3)) and families of
measurements of them, each family one *kind* with arrays of one shape, so that the solver evaluates a
family in one batch:

* ``"position"``: a pose ``X_i`` (with a sensor offset ``O``, the identity unless given) sees the point
  in its own frame: residual ``e = (X_i O)⁻¹ ⊙ p − z = R_Oᵀ(R_iᵀ(p − t_i) − t_O) − z`` ``(s,)``.
  g2o: ``EDGE_SE2_XY`` (``EdgeSE2PointXY``), ``EDGE_SE3_TRACKXYZ`` through ``PARAMS_SE3OFFSET``
  (``EdgeSE3PointXYZ``); iSAM: ``LANDMARK``/``POINT3``-type lines.
* ``"bearing"`` (2D): the angle of that point, ``e = wrap(atan2(y, x) − z)`` ``(1,)`` with
  ``(x, y) = X_i⁻¹ ⊙ p``, wrapped to ``[−π, π)``. g2o: ``EDGE_BEARING_SE2_XY``.
* ``"bearing_range"`` (2D): ``e = [wrap(atan2(y, x) − z_θ), ‖(x, y)‖ − z_r]`` ``(2,)``: gtsam's
  ``BearingRangeFactor2D`` (its files' ``BR`` lines).
* ``"prior"``: a prior on the point itself, ``e = p − z`` ``(s,)`` (no pose; ``pose`` is −1). g2o:
  ``EDGE_PRIOR_XY`` (``EdgeXYPrior``).

Every residual is *predicted − measured* (g2o's and gtsam's costs are the same, whatever their sign),
and the cost of the graph is ``½ Σ eᵀΩe`` over pose edges, priors and landmark measurements alike.
Landmark steps are additive: ``p ⊕ δ = p + δ``.

Gauge: a landmark joins the poses that see it, so connected components run through landmarks
(:func:`posegraph.model.graph.connected_components` counts them); a ``FIX`` landmark is held like a
``FIX`` pose and anchors its component.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["Observations", "Landmarks", "KINDS", "measurement_size", "observed_pairs"]

KINDS = ("position", "bearing", "bearing_range", "prior")
"""The kinds of landmark measurements (module docstring)."""


def measurement_size(kind: str, space_dim: int) -> int:
    """Rows ``r`` of a measurement and residual of ``kind`` in a space of ``space_dim`` (2 or 3)."""
    sizes = {"position": space_dim, "prior": space_dim, "bearing": 1, "bearing_range": 2}
    if kind not in sizes:
        raise ValueError(f"unknown landmark measurement kind {kind!r}; kinds are {', '.join(KINDS)}")
    return sizes[kind]


@dataclass(frozen=True, eq=False)
class Observations:
    """One family of landmark measurements, all of one kind and one file tag (``q`` of them).

    ``r`` = :func:`measurement_size`; ``k`` the group's matrix size.
    """

    kind: str
    """One of :data:`KINDS`."""
    pose: np.ndarray
    """``(q,)`` int64 — index (into the graph's poses) of the observing pose; −1 for ``"prior"``."""
    landmark: np.ndarray
    """``(q,)`` int64 — index (into :attr:`Landmarks.ids`) of the observed landmark."""
    measurements: np.ndarray
    """``(q, r)`` float64 — the measured values ``z`` (a point, ``[θ]`` or ``[θ, range]``)."""
    information: np.ndarray
    """``(q, r, r)`` float64 — Ω of the residual, in the residual's order."""
    offsets: np.ndarray | None = None
    """``(q, k, k)`` — the sensor's pose ``O`` in the body frame (``"position"`` only), or None: the identity."""
    tag: str = ""
    """The file tag the family was read from (``"EDGE_SE2_XY"``, ``"BR"``, …), for writing it back."""
    lines: np.ndarray | None = field(default=None, repr=False)
    """``(q,)`` int64 — the 1-based line of each measurement in its file (for messages), or None."""
    offset_ids: np.ndarray | None = field(default=None, repr=False)
    """``(q,)`` int64 — g2o's ``PARAMS_SE3OFFSET`` id of each measurement (3D files), or None."""
    text: list | None = field(default=None, repr=False)
    """``q`` strings, the text after the tag of each line as read (a writer copies them while the
    measurements are unchanged), or None."""

    @property
    def count(self) -> int:
        return int(self.landmark.shape[0])

    @property
    def unary(self) -> bool:
        """Whether the family involves no pose (point priors)."""
        return self.kind == "prior"


@dataclass(frozen=True, eq=False)
class Landmarks:
    """The landmarks of a graph (``L`` points of dimension ``s``) and the measurements of them."""

    ids: np.ndarray
    """``(L,)`` int64 — the file's ids of the landmark vertices (disjoint from the poses' ids)."""
    positions: np.ndarray
    """``(L, s)`` float64 — the points ``p_l`` (world frame), initial values as read."""
    observations: tuple = ()
    """The measurement families (:class:`Observations`), in the order they were read."""
    fixed: np.ndarray = field(default=None)  # type: ignore[assignment]
    """``(L,)`` bool — landmarks held constant (``FIX``); all False if None is given."""
    vertex_tag: str = ""
    """The tag of the landmark vertex lines (``"VERTEX_XY"``, ``"VERTEX_TRACKXYZ"``), for writing back."""

    def __post_init__(self) -> None:
        if self.fixed is None:
            object.__setattr__(self, "fixed", np.zeros(len(self.ids), dtype=bool))

    @property
    def count(self) -> int:
        return int(self.ids.shape[0])

    @property
    def space_dim(self) -> int:
        return int(self.positions.shape[1])

    @property
    def num_measurements(self) -> int:
        return sum(family.count for family in self.observations)

    def with_positions(self, positions: np.ndarray) -> "Landmarks":
        """The same landmarks at other points ``(L, s)``."""
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != self.positions.shape:
            raise ValueError(f"landmark positions must have shape {self.positions.shape}, got {positions.shape}")
        return replace(self, positions=positions)

    def index_of(self, ids) -> np.ndarray:
        """Landmark indices of the given ids (``KeyError`` if one is absent)."""
        ids = np.asarray(ids, dtype=np.int64)
        order = np.argsort(self.ids, kind="stable")
        pos = np.clip(np.searchsorted(self.ids, ids, sorter=order), 0, max(len(order) - 1, 0))
        found = order[pos] if len(order) else np.zeros(ids.shape, dtype=np.int64)
        if not len(order) or not np.all(self.ids[found] == ids):
            missing = ids if not len(order) else ids[self.ids[found] != ids]
            raise KeyError(f"landmark ids not in graph: {missing.reshape(-1)[:5].tolist()}")
        return found


def observed_pairs(landmarks: Landmarks | None) -> tuple[np.ndarray, np.ndarray]:
    """``(pose, landmark)`` index arrays of every pose–landmark measurement (priors left out)."""
    if landmarks is None or not landmarks.observations:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    binary = [family for family in landmarks.observations if not family.unary]
    if not binary:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return (np.concatenate([f.pose for f in binary]).astype(np.int64), np.concatenate([f.landmark for f in binary]).astype(np.int64))
