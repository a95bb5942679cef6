"""Gauss-Newton on the whole graph with its symbolic analysis held from update to update.

A loop closure moves the whole loop, so a solve around the touched vertices grows to most of the
graph anyway; here every update with work to do runs undamped Gauss-Newton on the *whole* graph, and
what does not change between updates is kept:

* **The analysis.** The block pattern of H (:func:`posegraph.solve.sparsity.analyze_pattern`) and
  CHOLMOD's symbolic factorisation (AMD) are made for a *capacity* larger than the graph (×GROWTH), the
  vertices not yet added decoupled (unit diagonal, zero gradient: their step is 0). The pattern holds
  the blocks of every edge so far, the odometry chain ``(v, v+1)`` of the vertices to come, and, for
  each loop closure ``(lo, hi)`` added since the last analysis, the cone of blocks a re-traversal
  would add next (``(lo + t, hi + s)``, ``1 ≤ s ≤ PREDICT``, ``−s−2 ≤ t ≤ 3s+2``: the older end may
  advance at another pace, or back). A new edge whose block is in the pattern costs only its
  scatter positions. Up to MAX_LEFT_OUT edges whose block is missing are left out of the factorised
  matrix and added back exactly as low-rank terms of the held factor (below);
  the analysis is redone when more are missing, the capacity is exceeded, the held set (FIX, anchors)
  changed, or H without the left-out terms is singular — amortised over many updates. It orders the
  vertex graph (AMD on p nodes), expanded to the blocks.
* **The factor, held (:mod:`posegraph.incremental.held_factor`).** The last numeric factorisation
  ``H0`` (made at an earlier point, over the edges then present) is kept across steps *and updates*;
  a step solves ``H̃ = H0 + E_K M E_Kᵀ`` with the exact gradient, ``M`` re-linearised at the current
  point at every step: the Hessian blocks of the edges added since ``H0`` and of the left-out edges,
  minus the unit diagonal ``H0`` gave the vertices added since, plus ``H(now) − H(then)`` of the
  RELINEARISE old edges whose residual moved most and of every prior. The Newton decrement
  ``½ gᵀH̃⁻¹g`` comes from the forward half of the solve (the stopping test runs before the backward
  solve). A step refactorises at the current point instead when the held one raised the cost, the
  decrement at this point is not ×4 (CHORD_RATE) below the last step's (the held system is off here:
  refactorised before the step is spent), the terms pass ``max_columns`` or BREAK_EVEN
  of a factorisation's work, priors were added, a new analysis was made, or held steps kept failing
  (CHORD_ODDS). The stopping test is ``½ gᵀH̃⁻¹g ≤ tolerance · cost`` at the current point (the excess
  over the optimum, to second order), so accuracy rests on the exact gradient.
* **Landmarks** (:mod:`posegraph.incremental.held_points`). The analysis gives the points variables of
  their own block size after the poses', for a capacity of points too, with the pose–point blocks of
  every measurement and those the next sightings are likely to need; a landmark update is Gauss-Newton
  here like a loop closure, the points retracted ``p + δ`` with the poses. Up to
  ``HeldPoints.max_left_out`` measurements whose block is missing (a landmark seen again after a gap) are
  left out of the factorised matrix as the left-out edges are. The measurements added since the held
  factor was made and the left-out ones are low-rank terms of it (their full pose–point Hessians, minus
  the unit diagonal of the points it decoupled): a re-sighting is a held step, not a factorisation.
* **The last linearisation.** A solve ends linearised at its final point; the next one starts from
  that evaluation and linearisation with only the new edges and landmark measurements computed
  (:mod:`posegraph.incremental.reuse`), as long as no old pose or point moved in between (odometry and
  first sightings are placed exactly) and there are no priors.

Each step's cost is the exact one (:class:`posegraph.solve.objective.Objective`, losses and priors
included); a step that raises it restores the poses (after a held step: a refactorised step is tried;
after one on a factor made at that point: :meth:`WholeGraph.solve` returns False and the caller runs the damped batch solver).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.incremental.held_factor import HeldFactor, LowRankTerms, edge_terms
from posegraph.incremental.held_points import HeldPoints
from posegraph.incremental.reuse import LastPoint
from posegraph.linalg.cholmod import NotPositiveDefiniteError, SparseCholesky, block_permutation, fill_reducing_order
from posegraph.model.graph import PoseGraph
from posegraph.solve.objective import Objective
from posegraph.solve.sparsity import analyze_pattern
from posegraph.solve.unary import add_prior_gradient, add_prior_hessian

__all__ = ["WholeGraph", "edge_positions", "GROWTH", "PREDICT"]

GROWTH = 1.1
"""Capacity of an analysis relative to the vertex count it was made at (at least 64 vertices more). The
vertices to come are factorised with the rest at every step (unit diagonal, chain blocks), and most
analyses come from new blocks every few loop-closure updates, not from the capacity: at ×1.5 a
replay of manhattan / parking-garage took ~10 % longer and ~40 % more CPU than at ×1.1."""

PREDICT = 8
"""Blocks predicted along each loop closure of the update that forced an analysis, each direction."""

PREDICTED_LOOPS = 16
"""At most this many of those loop closures (the last ones) get predicted blocks: a batch of thousands
(a whole graph put in at once) would otherwise add ~184 blocks each, filling the factor for nothing
(20,000 manhattan poses in one update: 74 s and a 0.47 s covariance solve with all of them predicted)."""

REORDER = 8
"""Analyses at one capacity that reuse the last elimination order before AMD runs again."""

BACKTRACK = 6
"""Halvings of an overshooting fresh step tried before the damped batch solver takes over."""

CHORD_RATE = 0.25
"""The Newton decrement on the held factor must be at most this share of the last step's, else the step
refactorises at once (the held system is off at this point)."""

CHORD_ODDS = 0.3
"""A held (chord) step, on a factor made at another point, is taken only while at least this share of
the recent ones (a moving average, weight 1/8 to the last) lowered the cost; otherwise the next step
refactorises at once: each rejected one costs an evaluation of the whole graph for nothing. The Newton
decrement is still computed on the held factor first (the stopping test). Every PROBE-th chance a held
step is tried."""

PROBE = 16
"""Every this many chances a held step is tried whatever the odds, so that the odds can recover."""

MAX_LEFT_OUT = 2
"""Edges whose block is outside the held pattern that are left out of the factorised matrix and put
back as low-rank terms (:mod:`posegraph.incremental.held_factor`) before a new analysis is made."""

MAX_COLUMNS = 240
"""Scalar columns of low-rank terms (edges and vertices added since the last numeric factorisation,
left-out edges) past which a step refactorises instead: each held step costs products of size
``|R| × q`` and a ``q × q`` solve, which grow past one factorisation's cost (measured, docs/incremental.md)."""

BREAK_EVEN = 0.5
"""A held step's dense work (the ``q × q`` system of its terms, the path products) at most this share of
one numeric factorisation's floating-point operations; past it the step refactorises."""

RELINEARISE = 8
"""Old edges (in the held factor) re-linearised at each held step as low-rank pairs (+new, −old blocks):
those whose residual moved most since the factorisation."""

DRIFT = 1e-3
"""Residual change ``‖Δe‖`` below which an old edge is not worth re-linearising."""


def _off_keys(pattern) -> tuple[np.ndarray, np.ndarray]:
    """``(keys, first)``: sorted ``col·p + row`` of the stored off-diagonal blocks (``(k,)``) and, per
    block column, the index of its first off-diagonal block in ``keys`` (``(p,)``)."""
    p = pattern.num_variables
    per_column = np.diff(pattern.block_indptr).astype(np.int64) - 1  # the diagonal block comes first
    column = np.repeat(np.arange(p, dtype=np.int64), np.diff(pattern.block_indptr))
    first_slot = np.zeros(pattern.block_indices.shape[0], dtype=bool)
    first_slot[pattern.block_indptr[:-1]] = True
    keys = column[~first_slot] * p + pattern.block_indices[~first_slot].astype(np.int64)
    return keys, np.concatenate(([0], np.cumsum(per_column)))[:-1]


def edge_positions(pattern, keys, first, ci: np.ndarray, cj: np.ndarray):
    """Where the entries of edges joining variables ``ci``, ``cj`` ``(m,)`` (−1: held) go.

    Returns ``(hessian (m, 3, d²), gradient (m, 2, d), found (m,) bool)``: the position in the lower-CSC
    ``data`` of each entry (row-major) of ``H_ii, H_jj, H_ij``, ``nnz`` where not stored (upper halves of
    diagonal blocks, held variables); the rows of ``g_i, g_j``, ``dimension`` for held variables; and
    whether the edge's off-diagonal block is in the pattern (edges at a held vertex have none).
    ``H_ij`` is stored at block (``ci``, ``cj``) when ``ci > cj``, else transposed at (``cj``, ``ci``).
    """
    d, nnz, p = pattern.block_size, pattern.nnz, pattern.num_variables
    indptr = pattern.indptr.astype(np.int64)
    a, b = np.repeat(np.arange(d), d), np.tile(np.arange(d), d)

    def diagonal(c):
        at = indptr[d * np.maximum(c, 0)[:, None] + b] + (a - b)
        return np.where((c >= 0)[:, None] & (a >= b), at, nnz)

    both = (ci >= 0) & (cj >= 0)
    lo, hi = np.minimum(ci, cj), np.maximum(ci, cj)
    key = np.where(both, lo * p + hi, -1)
    slot = np.minimum(np.searchsorted(keys, key), max(keys.shape[0] - 1, 0))
    found = ~both | ((keys.shape[0] > 0) & (keys[slot] == key) if keys.shape[0] else ~both)
    rank = slot - first[np.maximum(lo, 0)]
    as_is = (ci > cj)[:, None]
    row, col = np.where(as_is, a, b), np.where(as_is, b, a)  # entry of the stored block
    off = indptr[d * np.maximum(lo, 0)[:, None] + col] + (d - col) + d * rank[:, None] + row
    off = np.where((both & found)[:, None], off, nnz)
    rows = lambda c: np.where((c >= 0)[:, None], d * c[:, None] + np.arange(d), pattern.dimension)  # noqa: E731
    hessian = np.stack([diagonal(ci), diagonal(cj), off], axis=1)
    return hessian, np.stack([rows(ci), rows(cj)], axis=1), found


def _predicted(edge_from: np.ndarray, edge_to: np.ndarray, n: int, capacity: int, recent: np.ndarray):
    """``(from, to)`` of the blocks an analysis adds ahead: the chain ``(v, v+1)`` from vertex ``n−1`` to
    the capacity, and the cone ``(lo + t, hi + s)`` of each loop closure ``recent`` (edge positions), in range."""
    chain = np.arange(max(n - 1, 0), capacity - 1, dtype=np.int64)
    lo = np.minimum(edge_from[recent], edge_to[recent])
    hi = np.maximum(edge_from[recent], edge_to[recent])
    loops = hi - lo > 1
    # a re-traversal advances the older end at its own pace, either way: a cone of blocks ahead
    s = np.repeat(np.arange(1, PREDICT + 1), 4 * np.arange(1, PREDICT + 1) + 5)
    t = np.concatenate([np.arange(-(k + 2), 3 * k + 3) for k in range(1, PREDICT + 1)])
    lo, hi = lo[loops, None], hi[loops, None]
    a, b = (lo + t).ravel(), (hi + s).ravel()
    keep = (a >= 0) & (b < capacity) & (a != b)
    return np.concatenate([chain, a[keep]]), np.concatenate([chain + 1, b[keep]])


def _prior_changes(blocks, then, variable: np.ndarray) -> list:
    """The priors' ``H(now) − H(then)`` as parts of :func:`~posegraph.incremental.held_factor.edge_terms`
    (a prior is a diagonal block on its vertex: ``H_ii`` alone); none without priors or a kept linearisation."""
    if blocks.priors is None or then is None or then.priors is None:
        return []
    column = variable[blocks.priors.vertex]
    zeros, alone = np.zeros_like(blocks.priors.hessian), np.full(column.shape, -1)
    return [(blocks.priors.hessian, zeros, zeros, column, alone), (-then.priors.hessian, zeros, zeros, column, alone)]


class WholeGraph:
    """The held analysis of the whole graph's normal equations and Gauss-Newton on it (module docstring).

    ``store`` is the optimiser's :class:`~posegraph.incremental.store.GraphStore`; ``held`` ``(n,)`` bool
    the vertices held (FIX, anchors). :meth:`reset` drops everything (after edges are removed).
    """

    max_left_out = MAX_LEFT_OUT
    """Edges left out of H (low-rank terms) before an analysis (0: every missing block re-analyses)."""

    max_columns = MAX_COLUMNS
    """Columns of low-rank terms the held factor takes before a step refactorises (0: every step does)."""

    relinearise = RELINEARISE
    """Old edges re-linearised as low-rank pairs at each held step (0: none)."""

    def __init__(self, store, loss=None, landmarks=None):
        from posegraph.incremental.store import Rows

        self.store, self.loss = store, loss
        d = store.group.dim
        self.points = None if landmarks is None else HeldPoints(landmarks, d)  # the landmarks' side of the analysis
        self.hessian_at = Rows((3, d * d), np.int64)  # per edge, store order
        self.gradient_at = Rows((2, d), np.int64)
        self.pattern = self.factor = self.held_factor = None
        self.left_out = np.zeros(0, dtype=np.int64)  # edges (store order) whose H_ij is outside the pattern
        self.held = np.zeros(0, dtype=bool)
        self.last = LastPoint()
        self.covariance_wanted = False  # a covariance was asked since the last solve (set by the optimiser)
        self.current: tuple[int, int] | None = None  # (factorisations, vertices) of a factor at the solve's end
        self.analyses = self.factorizations = self.corrections = self.chord_chances = self.held_steps = 0
        self.chord_odds = 1.0  # moving share of held steps that lowered the cost
        self.decrement = np.inf  # ½ gᵀH⁻¹g at the end of the last solve that met its tolerance
        self.unary_cost = 0.0  # the priors' and landmark measurements' cost at the end of the last solve (_terms)

    def reset(self) -> None:
        self.pattern = self.factor = self.held_factor = None
        self.hessian_at.n = self.gradient_at.n = 0
        self.left_out = np.zeros(0, dtype=np.int64)
        self.last.clear()
        self.current = None
        if self.points is not None:
            self.points.reset()

    def _ready(self, held: np.ndarray) -> bool:
        """Scatter positions for every edge; False when the analysis no longer covers the graph: the
        capacity or the held set changed, or more than MAX_LEFT_OUT edges would have their block outside
        the pattern (those are left out of H: low-rank terms, :mod:`~posegraph.incremental.held_factor`)."""
        store, n = self.store, self.store.num_vertices
        if self.pattern is None or n > self.pattern.num_vertices or not np.array_equal(held, self.held[:n]):
            return False
        if self.points is not None and not (self.points.covered() and self.points.place(self.pattern, self.keys)):
            return False
        done, m = self.hessian_at.n, store.num_edges
        if done < m:
            variable = self.pattern.variable_of
            ci, cj = variable[store.edge_from.view[done:]], variable[store.edge_to.view[done:]]
            hessian, gradient, found = edge_positions(self.pattern, self.keys, self.first, ci, cj)
            left_out = np.concatenate([self.left_out, done + np.flatnonzero(~found)])
            if left_out.shape[0] > self.max_left_out:
                return False
            self.left_out = left_out
            hessian[~found] = self.pattern.nnz  # left out of H entirely: low-rank terms add them back
            self.hessian_at.extend(hessian)
            self.gradient_at.extend(gradient)
        return True

    def _analyse(self, held: np.ndarray) -> None:
        """Pattern and symbolic factorisation for a capacity ×GROWTH the vertex count (module docstring)."""
        store, n, d = self.store, self.store.num_vertices, self.store.group.dim
        capacity = max(int(GROWTH * n) + 1, n + 64)
        i, j = store.edge_from.view, store.edge_to.view
        recent = np.arange(self.hessian_at.n if self.pattern is not None else 0, store.num_edges)
        recent = recent[np.abs(i[recent] - j[recent]) > 1][-PREDICTED_LOOPS:]
        recent = np.concatenate([self.left_out, recent]) if self.pattern is not None else recent
        pi, pj = _predicted(i, j, n, capacity, recent)
        self.held = np.zeros(capacity, dtype=bool)
        self.held[:n] = held
        points = None if self.points is None else self.points.variables(n, capacity)
        self.pattern = pattern = analyze_pattern(capacity, np.concatenate([i, pi]), np.concatenate([j, pj]), self.held, d,
                                                 points=points, positions=False)
        self.keys, self.first = _off_keys(pattern)
        if points is not None:
            self.points.place(pattern, self.keys)
        self.held_factor = None
        self.factor = SparseCholesky(pattern.indptr, pattern.indices, pattern.dimension, permutation=self._order(pattern))
        variable = pattern.variable_of
        hessian, gradient, _ = edge_positions(pattern, self.keys, self.first, variable[i], variable[j])
        self.hessian_at.n = self.gradient_at.n = 0
        self.hessian_at.extend(hessian)
        self.gradient_at.extend(gradient)
        self.left_out = np.zeros(0, dtype=np.int64)
        self.analyses += 1

    def _order(self, pattern) -> np.ndarray:
        """``(D,)`` elimination order for a new analysis: AMD of the vertex graph (``p`` nodes: d² times fewer
        entries than the scalar pattern, the same order of the blocks), expanded to the blocks. A few new
        blocks at the same capacity leave the last order good, so it is kept, and recomputed with the
        capacity, the held set, or every REORDER analyses."""
        factor = self.factor
        if factor is not None and factor.n == pattern.dimension and self.analyses % REORDER and factor._factorized:
            return factor.permutation
        order = fill_reducing_order(pattern.block_indptr, pattern.block_indices, pattern.num_variables, "amd")
        return block_permutation(order, pattern.sizes if pattern.point_size else pattern.block_size)  # (points: two sizes)

    def _factorize(self, data: np.ndarray, n: int, weighted: bool, blocks) -> None:
        """Numeric factorisation of ``data`` (H without the left-out edges and measurements) held for the
        next steps (:class:`~posegraph.incremental.held_factor.HeldFactor`); raises NotPositiveDefiniteError."""
        self.held_factor = None
        self.factor.factorize(data)
        self.held_factor = HeldFactor(self.factor, n, self.store.num_edges, self._prior_count(), weighted, blocks)
        if self.pattern.point_size:
            self.points.factored(self.pattern)

    def _prior_count(self) -> int:
        priors = self.store.priors()
        return 0 if priors is None else len(priors)

    def _low_rank(self, blocks, n: int) -> LowRankTerms:
        """The terms ``H − H0`` of the held factor at the linearisation ``blocks``: the Hessian blocks of
        the edges added since it was made and of the left-out edges, minus the unit diagonal of the
        vertices added since (decoupled in ``H0``), the change of the RELINEARISE old edges whose
        residual moved most since (:meth:`_drifted`) and of every prior (few; their blocks move with the pose)."""
        held, store = self.held_factor, self.store
        extra = np.union1d(self.left_out, np.arange(held.edges, store.num_edges))
        variable = self.pattern.variable_of
        ends = lambda e: (variable[store.edge_from.view[e]], variable[store.edge_to.view[e]])  # noqa: E731
        parts = [(*blocks.hessian_slice(extra), *ends(extra))]
        old = self._drifted(blocks)
        if old.shape[0]:
            parts.append((*blocks.hessian_slice(old), *ends(old)))
            parts.append((*(-h for h in held.blocks.hessian_slice(old)), *ends(old)))
        parts += _prior_changes(blocks, held.blocks, variable)
        new = variable[held.vertices : n]
        self.corrections += self._leaves_out()  # steps with left-out edges or measurements among the terms
        terms = edge_terms(parts, self.pattern.block_size, new[new >= 0])
        return self.points.terms(self.pattern, terms, blocks.landmarks) if self.pattern.point_size else terms

    def _drifted(self, blocks) -> np.ndarray:
        """Up to ``relinearise`` edges in H0 (store order) whose residual moved most since it was made
        (by ``‖Δe‖``, at least DRIFT): their blocks are replaced by the current ones as low-rank terms."""
        held = self.held_factor
        if not self.relinearise or held.blocks is None or held.edges == 0:
            return np.zeros(0, dtype=np.int64)
        moved = np.linalg.norm(blocks.residuals[: held.edges] - held.blocks.residuals[: held.edges], axis=1)
        moved[self.left_out[self.left_out < held.edges]] = 0.0
        count = min(self.relinearise, held.edges)
        top = np.argpartition(moved, -count)[-count:]
        return np.sort(top[moved[top] > DRIFT])

    def _held_terms(self, blocks, n: int) -> LowRankTerms | None:
        """The low-rank terms when the held factor can take this step; None when a refactorisation is
        due: no factor, priors added since, a factor without the loss weights a loss needs, more than
        ``max_columns`` columns of terms, or terms whose dense work passes BREAK_EVEN of a factorisation's."""
        held = self.held_factor
        if held is None or held.priors != self._prior_count() or (self.loss is not None and not held.weighted):
            return None
        if self.pattern.block_size * (n - held.vertices) > self.max_columns:
            return None  # more columns than allowed for sure (a long odometry run): not worth building them
        terms = self._low_rank(blocks, n)
        count = terms.columns.shape[0]
        return terms if count <= self.max_columns and held.affordable(count, BREAK_EVEN) else None

    def _system_at(self, blocks, held: np.ndarray, n: int, refactor: bool):
        """``(half, made_here)`` for a step at ``blocks``: the forward half (:meth:`HeldFactor.forward`) on
        the held factor with its low-rank terms unless ``refactor`` or it cannot serve (:meth:`_held_terms`,
        or the held system with its terms is singular: a point seen by a lone bearing), else on a fresh
        factorisation (``made_here``); ``half`` None when H is not positive definite."""
        if not refactor:
            terms = self._held_terms(blocks, n)
            if terms is not None:
                try:
                    return self.held_factor.forward(self._system(blocks, n, False)[1], terms), False
                except np.linalg.LinAlgError:
                    pass
        g = self._fresh(blocks, held, n)
        return None if g is None else self.held_factor.forward(g, self.held_factor.terms), True

    def _fresh(self, blocks, held: np.ndarray, n: int, weighted: bool = True) -> np.ndarray | None:
        """H assembled and factorised at ``blocks``, held with its terms at ``blocks`` (the left-out
        edges' and measurements'); the gradient ``g`` ``(D,)``, or None when H is not positive definite. H
        without the left-out terms may be singular (a vertex joined only by them): then every edge and
        measurement goes in the pattern (a new analysis) and the factorisation is tried again."""
        for attempt in range(2):
            data, g = self._system(blocks, n, True)
            try:
                self._factorize(data, n, weighted, blocks)
            except NotPositiveDefiniteError:
                if attempt or not self._leaves_out():
                    return None
                self._analyse(held)
                continue
            self.factorizations += 1
            self.held_factor.terms = self._low_rank(blocks, n)
            return g
        return None

    def _leaves_out(self) -> bool:
        """Whether edges or landmark measurements are left out of the factorised matrix."""
        return bool(self.left_out.shape[0]) or (self.points is not None and self.points.left_out_count() > 0)

    def _solve_full(self, rhs: np.ndarray) -> np.ndarray:
        """``H̃⁻¹ rhs`` ``(D,)`` or ``(D, r)``: the held factor with the low-rank terms it last solved with."""
        return self.held_factor.solve(rhs)

    def _system(self, blocks, n: int, hessian: bool):
        """``(data (nnz,) or None, g (D,))`` of the whole graph from the per-edge ``blocks``; the rows of
        vertices not yet added (``≥ n``) decoupled: unit diagonal, zero gradient (they have no edges)."""
        pattern = self.pattern
        size = pattern.dimension
        g = np.bincount(self.gradient_at.view.ravel(), weights=blocks.gradient.ravel(), minlength=size + 1)[:size].astype(np.float64, copy=False)  # no edges: int zeros
        if blocks.priors is not None:
            add_prior_gradient(pattern, g, blocks.priors)
        if not hessian:
            if blocks.landmarks is not None:
                self.points.add(pattern, g, None, blocks.landmarks)
            return None, g
        values = np.stack(blocks.hessian_blocks, axis=1)  # (m, 3, d, d), as hessian_at
        data = np.bincount(self.hessian_at.view.ravel(), weights=values.ravel(), minlength=pattern.nnz + 1).astype(np.float64, copy=False)
        if blocks.priors is not None:
            add_prior_hessian(pattern, data, blocks.priors)
        future = pattern.variable_of[n:]
        rows = (pattern.block_size * future[future >= 0][:, None] + np.arange(pattern.block_size)).ravel()
        if pattern.point_size:
            self.points.add(pattern, g, data, blocks.landmarks)
            rows = np.concatenate([rows, self.points.decoupled_rows(pattern)])
        data[pattern.diagonal[rows]] = 1.0
        return data[: pattern.nnz], g

    def _objective(self, held: np.ndarray) -> Objective:
        """The solver's objective on the whole graph so far (views of the store, no copies)."""
        s = self.store
        landmarks = None if self.points is None else self.points.store.landmarks()
        graph = PoseGraph(ids=s.ids.view, poses=s.poses.view, edge_from=s.edge_from.view, edge_to=s.edge_to.view,
                          measurements=s.measurements.view, information=s.information.view, fixed=held,
                          group=s.group, priors=s.priors(), landmarks=landmarks)
        return Objective(graph, self.loss)

    def _state(self) -> tuple:
        """Copies of the poses ``(n, k, k)`` and the landmarks' points ``(L, s)`` (None without)."""
        points = self._points()
        return self.store.poses.view.copy(), None if points is None else points.copy()

    def _points(self) -> np.ndarray | None:
        """The landmarks' points ``(L, s)`` (the store's rows, live), None without landmarks."""
        return None if self.points is None or not self.points.store.count else self.points.store.positions.view

    def _restore(self, state: tuple) -> None:
        self.store.poses.view[:] = state[0]
        if state[1] is not None:
            self._points()[:] = state[1]

    def _move(self, state: tuple, step: np.ndarray, scale: float) -> None:
        """Poses and points at ``state`` moved by ``scale`` times the step ``(D,)``: ``X exp(δ)``, ``p + δ``."""
        poses, points = state
        self.store.poses.view[:] = poses @ self.store.group.exp(scale * self.pattern.expand(step)[: poses.shape[0]])
        if points is not None:
            self._points()[:] = points + scale * self.pattern.expand_points(step)[: points.shape[0]]

    def _evaluate(self, objective: Objective):
        return objective.evaluate(self.store.poses.view, self._points())

    def solve(self, held: np.ndarray, tolerance: float, max_iterations: int = 30,
              predicted_stop: bool = False) -> tuple[bool, int, np.ndarray]:
        """Gauss-Newton on the whole graph, in place on the store's poses, until ``½ gᵀH⁻¹g ≤ tolerance · cost``.

        ``predicted_stop`` (loose tolerances): also stop after a step that lowered the cost by its decrement
        ``λ = ½ gᵀH̃⁻¹g`` to within ``tolerance · cost`` (``|λ − Δf|``, the excess left to second order when
        ``H̃`` models the cost), without the check step's linearisation and solve.

        Returns ``(ok, iterations, terms (m,))`` with ``terms`` each edge's ``eᵀΩe`` (``ρ`` of it with a
        loss) at the final poses. ``ok`` False: a fresh step raised the cost or H was not positive
        definite (the poses are then as before the call), or ``max_iterations`` steps did not reach the
        tolerance (the poses are then where they led, the cost lower than before: a start for the batch solver).
        """
        if not self._ready(held):
            self._analyse(held)
        n, d = self.store.num_vertices, self.store.group.dim
        objective, poses = self._objective(held), self.store.poses.view
        saved = self._state()
        start = self.last.extended(objective, poses, self._points())  # the last solve's final linearisation, new terms added
        evaluation, blocks = start if start is not None else (self._evaluate(objective), None)
        self.last.clear()
        self.current, self.decrement = None, np.inf
        refactor, previous = False, np.inf
        for iteration in range(1, max_iterations + 1):
            if blocks is None:
                blocks = objective.linearize(poses, evaluation)
            half, made_here = self._system_at(blocks, held, n, refactor)
            if half is None:
                self._restore(saved)
                return False, iteration, np.zeros(0)
            decrement = half.decrement
            if 0 <= decrement <= tolerance * evaluation.cost + 1e-300:
                self.decrement = decrement
                self.last.keep(poses, evaluation, blocks)
                self._end_factored(made_here, blocks, held, n)
                break  # the current point is within tolerance of the optimum: no step, no evaluation
            if not made_here and (decrement > CHORD_RATE * previous or not self._chord_pays()):
                refactor = True  # the held system is off here, or its steps keep failing: refactorise at this point
                continue
            outcome, trial = self._take_step(objective, half, made_here, evaluation.cost, n)
            if outcome == "refactor":
                refactor = True  # the held step raised the cost: refactorise at this point (its blocks as they are)
                continue
            if trial is None:
                self._restore(saved)
                return False, iteration, np.zeros(0)
            if outcome == "backtracked":
                refactor, previous, evaluation, blocks = True, np.inf, trial, None  # far from the optimum still
                continue
            left = abs(decrement - (evaluation.cost - trial.cost))  # the excess left, to second order
            refactor, previous, evaluation, blocks = False, decrement, trial, None
            if predicted_stop and left <= tolerance * evaluation.cost:
                self.decrement = left
                self.last.keep(poses, evaluation, None)
                break  # the step did what the model said: within tolerance without the check step
        else:
            return False, iteration, np.zeros(0)  # not within the tolerance yet
        return True, iteration, self._terms(evaluation)

    def _take_step(self, objective: Objective, half, made_here: bool, cost: float, n: int):
        """The step ``−H̃⁻¹g`` (the backward half of ``half``) applied to the store's poses; ``(outcome,
        trial)``: ``"taken"`` and the evaluation at the new poses when the cost did not rise; ``"refactor"``
        (poses restored) when a held step raised it; ``"backtracked"`` when a step on a factor made here did,
        with the evaluation of the halved step that lowered the cost (:meth:`_backtrack`; None, poses
        restored, when none did)."""
        step = -self.held_factor.backward(half)
        self.held_steps += not made_here
        before = self._state()
        self._move(before, step, 1.0)
        trial = self._evaluate(objective) if half.decrement > 0 else None
        if trial is not None and trial.cost <= cost * (1 + 1e-12):
            if not made_here:
                self._chord_outcome(True)
            return "taken", trial
        self._restore(before)
        if not made_here:
            self._chord_outcome(False)
            return "refactor", None
        return "backtracked", self._backtrack(objective, before, step, n, cost)

    def _end_factored(self, fresh: bool, blocks, held: np.ndarray, n: int) -> None:
        """When a covariance was asked since the last solve (``covariance_wanted``: a front end asking
        after every update) and without a loss, a solve ends holding a factor of H at its final poses
        (refactorised there after a held step), marked in ``current``: the covariances after the update
        are then forward solves on it (:mod:`posegraph.incremental.covariance`), and the factorisation
        they need is made here, where the linearisation at those poses is at hand. With a loss, the
        solve's H carries IRLS weights that the covariance convention leaves out."""
        wanted, self.covariance_wanted = self.covariance_wanted, False
        if not wanted or self.loss is not None or self._points() is not None:
            return
        if fresh or self._fresh(blocks, held, n) is not None:
            self.held_factor.cover(self.held_factor.terms.columns)  # the left-out edges' path solves here, not in the call
            self.current = (self.factorizations, n)

    def _chord_pays(self) -> bool:
        """Whether to try the held step now (CHORD_ODDS, PROBE)."""
        self.chord_chances += 1
        return self.chord_odds >= CHORD_ODDS or self.chord_chances % PROBE == 0

    def _chord_outcome(self, accepted: bool) -> None:
        self.chord_odds += (float(accepted) - self.chord_odds) / 8

    def _backtrack(self, objective: Objective, before: tuple, step: np.ndarray, n: int, cost: float):
        """A fresh Gauss-Newton step overshot (a large loop closure far from the linearisation): the
        step halved up to BACKTRACK times, the first that lowers the cost kept (its evaluation), else
        None with the poses as ``before``. Cheaper than handing the graph to the damped batch solver."""
        for halving in range(1, BACKTRACK + 1):
            self._move(before, step, 0.5**halving)
            trial = self._evaluate(objective)
            if trial.cost < cost:
                return trial
        self._restore(before)
        return None

    def _terms(self, evaluation) -> np.ndarray:
        """Each edge's ``eᵀΩe`` (``ρ`` of it) at ``evaluation``, from the ``Ω e`` it holds; the rest of its
        cost (priors, landmark measurements) kept in ``unary_cost``, which spares the optimiser evaluating them again."""
        s = np.einsum("mi,mi->m", evaluation.residuals, evaluation.weighted_residuals)
        terms = s if self.loss is None else self.loss.rho(s)
        self.unary_cost = max(evaluation.cost - 0.5 * float(np.sum(terms)), 0.0)
        return terms

    def factorize_unweighted(self, held: np.ndarray) -> None:
        """Factorise H at the current poses on the held analysis, without loss weights and priors
        included (the convention of :mod:`posegraph.analysis.covariance`), for
        :mod:`posegraph.incremental.covariance`; :meth:`_solve_full` then applies ``H⁻¹`` (the left-out
        edges' correction included). The last solve's final linearisation is reused when it is of these
        poses (no priors: :class:`~posegraph.incremental.reuse.LastPoint`), its IRLS weights dropped (the
        Jacobians do not depend on the loss). Raises NotPositiveDefiniteError."""
        if not self._ready(held):
            self._analyse(held)
        objective, poses = self._objective(held), self.store.poses.view
        kept = self.last.extended(objective, poses)
        if kept is not None and kept[1] is not None:  # without a loss its Hessian blocks may be made already
            blocks = kept[1] if kept[1].weights is None else replace(kept[1], weights=None)
        else:
            objective = Objective(objective.graph, None)
            blocks = objective.linearize(poses, objective.evaluate(poses))
        n = self.store.num_vertices
        if self._fresh(blocks, held, n, weighted=self.loss is None) is None:
            raise NotPositiveDefiniteError("the Hessian at the estimate is not positive definite")
