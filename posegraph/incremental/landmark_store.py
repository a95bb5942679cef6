"""The landmarks of an incremental graph: points, their measurements by family, and checks of new ones.

Points and measurements are kept in growable rows (:class:`~posegraph.incremental.store.Rows`), one
family per ``(kind, tag)`` as :class:`posegraph.model.landmarks.Observations` holds them, so that the
graph so far is a :class:`~posegraph.model.landmarks.Landmarks` without copying row by row. Each
landmark remembers the first pose that observed it (gauge: a landmark joins the poses that see it) and
whether something other than the poses ties it down (``FIX`` or a point prior).
"""

from __future__ import annotations

import numpy as np

from posegraph.errors import GraphError
from posegraph.incremental.store import Rows, check_information, check_poses, indices_in
from posegraph.model.landmarks import KINDS, Landmarks, Observations, measurement_size

__all__ = ["LandmarkStore", "LandmarkFamily", "check_landmark_measurements"]


class LandmarkFamily:
    """The rows of one ``(kind, tag)`` family: pose and landmark indices, ``z`` ``(q, r)``, Ω ``(q, r, r)``,
    sensor offsets ``(q, k, k)`` (``"position"`` only)."""

    def __init__(self, kind: str, tag: str, group):
        r, k = measurement_size(kind, group.space_dim), group.matrix_size
        self.kind, self.tag = kind, tag
        self.pose, self.landmark = Rows((), np.int64), Rows((), np.int64)
        self.measurements, self.information = Rows((r,)), Rows((r, r))
        self.offsets = Rows((k, k)) if kind == "position" else None
        self.keys = Rows((), np.int64)
        """Per measurement: its key (what :meth:`IncrementalOptimizer.add_landmark_measurements` returned)."""

    @property
    def count(self) -> int:
        return self.landmark.n

    def extend(self, pose, landmark, measurements, information, offsets, keys) -> None:
        self.keys.extend(keys)
        self.pose.extend(pose)
        self.landmark.extend(landmark)
        self.measurements.extend(measurements)
        self.information.extend(information)
        if self.offsets is not None:
            self.offsets.extend(offsets)

    def keep(self, mask: np.ndarray) -> None:
        """Only the measurements where ``mask`` ``(q,)`` is True, in order."""
        for rows in (self.keys, self.pose, self.landmark, self.measurements, self.information, self.offsets):
            if rows is not None:
                rows.keep(mask)

    def observations(self) -> Observations:
        """The family as the model holds it (copies)."""
        offsets = None if self.offsets is None else self.offsets.view.copy()
        return Observations(self.kind, self.pose.view.copy(), self.landmark.view.copy(), self.measurements.view.copy(),
                            self.information.view.copy(), offsets, self.tag)


class LandmarkStore:
    """Points ``(L, s)``, ``FIX`` flags, ids, and the measurement families of an incremental graph."""

    def __init__(self, group):
        self.group = group
        self.ids = Rows((), np.int64)
        self.positions = Rows((group.space_dim,))
        self.fixed = Rows((), bool)
        self.first_pose = Rows((), np.int64)
        """Per landmark: the index of the first pose that observed it, −1 while none has."""
        self.tied = Rows((), bool)
        """Per landmark: ``FIX`` or under a point prior (it anchors the component of the poses seeing it)."""
        self.index: dict[int, int] = {}
        self.families: dict[tuple[str, str], LandmarkFamily] = {}
        self.next_key = 0
        self.vertex_tag = "VERTEX_XY" if group.space_dim == 2 else "VERTEX_TRACKXYZ"

    @property
    def count(self) -> int:
        return self.ids.n

    def add(self, ids: np.ndarray, positions: np.ndarray, fixed: np.ndarray) -> np.ndarray:
        """Append landmarks (checked by the caller); their indices."""
        start = self.ids.n
        for rows, values in ((self.ids, ids), (self.positions, positions), (self.fixed, fixed), (self.tied, fixed),
                             (self.first_pose, np.full(ids.shape[0], -1))):
            rows.extend(values)
        for offset, landmark in enumerate(ids.tolist()):
            self.index[landmark] = start + offset
        return np.arange(start, self.ids.n)

    def family(self, kind: str, tag: str) -> LandmarkFamily:
        key = (kind, tag)
        if key not in self.families:
            self.families[key] = LandmarkFamily(kind, tag, self.group)
        return self.families[key]

    def indices_of(self, ids: np.ndarray, what: str) -> np.ndarray:
        """Indices of landmark ids (``GraphError`` naming the first unknown one)."""
        return indices_in(self.index, ids, what, "landmark")

    def landmarks(self) -> Landmarks | None:
        """The landmarks so far as the model holds them (copies); None when there are none."""
        if self.count == 0:
            return None
        observations = tuple(f.observations() for f in self.families.values() if f.count)
        return Landmarks(self.ids.view.copy(), self.positions.view.copy(), observations, self.fixed.view.copy(),
                         self.vertex_tag)

    def remove(self, keys: np.ndarray) -> np.ndarray:
        """Drop the measurements of ``keys`` (checked by :meth:`find`); the poses that made them. Each
        landmark's first observer and tie (``FIX``, a point prior) are then recomputed from what is left."""
        poses = []
        for family in self.families.values():
            gone = np.isin(family.keys.view, keys)
            poses.append(family.pose.view[gone & (family.pose.view >= 0)])
            family.keep(~gone)
        self.first_pose.view[:] = -1
        self.tied.view[:] = self.fixed.view
        first = self.first_pose.view
        for family in self.families.values():
            if family.kind == "prior":
                self.tied.view[family.landmark.view] = True
                continue
            seen, row = np.unique(family.landmark.view, return_index=True)  # any observer joins; the first kept
            unset = first[seen] < 0
            first[seen[unset]] = family.pose.view[row[unset]]
        return np.concatenate(poses) if poses else np.zeros(0, np.int64)

    def find(self, keys: np.ndarray) -> None:
        """``GraphError`` naming the first of ``keys`` no measurement has, or one given twice."""
        known = np.concatenate([f.keys.view for f in self.families.values()]) if self.families else np.zeros(0, np.int64)
        missing = np.flatnonzero(~np.isin(keys, known))
        if missing.size:
            raise GraphError(f"landmark measurement to remove #{int(missing[0])}: no measurement with key {int(keys[missing[0]])}")
        if np.unique(keys).shape[0] != keys.shape[0]:
            raise GraphError("landmark measurements to remove: a key is given twice")

    def observed_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(pose, landmark)`` of every pose–landmark measurement so far (priors left out)."""
        binary = [f for f in self.families.values() if f.kind != "prior" and f.count]
        if not binary:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return np.concatenate([f.pose.view for f in binary]), np.concatenate([f.landmark.view for f in binary])


def check_landmark_measurements(group, kind: str, count: int, measurements, information, offsets):
    """``(z (q, r), Ω (q, r, r), offsets (q, k, k) or None)`` checked: ``GraphError`` naming the first bad item."""
    if kind not in KINDS:
        raise GraphError(f"landmark measurements: unknown kind {kind!r}; kinds are {', '.join(KINDS)}")
    if group.space_dim not in (2, 3) or group.name == "SIM3":
        raise GraphError(f"landmark measurements: {group.name} graphs have no landmarks (SE(2) and SE(3) have)")
    if kind in ("bearing", "bearing_range") and group.space_dim != 2:
        raise GraphError(f"landmark measurements: {kind} measurements are 2D (SE(2) graphs)")
    r, k = measurement_size(kind, group.space_dim), group.matrix_size
    z = np.asarray(measurements, dtype=np.float64).reshape((-1, r))
    w = np.asarray(information, dtype=np.float64).reshape((-1, r, r))
    if z.shape[0] != count or w.shape[0] != count:
        raise GraphError(f"landmark measurements: {count} landmark ids, {z.shape[0]} measurements, "
                         f"{w.shape[0]} information matrices")
    bad = np.flatnonzero(~np.isfinite(z).all(axis=1))
    if bad.size:
        raise GraphError(f"landmark measurement #{int(bad[0])}: not finite")
    check_information(w, "landmark measurement", r)
    if offsets is None:
        return z, w, (np.broadcast_to(np.eye(k), (count, k, k)).copy() if kind == "position" else None)
    if kind != "position":
        raise GraphError(f"landmark measurements: sensor offsets belong to position measurements, not {kind}")
    offsets = np.asarray(offsets, dtype=np.float64).reshape((-1, k, k))
    if offsets.shape[0] != count:
        raise GraphError(f"landmark measurements: {count} landmark ids, {offsets.shape[0]} sensor offsets")
    check_poses(offsets, group, "sensor offset")
    return z, w, offsets.copy()
