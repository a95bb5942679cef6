"""Landmarks in the held analysis of :mod:`posegraph.incremental.whole`.

The analysis gives the points variables of their own block size ``s`` (2 or 3), numbered after every
pose variable of its capacity, for a capacity of points too (×GROWTH the landmark count, at least
FUTURE_POINTS more): the points not yet added, and those no measurement reaches yet, are decoupled as
the poses to come are (unit diagonal, zero gradient). Besides the pose–point blocks of every
measurement so far it holds the blocks the next sightings are likely to need, so that most of them
cost only their scatter positions: the poses of the next AHEAD vertices joined to every landmark seen
by the last RECENT poses and to the points to come. A capacity exceeded or a ``FIX`` flag changed makes a
new analysis.

**Left-out measurements.** A measurement whose pose–point block is missing (a landmark seen again after a
gap longer than RECENT poses) is left out of the factorised matrix: its Hessian positions are ``nnz``
(dropped), its gradient rows kept, and its whole ``(d+s)×(d+s)`` Hessian, linearised at the current point,
is one of the held factor's low-rank terms at every step (:meth:`HeldPoints.terms`), through every
refactorisation until the next analysis puts its block in the pattern. Up to MAX_LEFT_OUT are left out
before a new analysis is made; one whose point has no measurement in H yet makes one at once (H without it
would be singular there).

Scatter positions come from the pattern's own placement (:attr:`HessianPattern.placement
<posegraph.solve.sparsity.HessianPattern.placement>`: ``pair_positions`` for a pose–point measurement,
``diagonal_positions`` for a point prior), kept per family in the store's order, and the families'
blocks (:func:`posegraph.solve.landmark_terms.linearize_landmarks`, raveled ``[H_pp, H_ll, H_pl]``)
are added with one ``np.bincount`` each.
"""

from __future__ import annotations

import numpy as np

from posegraph.incremental.store import Rows
from posegraph.solve.sparsity import PointFamily, PointVariables

__all__ = ["HeldPoints", "AHEAD", "RECENT", "FUTURE_POINTS", "MAX_LEFT_OUT"]

AHEAD = 64
"""Poses to come whose blocks with the recently seen landmarks (and the points to come) an analysis adds."""

RECENT = 32
"""A landmark seen by one of the last this many poses counts as recently seen."""

FUTURE_POINTS = 16
"""Point capacity beyond the landmark count (at least); the first of them get predicted blocks."""

MAX_LEFT_OUT = 16
"""Measurements whose pose–point block is outside the held pattern left out of H as low-rank terms before
a new analysis is made (module docstring)."""


def _diagonal(at, variables: np.ndarray, z: int) -> np.ndarray:
    """``(q, z²)`` data positions of the diagonal blocks of ``variables`` (size ``z``; −1: held, ``nnz``),
    the upper halves ``nnz``: ``_System.diagonal_slots`` for these few variables alone (its
    ``diagonal_positions`` tabulates every variable of the pattern, O(p) a call)."""
    a, b = np.repeat(np.arange(z), z), np.tile(np.arange(z), z)
    slots = at.diagonal_slots(np.maximum(variables, 0), z)
    return np.where((variables >= 0)[:, None] & (a >= b), slots, at.nnz)


def _crossed(at, both: np.ndarray, slot: np.ndarray, d: int, s: int) -> np.ndarray:
    """``(q, d·s)`` data positions of ``H_pose,point`` (row-major), ``nnz`` where a variable is held: the
    block sits at (point, pose), points being numbered after the poses, entry ``(a, b)`` at ``(b, a)``
    (``slot`` ``(w,)``: the stored blocks of the measurements where ``both`` ``(q,)``)."""
    out = np.full((both.shape[0], d * s), at.nnz, dtype=np.int64)
    out[both] = at.off_slots(slot, s, d).reshape(-1, s, d).swapaxes(1, 2).reshape(-1, d * s)
    return out


class HeldPoints:
    """The landmark side of the held analysis: ``store`` the optimiser's
    :class:`~posegraph.incremental.landmark_store.LandmarkStore`, ``d`` the poses' block size."""

    def __init__(self, store, d: int):
        self.store, self.d, self.s = store, d, store.group.space_dim
        self.capacity = 0
        self.fixed = np.zeros(0, dtype=bool)  # FIX flags the analysis was made with, (capacity,)
        self.placed: dict = {}  # (kind, tag) -> (hessian positions Rows, gradient rows Rows)
        self.held_counts: dict = {}  # (kind, tag) -> measurements in the held factor (factored)
        self.held_decoupled = np.zeros(0, dtype=np.int64)  # rows of the points the held factor decoupled
        self.left_out: dict = {}  # (kind, tag) -> (k,) measurements (family order) left out of H
        self.in_matrix = np.zeros(0, dtype=bool)  # (capacity,) points with a measurement placed in H
        self.left_out_taken = 0  # measurements left out so far, over every analysis (a statistic)

    max_left_out = MAX_LEFT_OUT
    """Measurements left out of H (low-rank terms) before an analysis (0: every missing block re-analyses)."""

    def reset(self) -> None:
        self.placed, self.left_out = {}, {}

    def left_out_count(self) -> int:
        return sum(rows.shape[0] for rows in self.left_out.values())

    def covered(self) -> bool:
        """Whether the analysis's points still fit: count within capacity, ``FIX`` flags as analysed."""
        count = self.store.count
        return count <= self.capacity and np.array_equal(self.store.fixed.view, self.fixed[:count])

    def variables(self, n: int, pose_capacity: int) -> PointVariables | None:
        """The points for a new analysis at ``n`` poses of capacity ``pose_capacity`` (module docstring);
        None without landmarks."""
        count = self.store.count
        self.placed, self.left_out = {}, {}
        if count == 0:
            self.capacity, self.fixed = 0, np.zeros(0, dtype=bool)
            return None
        self.capacity = max(int(1.1 * count) + 1, count + FUTURE_POINTS)
        self.in_matrix = np.zeros(self.capacity, dtype=bool)
        self.fixed = np.zeros(self.capacity, dtype=bool)
        self.fixed[:count] = self.store.fixed.view
        pose, point = self.store.observed_pairs()
        ahead_pose, ahead_point = self._predicted(pose, point, n, pose_capacity)
        family = PointFamily(np.concatenate([pose, ahead_pose]), np.concatenate([point, ahead_point]))
        return PointVariables(self.capacity, self.s, self.fixed, (family,))

    def _predicted(self, pose: np.ndarray, point: np.ndarray, n: int, pose_capacity: int):
        """``(pose, point)`` pairs predicted: poses ``n .. n+AHEAD−1`` with the landmarks seen by the last
        RECENT poses and with the first FUTURE_POINTS points to come."""
        recent = np.unique(point[pose >= n - RECENT])
        count = self.store.count
        points = np.concatenate([recent, np.arange(count, min(count + FUTURE_POINTS, self.capacity))])
        poses = np.arange(n, min(n + AHEAD, pose_capacity))
        return np.repeat(poses, points.shape[0]), np.tile(points, poses.shape[0])

    def place(self, pattern, keys: np.ndarray) -> bool:
        """Scatter positions of the measurements not yet placed; those whose pose–point block is not in
        ``pattern`` (``keys``: sorted ``col·p + row`` of its off-diagonal blocks) left out of H (module
        docstring). False when they would pass ``max_left_out``, or one's point has nothing in H: a new
        analysis is due."""
        d, s, at = self.d, self.s, pattern.placement
        for key, family in self.store.families.items():
            if key not in self.placed:
                width = s * s if family.kind == "prior" else d * d + s * s + d * s
                self.placed[key] = (Rows((width,), np.int64), Rows((s if family.kind == "prior" else d + s,), np.int64))
            hessian, gradient = self.placed[key]
            start = hessian.n
            if start == family.count:
                continue
            landmark = family.landmark.view[start:]
            point = pattern.point_variable_of[landmark]
            if family.kind == "prior":
                self.in_matrix[landmark] = True
                hessian.extend(_diagonal(at, point, s))
                gradient.extend(at.rows(point, s))
                continue
            pose = pattern.variable_of[family.pose.view[start:]]
            both = (pose >= 0) & (point >= 0)
            slot, found = _find(keys, pose[both] * pattern.num_variables + point[both])
            missing = np.flatnonzero(both)[~found]
            self.in_matrix[np.delete(landmark, missing)] = True
            if missing.shape[0] and not self._leave_out(key, start + missing, landmark[missing]):
                return False
            positions = np.concatenate([_diagonal(at, pose, d), _diagonal(at, point, s),
                                        _crossed(at, both, slot, d, s)], axis=1)
            positions[missing] = at.nnz  # left out of H entirely: a low-rank term adds it back
            hessian.extend(positions)
            gradient.extend(np.concatenate([at.rows(pose, d), at.rows(point, s)], axis=1))
        return True

    def _leave_out(self, key, rows: np.ndarray, landmarks: np.ndarray) -> bool:
        """Record measurements ``rows`` ``(k,)`` of family ``key`` (of points ``landmarks``) as left out of H;
        False (nothing recorded) past ``max_left_out`` or when one's point has no measurement in H."""
        if self.left_out_count() + rows.shape[0] > self.max_left_out or not np.all(self.in_matrix[landmarks]):
            return False
        self.left_out[key] = np.concatenate([self.left_out.get(key, np.zeros(0, dtype=np.int64)), rows])
        self.left_out_taken += rows.shape[0]
        return True

    def _positions(self):
        """Per family with measurements (the order of ``Landmarks.observations``): the Hessian positions in
        the order of :class:`~posegraph.solve.landmark_terms.LandmarkBlocks` and the gradient rows."""
        d, s = self.d, self.s
        for key, family in self.store.families.items():
            if not family.count:
                continue
            hessian, gradient = (rows.view for rows in self.placed[key])
            if family.kind != "prior":
                hessian = np.concatenate([hessian[:, : d * d].ravel(), hessian[:, d * d : d * d + s * s].ravel(),
                                          hessian[:, d * d + s * s :].ravel()])
            yield hessian.ravel(), gradient.ravel()

    def add(self, pattern, g: np.ndarray, data: np.ndarray | None, blocks) -> None:
        """Add the families' ``blocks`` (:class:`~posegraph.solve.landmark_terms.LandmarkBlocks`) into ``g``
        ``(D,)`` and, unless None, the lower-CSC ``data`` ``(nnz,)`` (in place)."""
        size, nnz = pattern.dimension, pattern.nnz
        for (hessian, gradient), h, r in zip(self._positions(), blocks.hessian, blocks.gradient):
            g += np.bincount(gradient, weights=r.ravel(), minlength=size + 1)[:size]
            if data is not None:
                data[:nnz] += np.bincount(hessian, weights=h, minlength=nnz + 1)[:nnz]

    def factored(self, pattern) -> None:
        """Remember what a numeric factorisation made now holds: each family's count, the decoupled rows."""
        self.held_counts = {key: family.count for key, family in self.store.families.items()}
        self.held_decoupled = self.decoupled_rows(pattern)

    def terms(self, pattern, terms, blocks):
        """``terms`` with the landmark measurements not in the held factor — added since it was made
        (:meth:`factored`) or left out of H — as low-rank terms, at their linearisation ``blocks``
        (``LandmarkBlocks``), minus the unit diagonal of the points the factor decoupled that measurements
        reach now."""
        d, s = self.d, self.s
        columns, values = [], []
        for (key, family), h in zip(((k, f) for k, f in self.store.families.items() if f.count), blocks.hessian):
            start = self.held_counts.get(key, 0)
            rows = np.arange(start, family.count)
            if key in self.left_out:
                rows = np.union1d(self.left_out[key], rows)
            if rows.shape[0]:
                columns.append(self.placed[key][1].view[rows])
                values.append(_measurement_blocks(family, h, d, s, rows))
        unit = np.setdiff1d(self.held_decoupled, self.decoupled_rows(pattern))
        if not columns and not unit.shape[0]:
            return terms
        width = max((c.shape[1] for c in columns), default=s)
        columns = [np.pad(c, ((0, 0), (0, width - c.shape[1])), constant_values=pattern.dimension) for c in columns]
        values = [np.pad(v, ((0, 0), (0, width - v.shape[1]), (0, width - v.shape[1]))) for v in values]
        empty = (np.zeros((0, width), np.int64), np.zeros((0, width, width)))
        return with_landmark_terms(terms, np.concatenate(columns) if columns else empty[0],
                                   np.concatenate(values) if values else empty[1], unit, pattern.dimension)

    def decoupled_rows(self, pattern) -> np.ndarray:
        """Rows of the point variables no measurement reaches (points to come, points not yet seen)."""
        s = self.s
        seen = np.zeros(self.capacity, dtype=bool)
        for family in self.store.families.values():
            seen[family.landmark.view] = True
        variable = pattern.point_variable_of[~seen]
        variable = variable[variable >= 0]
        return (pattern.offsets[variable][:, None] + np.arange(s)).ravel()


def _find(keys: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(slot, found)`` ``(w,)``: where each of ``wanted`` (block keys) is or would be in the sorted ``keys``."""
    slot = np.minimum(np.searchsorted(keys, wanted), max(keys.shape[0] - 1, 0))
    found = keys[slot] == wanted if keys.shape[0] else np.zeros(wanted.shape[0], dtype=bool)
    return slot, found


def _measurement_blocks(family, h: np.ndarray, d: int, s: int, rows: np.ndarray) -> np.ndarray:
    """``(k, c, c)`` the full Hessian of the measurements ``rows`` ``(k,)`` of ``family``, from its raveled
    blocks ``h`` (``[H_pp, H_ll, H_pl]``; priors ``H_ll``): ``[[H_pp, H_pl], [H_plᵀ, H_ll]]``, c = d + s (priors s)."""
    q = family.count
    if family.kind == "prior":
        return h.reshape(q, s, s)[rows]
    pp = h[: q * d * d].reshape(q, d, d)[rows]
    ll = h[q * d * d : q * (d * d + s * s)].reshape(q, s, s)[rows]
    pl = h[q * (d * d + s * s) :].reshape(q, d, s)[rows]
    return np.concatenate([np.concatenate([pp, pl], axis=2), np.concatenate([np.swapaxes(pl, 1, 2), ll], axis=2)], axis=1)


def with_landmark_terms(terms, columns: np.ndarray, values: np.ndarray, unit: np.ndarray, dimension: int):
    """``terms`` (:class:`~posegraph.incremental.held_factor.LowRankTerms`) plus measurements' Hessians
    ``values`` ``(q, c, c)`` on scalar columns ``columns`` ``(q, c)`` (``dimension``: held, left out) minus
    the unit diagonal of rows ``unit`` (points decoupled in the factor, reached by a measurement since)."""
    from posegraph.incremental.held_factor import LowRankTerms

    valid = columns < dimension
    union = np.unique(np.concatenate([terms.columns, columns[valid], unit]))
    q = union.shape[0]
    matrix = np.zeros((q, q))
    old = np.searchsorted(union, terms.columns)
    matrix[np.ix_(old, old)] = terms.matrix
    at = np.searchsorted(union, np.where(valid, columns, union[-1] if q else 0))
    both = valid[:, :, None] & valid[:, None, :]
    flat = (at[:, :, None] * q + at[:, None, :])[both]
    matrix += np.bincount(flat, weights=values[both], minlength=q * q).reshape(q, q)
    diagonal = np.searchsorted(union, unit)
    matrix[diagonal, diagonal] -= 1.0
    return LowRankTerms(union, matrix)
