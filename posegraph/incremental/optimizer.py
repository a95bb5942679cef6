"""The incremental optimiser: a graph that grows in batches and an estimate kept at its optimum.

Design (``docs/incremental.md``):

* **New poses by composition.** A new vertex reached through a new edge from a vertex already placed
  is put where that edge says (``X_j = X_i Z``), breadth first over the batch's edges. An edge used so
  (a *tree* edge) has a zero residual and adds nothing to the gradient: a batch made only of such edges
  (odometry) leaves the estimate at the optimum of the new graph exactly, with no linear algebra.
* **Gauss-Newton on the whole graph, its analysis held** (:mod:`posegraph.incremental.whole`). Every
  other edge, a prior, a landmark measurement that is not a first sighting, a removed edge or an anchor
  released by a join runs Gauss-Newton on the whole graph (landmarks' points included) with the block
  pattern and CHOLMOD's symbolic factorisation kept from update to update; a fresh
  step that raises the cost even halved six times, or 30 steps short of the tolerance, hand the update
  to the batch solver (:func:`posegraph.solve.optimize`, LM, warm), and so does a *drastic* update
  from the start (:data:`DRASTIC`).
* **Stated tolerance.** Default ``tolerance = 1e-7`` (:data:`DEFAULT_TOLERANCE`): after each update the
  cost exceeds the optimum of the graph so far by at most about ``tolerance`` relative (measured at most
  1e-6 in ``benchmarks/bench_incremental.py``; the Newton decrement is the excess to second order, not a
  bound). ``verify=True`` checks every update that did any work with a warm batch solve of the whole
  graph (its own test, the Newton decrement, stops it at once when the estimate is already optimal):
  exact, O(graph) per update.
* **Deferred updates** (the speed setting, a looser ``tolerance``). The optimiser keeps a bound ``E`` on
  cost − optimum: the Newton decrement where the last solve stopped (at SOLVE_SHARE of a loose
  tolerance), unchanged by odometry (new leaves move neither), and raised by exactly the cost an update
  adds when it adds terms without solving: adding terms ``r ≥ 0`` raises the optimum by at least 0, so
  ``f(x) + r(x) − min(f + r) ≤ f(x) − min f + r(x)``. An update that only adds (no removal, no landmark)
  is left unsolved (``kind = "bounded"``) while ``E ≤ tolerance/(1 + tolerance) · cost``, which makes
  ``(cost − optimum)/optimum ≤ tolerance`` (the decrement part to second order). A removal, the batch
  solver (no decrement) or ``verify`` forget the bound: the next update with work solves.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from posegraph.errors import GraphError
from posegraph.incremental.components import Components
from posegraph.incremental.covariance import Covariances
from posegraph.incremental.landmark_store import LandmarkStore, check_landmark_measurements
from posegraph.incremental.store import EdgeTerms, GraphStore, check_information, check_poses
from posegraph.incremental.whole import WholeGraph
from posegraph.lie.group import SE3
from posegraph.model.graph import PoseGraph
from posegraph.solve.params import SolverParams

__all__ = ["IncrementalOptimizer", "UpdateInfo", "DEFAULT_TOLERANCE"]

DRASTIC = 10.0
DRASTIC_CHI2 = 1e3
"""An update whose new terms raise the cost by more than DRASTIC times the cost before it, and by more
than DRASTIC_CHI2 per tangent dimension, goes to the batch solver at once
(:meth:`IncrementalOptimizer._drastic`). Ordinary loop closures raise the cost by a few per cent; the
first one of an odometry chain (cost ~0 before) by χ² of order 1, which Gauss-Newton handles in a step or
two; a loop closure over a long drifted trajectory by χ² of 10⁴–10⁸. χ² scales with the information:
with intel's ×1e4, its first loop closure goes to the batch solver too, to the same optimum (intel's first
600 poses replayed with the information ×1e-4, ×1, ×1e4: cost / scale 3.662873663471 each time)."""

DEFAULT_TOLERANCE = 1e-7
"""Relative cost excess aimed at after each update. The stopping test is the Newton decrement at the
current point, so a loop closure's update usually ends after one Newton step and the check that
follows it; at 1e-8 a third of them took another step (sphere2500, intel), ~25 % more time for
excesses that stay an order of magnitude below the 1e-6 the optimiser is measured against."""


SOLVE_SHARE = 0.1
"""A solve under a tolerance looser than DEFAULT_TOLERANCE stops when its Newton decrement is below this
share of it (:attr:`IncrementalOptimizer.solve_tolerance`): the rest is the budget that lets later updates
be deferred (:meth:`IncrementalOptimizer._defer_if_bounded`) and a margin for the decrement being the excess to
second order only (a solve stopped at the full tolerance ended 0.7 % above it on a random SE(2) graph)."""


@dataclass(frozen=True)
class UpdateInfo:
    """What one :meth:`IncrementalOptimizer.update` did."""

    kind: str
    """``"none"`` (nothing added), ``"exact"`` (new poses by composition only), ``"whole"`` (Gauss-Newton on
    the held analysis), ``"bounded"`` (terms added, no solve: the excess bound allows it), ``"full"`` (the batch solver)."""
    seconds: float
    vertices: int
    """Free vertices Gauss-Newton ran on (0 for ``none``/``exact``)."""
    iterations: int
    cost: float
    """The cost after the update (½ Σ eᵀΩe, or ½ Σ ρ with a loss; priors included)."""


class _Batch:
    """What was added since the last update, checked, not yet in the graph."""

    def __init__(self, k: int, d: int):
        self.ids: list[np.ndarray] = []
        self.poses: list[np.ndarray] = []
        self.fixed: list[np.ndarray] = []
        self.known: set[int] = set()
        self.edges: list[tuple] = []
        self.pose_priors: list[tuple] = []
        self.position_priors: list[tuple] = []
        self.removals: list[np.ndarray] = []
        self.landmarks: list[tuple] = []
        self.known_landmarks: set[int] = set()
        self.landmark_measurements: list[tuple] = []
        self.landmark_removals: list[np.ndarray] = []

    def empty(self) -> bool:
        return not (self.ids or self.edges or self.pose_priors or self.position_priors or self.removals
                    or self.landmarks or self.landmark_measurements or self.landmark_removals)


def _ids(values, what: str) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim != 1 or (array.size and not np.issubdtype(array.dtype, np.integer)):
        raise GraphError(f"{what}: ids must be a 1-D array of integers")
    return array.astype(np.int64)


class IncrementalOptimizer:
    """A pose graph that grows in batches, kept at its optimum after each :meth:`update`.

    ``group``: :data:`posegraph.lie.group.SE3` (default), ``SE2``, ``SIM3``. ``tolerance``: the relative
    cost excess aimed at (module docstring). ``params``: :class:`posegraph.solve.SolverParams` of the
    solves handed to the batch solver (``optimize``, ``verify``, drastic or failed updates): its ``loss``
    (a robust loss, applied in every solve, the incremental ones too), ``linear_solver``, ``ordering``, ``method``.
    """

    def __init__(self, group=SE3, *, tolerance: float = DEFAULT_TOLERANCE, params: SolverParams | None = None, verify: bool = False):
        if not tolerance > 0:
            raise ValueError(f"tolerance must be positive, got {tolerance}")
        self.group, self.tolerance, self.verify = group, float(tolerance), bool(verify)
        self.params = SolverParams() if params is None else params
        self._store = GraphStore(group)
        self._landmarks = LandmarkStore(group)
        self._whole = WholeGraph(self._store, self.params.loss, self._landmarks)
        self._components = Components()
        self._covariances = Covariances(self._store, self._whole, lambda: self._components.held, self.held)
        self._terms = EdgeTerms()
        self._unary: float | None = None  # the priors' and landmark measurements' part of the cost, when known
        self._excess: float | None = None  # a bound on cost − optimum of the graph so far (None: not known)
        self._batch = _Batch(group.matrix_size, group.dim)
        self.last_update: UpdateInfo | None = None
        self._version = 0

    # ------------------------------------------------------------------ reading

    @property
    def num_vertices(self) -> int:
        return self._store.num_vertices

    @property
    def num_edges(self) -> int:
        return self._store.num_edges

    @property
    def ids(self) -> np.ndarray:
        return self._store.ids.view.copy()

    @property
    def poses(self) -> np.ndarray:
        """``(n, k, k)`` the current estimate, in the order the vertices were added (a copy)."""
        return self._store.poses.view.copy()

    @property
    def edge_keys(self) -> np.ndarray:
        """``(m,)`` the key of each edge in the graph (what :meth:`add_edges` returned), edge order."""
        return self._store.edge_keys.view.copy()

    @property
    def landmark_ids(self) -> np.ndarray:
        """``(L,)`` the landmarks' ids, in the order they were added."""
        return self._landmarks.ids.view.copy()

    @property
    def landmark_positions(self) -> np.ndarray:
        """``(L, s)`` the current estimate of the landmarks, in :attr:`landmark_ids` order (a copy)."""
        return self._landmarks.positions.view.copy()

    def pose(self, vertex_id: int) -> np.ndarray:
        return self._store.poses.view[self._store.indices_of(_ids([vertex_id], "pose"), "pose")[0]].copy()

    def cost(self) -> float:
        """The cost at the current estimate (from per-edge terms kept up to date; the priors' and landmark
        measurements' part evaluated once per change of it)."""
        total = 0.5 * self._terms.total()
        if self._store.num_priors or self._landmarks.count:
            if self._unary is None:
                self._unary = self._unary_cost()
            total += self._unary
        return total

    def _unary_cost(self) -> float:
        """The priors' and landmark measurements' part of the cost (the edges' is kept per edge)."""
        from posegraph.solve.objective import Objective

        store = self._store
        graph = PoseGraph(ids=store.ids.view, poses=store.poses.view, edge_from=np.zeros(0, np.int64),
                          edge_to=np.zeros(0, np.int64), measurements=store.measurements.view[:0],
                          information=store.information.view[:0], fixed=store.fixed.view, group=self.group,
                          priors=store.priors(), landmarks=self._landmarks.landmarks())
        points = self._landmarks.positions.view if self._landmarks.count else None
        return Objective(graph, self.params.loss).evaluate(store.poses.view, points).cost

    def graph(self) -> PoseGraph:
        """The graph so far as a :class:`PoseGraph` at the current estimate (write it with ``write_g2o``)."""
        s = self._store
        return PoseGraph(
            ids=s.ids.view.copy(), poses=s.poses.view.copy(), edge_from=s.edge_from.view.copy(),
            edge_to=s.edge_to.view.copy(), measurements=s.measurements.view.copy(),
            information=s.information.view.copy(), fixed=s.fixed.view.copy(), group=self.group, priors=s.priors(),
            landmarks=self._landmarks.landmarks(),
        )  # fmt: skip

    def held(self) -> np.ndarray:
        """``(n,)`` bool: FIX vertices and each component's anchor (held at their estimate)."""
        return self._components.held_mask()

    # ------------------------------------------------------------------ adding (checked, staged)

    def add_vertices(self, ids, poses, fixed=None) -> None:
        """Stage new vertices: ids ``(a,)``, initial poses ``(a, k, k)`` (used for a vertex no edge
        places: the first of a new component), ``fixed`` ``(a,)`` bool (FIX: held at that pose)."""
        ids = _ids(ids, "vertices")
        poses = np.asarray(poses, dtype=np.float64).reshape((-1,) + (self.group.matrix_size,) * 2)
        fixed = np.zeros(ids.shape[0], bool) if fixed is None else np.asarray(fixed, dtype=bool).reshape(-1)
        if poses.shape[0] != ids.shape[0] or fixed.shape[0] != ids.shape[0]:
            raise GraphError(f"vertices: {ids.shape[0]} ids, {poses.shape[0]} poses, {fixed.shape[0]} fixed flags")
        check_poses(poses, self.group, "vertex")
        unique, counts = np.unique(ids, return_counts=True)
        if unique.shape[0] != ids.shape[0]:
            raise GraphError(f"vertex id {int(unique[counts > 1][0])} is given twice in the batch")
        index, known = self._store.index, self._batch.known
        for vertex in ids.tolist():
            if vertex in index or vertex in known or self._is_landmark(vertex):
                raise GraphError(f"vertex id {vertex} is already in the graph")
        self._batch.ids.append(ids)
        self._batch.poses.append(poses.copy())
        self._batch.fixed.append(fixed.copy())
        known.update(ids.tolist())

    def _check_known(self, ids: np.ndarray, what: str) -> None:
        index, known = self._store.index, self._batch.known
        for position, vertex in enumerate(ids.tolist()):
            if vertex not in index and vertex not in known:
                raise GraphError(f"{what} #{position}: vertex id {vertex} is not in the graph")

    def add_edges(self, from_ids, to_ids, measurements, information) -> np.ndarray:
        """Stage edges ``from_ids[e] → to_ids[e]`` measuring ``Z ≈ X_i⁻¹ X_j`` ``(b, k, k)`` with
        information ``(b, d, d)`` (tangent order); returns their keys (for :meth:`remove_edges`)."""
        i, j = _ids(from_ids, "edges"), _ids(to_ids, "edges")
        k, d = self.group.matrix_size, self.group.dim
        z = np.asarray(measurements, dtype=np.float64).reshape((-1, k, k))
        w = np.asarray(information, dtype=np.float64)
        w = w.reshape((-1, d, d)) if w.size == i.shape[0] * d * d else w
        if not (i.shape == j.shape and z.shape[0] == i.shape[0] and w.ndim == 3 and w.shape[0] == i.shape[0]):
            raise GraphError(f"edges: {i.shape[0]} from-ids, {j.shape[0]} to-ids, {z.shape[0]} measurements, "
                             f"{w.shape[0] if w.ndim else 0} information matrices")
        self._check_known(i, "edge")
        self._check_known(j, "edge")
        loops = np.flatnonzero(i == j)
        if loops.size:
            raise GraphError(f"edge #{int(loops[0])}: joins vertex {int(i[loops[0]])} to itself")
        check_poses(z, self.group, "edge measurement")
        check_information(w, "edge", d)
        start = self._store.next_key + sum(len(e[0]) for e in self._batch.edges)
        self._batch.edges.append((i, j, z.copy(), w.copy()))
        return np.arange(start, start + i.shape[0], dtype=np.int64)

    def add_pose_priors(self, ids, measurements, information) -> None:
        """Stage pose priors ``Z ≈ X`` ``(a, k, k)`` with information ``(a, d, d)``."""
        ids = _ids(ids, "pose priors")
        k, d = self.group.matrix_size, self.group.dim
        z = np.asarray(measurements, dtype=np.float64).reshape((-1, k, k))
        w = np.asarray(information, dtype=np.float64).reshape((-1, d, d))
        if not (z.shape[0] == w.shape[0] == ids.shape[0]):
            raise GraphError("pose priors: ids, measurements and information differ in count")
        self._check_known(ids, "pose prior")
        check_poses(z, self.group, "pose prior")
        check_information(w, "pose prior", d)
        self._batch.pose_priors.append((ids, z.copy(), w.copy()))

    def add_position_priors(self, ids, positions, information) -> None:
        """Stage position priors ``z ≈ t(X)`` ``(b, r)`` with information ``(b, r, r)``."""
        ids = _ids(ids, "position priors")
        r = self.group.space_dim
        z = np.asarray(positions, dtype=np.float64).reshape((-1, r))
        w = np.asarray(information, dtype=np.float64).reshape((-1, r, r))
        if not (z.shape[0] == w.shape[0] == ids.shape[0]) or not np.isfinite(z).all():
            raise GraphError("position priors: ids, positions and information differ in count, or a position is not finite")
        self._check_known(ids, "position prior")
        check_information(w, "position prior", r)
        self._batch.position_priors.append((ids, z.copy(), w.copy()))

    def _is_landmark(self, identifier: int) -> bool:
        return identifier in self._landmarks.index or identifier in self._batch.known_landmarks

    def add_landmarks(self, ids, positions=None, fixed=None) -> None:
        """Stage landmarks, points of the graph's space (SE(2): ``s = 2``, SE(3): ``s = 3``).

        ``ids`` ``(a,)``, distinct from every pose id; ``positions`` ``(a, s)``, or None, or NaN rows:
        a landmark is placed at :meth:`update` from its measurements given the poses
        (:func:`posegraph.init.landmarks.initialize_landmarks`), its given position kept only when they
        do not determine it (a lone bearing); ``fixed`` ``(a,)`` bool: ``FIX``, held at its given position.
        """
        ids = _ids(ids, "landmarks")
        s = self.group.space_dim
        if self.group.name == "SIM3":
            raise GraphError("landmarks: Sim(3) graphs have no landmarks (SE(2) and SE(3) have)")
        given = np.full((ids.shape[0], s), np.nan) if positions is None else np.asarray(positions, np.float64)
        fixed = np.zeros(ids.shape[0], bool) if fixed is None else np.asarray(fixed, dtype=bool).reshape(-1)
        if given.shape != (ids.shape[0], s) or fixed.shape[0] != ids.shape[0]:
            raise GraphError(f"landmarks: {ids.shape[0]} ids, positions of shape {given.shape} (want "
                             f"({ids.shape[0]}, {s})), {fixed.shape[0]} fixed flags")
        bad = np.flatnonzero(np.isinf(given).any(axis=1) | (fixed & np.isnan(given).any(axis=1)))
        if bad.size:
            raise GraphError(f"landmark #{int(bad[0])}: position not finite (a FIX landmark needs its position)")
        unique, counts = np.unique(ids, return_counts=True)
        if unique.shape[0] != ids.shape[0]:
            raise GraphError(f"landmark id {int(unique[counts > 1][0])} is given twice in the batch")
        for landmark in ids.tolist():
            if self._is_landmark(landmark) or landmark in self._store.index or landmark in self._batch.known:
                raise GraphError(f"landmark id {landmark} is already in the graph")
        self._batch.landmarks.append((ids, given.copy(), fixed.copy()))
        self._batch.known_landmarks.update(ids.tolist())

    def add_landmark_measurements(self, kind: str, pose_ids, landmark_ids, measurements, information, *,
                                  offsets=None, tag: str = "") -> np.ndarray:
        """Stage measurements of one kind (:data:`posegraph.model.landmarks.KINDS`; residuals as in
        :mod:`posegraph.model.landmarks`): pose ``pose_ids`` ``(q,)`` (None for ``"prior"``) sees landmark
        ``landmark_ids`` ``(q,)`` as ``measurements`` ``(q, r)`` with ``information`` ``(q, r, r)``;
        ``offsets`` ``(q, k, k)``: the sensor in the body frame (``"position"``; identity if None);
        ``tag``: the file tag written back (``EDGE_SE2_XY``, …). Returns their keys ``(q,)`` (for
        :meth:`remove_landmark_measurements`)."""
        landmarks = _ids(landmark_ids, "landmark measurements")
        z, w, offsets = check_landmark_measurements(self.group, kind, landmarks.shape[0], measurements, information, offsets)
        if kind == "prior":
            poses = np.full(landmarks.shape[0], -1, dtype=np.int64)
        else:
            poses = _ids(pose_ids, "landmark measurements")
            if poses.shape != landmarks.shape:
                raise GraphError(f"landmark measurements: {poses.shape[0]} pose ids, {landmarks.shape[0]} landmark ids")
            self._check_known(poses, "landmark measurement")
        for position, landmark in enumerate(landmarks.tolist()):
            if not self._is_landmark(landmark):
                raise GraphError(f"landmark measurement #{position}: landmark id {landmark} is not in the graph")
        start = self._landmarks.next_key + sum(len(m[3]) for m in self._batch.landmark_measurements)
        keys = np.arange(start, start + landmarks.shape[0], dtype=np.int64)
        self._batch.landmark_measurements.append((kind, str(tag), poses, landmarks, z.copy(), w.copy(), offsets, keys))
        return keys.copy()

    def remove_landmark_measurements(self, keys) -> None:
        """Stage the removal of landmark measurements by key (a data association found wrong); applied at
        :meth:`update`, before the batch's new measurements."""
        keys = _ids(keys, "landmark measurements to remove")
        self._landmarks.find(np.concatenate(self._batch.landmark_removals + [keys]))  # checks, unchanged on error
        self._batch.landmark_removals.append(keys)

    def remove_edges(self, keys) -> None:
        """Stage the removal of edges by key (e.g. a loop closure found wrong); applied at :meth:`update`."""
        keys = _ids(keys, "edges to remove")
        self._store.edge_positions(np.concatenate(self._batch.removals + [keys]))  # checks, unchanged on error
        self._batch.removals.append(keys)

    def discard(self) -> None:
        """Drop what was staged since the last update."""
        self._batch = _Batch(self.group.matrix_size, self.group.dim)

    # ------------------------------------------------------------------ updating

    def update(self) -> UpdateInfo:
        """Put the staged batch into the graph and bring the estimate to the new optimum."""
        from posegraph.incremental.commit import commit_batch
        from posegraph.incremental.landmark_commit import check_placeable

        start = time.perf_counter()
        check_placeable(self._batch)
        batch, self._batch = self._batch, _Batch(self.group.matrix_size, self.group.dim)
        placed = np.zeros((0, 3), dtype=np.int64)
        if batch.empty():
            info = UpdateInfo("none", 0.0, 0, 0, self.cost())
        else:
            if batch.removals or batch.landmark_removals:
                self._excess = None  # a removal can lower the optimum: the bound is lost
            before = self.cost() if self._excess is not None else None
            touched, landmark_work, placed = commit_batch(self, batch)
            if landmark_work or batch.pose_priors or batch.position_priors:
                self._unary = None  # terms that need not vanish were added to that part of the cost
            kind, vertices, iterations = self._solve(touched, landmark_work, self._defer_if_bounded(batch, before))
            if kind == "whole":
                self._unary = self._whole.unary_cost  # the solve's final evaluation less its edges' terms
            elif kind != "exact":
                # an exact update moves nothing and adds landmark terms that vanish (first sightings); else re-evaluate
                self._unary = None
            info = UpdateInfo(kind, time.perf_counter() - start, vertices, iterations, self.cost())
        self.last_update = info
        self._version += 1
        # pure odometry adds leaves (every covariance so far unchanged); anything else drops the covariances
        odometry = info.kind in ("none", "exact") and not (batch.pose_priors or batch.position_priors or batch.removals
                                                          or batch.landmarks or batch.landmark_measurements
                                                          or batch.landmark_removals or self._landmarks.count)
        self._covariances.advance(self._version - 1, self._version, placed if odometry else None)
        return info

    def _solve(self, touched: list[int], landmark_work: bool = False, deferrable: bool = False) -> tuple[str, int, int]:
        held = self._components.held
        seeds = [v for v in touched if not held[v]]
        if not seeds and not landmark_work:
            return "exact", 0, 0  # the optimum moved by exactly what the cost did: the excess is unchanged
        if deferrable:
            return "bounded", 0, 0
        self._excess = None
        kind, vertices, iterations = self._solve_whole()
        if self.verify and kind != "full":
            self.optimize(method="gn")
            kind = "full"
        elif kind == "whole":
            self._excess = self._whole.decrement
        return kind, vertices, iterations

    def _defer_if_bounded(self, batch, before: float | None) -> bool:
        """Defer this update when it may leave the estimate where it is, the excess still within ``tolerance``
        (module docstring, *Deferred updates*): terms were only added (no removal, no landmark), and the
        bound on the excess before it plus the cost they added is at most ``tolerance/(1 + tolerance)``
        of the cost now; then keeps that sum as the bound, drops the held factor and returns True."""
        if before is None or self.verify or batch.removals or batch.landmarks or batch.landmark_measurements \
                or batch.landmark_removals or self._landmarks.count:
            return False
        now = self.cost()
        bound = self._excess + max(now - before, 0.0)
        if not bound <= self.tolerance / (1.0 + self.tolerance) * now:
            return False
        self._excess = bound
        self._whole.current = None  # a factor the last solve ended on lacks the new terms
        return True

    def _solve_whole(self) -> tuple[str, int, int]:
        """Gauss-Newton on the whole graph with the held analysis (:mod:`posegraph.incremental.whole`);
        the damped batch solver when the update is drastic or a step fails."""
        held = self._components.held_mask()
        if self._drastic():
            result = self._batch_solve()
            return "full", int(np.count_nonzero(~held)), int(result.iterations)
        ok, iterations, terms = self._whole.solve(held, self.solve_tolerance, predicted_stop=self.tolerance > DEFAULT_TOLERANCE)
        if not ok:
            result = self._batch_solve()
            return "full", int(np.count_nonzero(~held)), iterations + int(result.iterations)
        self._terms.set(slice(None), terms)
        return "whole", int(np.count_nonzero(~held)), iterations

    @property
    def solve_tolerance(self) -> float:
        """The Newton-decrement test a solve stops at, relative to the cost: ``tolerance`` up to
        DEFAULT_TOLERANCE, else SOLVE_SHARE of it (at least DEFAULT_TOLERANCE)."""
        return min(self.tolerance, max(DEFAULT_TOLERANCE, SOLVE_SHARE * self.tolerance))

    def _drastic(self) -> bool:
        """Whether this update's new terms raised the cost by more than DRASTIC times the last update's
        cost and by more than DRASTIC_CHI2 per tangent dimension: the new constraints then dominate the
        cost and disagree wildly with the estimate (a loop closure over a long drifted trajectory), far
        from the new optimum, where the batch solver's LM takes fewer steps than Gauss-Newton with
        backtracking (100,000-pose route: 28–32 against 30 plus the hand-over's 12)."""
        if self.last_update is None:
            return False
        added = self.cost() - self.last_update.cost
        return added > DRASTIC * self.last_update.cost and added > DRASTIC_CHI2 * self.group.dim

    def _batch_solve(self):
        """The batch solver from the current estimate, its relative tolerance at most :attr:`tolerance`."""
        return self.optimize(relative_tolerance=min(self.tolerance, self.params.relative_tolerance))

    def _refresh_terms(self, edges: np.ndarray, residuals: np.ndarray | None = None) -> None:
        """Per-edge cost terms of ``edges`` at the current estimate (from their ``residuals`` ``(k, d)`` at
        it when given, e.g. the batch solver's last evaluation)."""
        from posegraph.solve.residuals import squared_norms

        store = self._store
        if residuals is None:
            residuals = store.edge_errors(edges)[1]
        s = squared_norms(residuals, store.information.view[edges])
        loss = self.params.loss
        self._terms.set(edges, s if loss is None else loss.rho(s))

    def optimize(self, **changes):
        """A batch solve of the whole graph from the current estimate (:func:`posegraph.solve.optimize`
        with ``params``, ``changes`` replacing fields); the estimate becomes its result, returned."""
        from posegraph.solve import optimize

        graph = replace(self.graph(), fixed=self.held())
        points = None if graph.landmarks is None else graph.landmarks.positions
        result = optimize(graph, initial=graph.poses, params=replace(self.params, **changes) if changes else self.params,
                          initial_points=points)
        self._store.poses.view[:] = result.poses
        self._whole.current = None  # a factor the last solve ended on is not of these poses
        self._excess = None  # LM's stopping test bounds no excess
        self._unary = None
        if points is not None:
            self._landmarks.positions.view[:] = result.points
        self._version += 1  # the estimate changed: a covariance factorised before is stale
        residuals = result.final_residuals
        usable = residuals is not None and residuals.shape[0] == self._store.num_edges
        self._refresh_terms(np.arange(self._store.num_edges), residuals if usable else None)
        return result

    # ------------------------------------------------------------------ covariances

    def marginal_covariance(self, vertex_id: int) -> np.ndarray:
        """``(d, d)`` marginal covariance of one pose at the current estimate (``analysis.covariance``'s
        convention; zero for a held vertex). Cached until the next update that is not pure odometry;
        a pose added by odometry costs O(1) (:mod:`posegraph.incremental.covariance`)."""
        self._whole.covariance_wanted = True  # the next solve ends on a factor at its final poses
        index = int(self._store.indices_of(_ids([vertex_id], "covariance"), "covariance")[0])
        if self._landmarks.count:  # the held analysis is of poses only
            return self.joint_covariance([vertex_id])
        return self._covariances.marginal(index, self._version)

    def joint_covariance(self, vertex_ids) -> np.ndarray:
        """``(k·d, k·d)`` joint covariance of a few poses at the current estimate, blocks in the order given
        (cached as :meth:`marginal_covariance`; with landmarks: :mod:`posegraph.analysis.covariance` on the whole graph)."""
        from posegraph.analysis.covariance import joint_covariance

        self._whole.covariance_wanted = True
        index = self._store.indices_of(_ids(vertex_ids, "covariance"), "covariance")
        if not self._landmarks.count:
            return self._covariances.joint(index.tolist(), self._version)
        graph = replace(self.graph(), fixed=self.held())
        points = None if graph.landmarks is None else graph.landmarks.positions
        return joint_covariance(graph, graph.poses, index, points=points)
