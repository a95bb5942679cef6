"""The part of the graph an update moves, and Gauss-Newton on it with everything else held.

:class:`Region` grows by breadth-first rings from the vertices an update touched (the ends of its
loop closures, vertices given priors, the ends of removed edges), never through a held vertex (FIX,
an anchor): those cannot move, and nothing moves through them. :func:`solve_region` runs undamped
Gauss-Newton on the region's free vertices, every edge incident to them linearised and the vertices
beyond held at their estimate, until the Newton decrement ``½ gᵀH⁻¹g`` of the region is below a
tolerance. The normal equations of the region are dense up to :data:`DENSE_LIMIT` unknowns (one
LAPACK Cholesky, no symbolic work), else sparse through CHOLMOD (:class:`posegraph.linalg.cholmod.SparseCholesky`,
AMD, analysed once per region); the batch solver on the region's subgraph (:func:`solve_subgraph`:
:func:`posegraph.solve.optimize`, damped) takes over when undamped Gauss-Newton fails.

All arithmetic of the residuals and their Jacobians is the solver's own
(:class:`posegraph.solve.objective.Objective`: edges, priors, robust loss weights); only the assembly
of a small system is here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.solve.objective import Objective

__all__ = ["Region", "RegionSolve", "solve_region", "solve_subgraph", "DENSE_LIMIT", "SPARSE_LIMIT"]

DENSE_LIMIT = 96
"""Unknowns up to which a region's normal equations are a dense matrix (32 SE(2) / 16 SE(3) poses); sparse above."""

SPARSE_LIMIT = 60000
"""Unknowns above which a region goes to the batch solver (:func:`solve_subgraph`)."""


class Region:
    """Free vertices within ``radius`` rings of the seeds (breadth first, stopping at held vertices)."""

    def __init__(self, adjacency, edge_from, edge_to, held, seeds):
        self.adjacency, self.edge_from, self.edge_to, self.held = adjacency, edge_from, edge_to, held
        self.vertices: list[int] = list(dict.fromkeys(int(s) for s in seeds if not held[s]))
        self.seen = set(self.vertices)
        self.frontier = list(self.vertices)
        self.radius = 0

    @property
    def exhausted(self) -> bool:
        """True when no free vertex is left beyond the region (it is its whole part of the graph)."""
        return not self.frontier

    def grow(self, radius: int) -> None:
        """Add the rings up to ``radius``; :attr:`frontier` becomes the outermost ring added."""
        adjacency, edge_from, edge_to, held, seen = self.adjacency, self.edge_from, self.edge_to, self.held, self.seen
        while self.radius < radius and self.frontier:
            ring = []
            for v in self.frontier:
                for e in adjacency[v]:
                    w = edge_from[e] if edge_to[e] == v else edge_to[e]
                    if w not in seen:
                        seen.add(w)
                        if not held[w]:
                            ring.append(w)
            self.radius += 1
            if not ring:
                self.frontier = []
                break
            self.vertices.extend(ring)
            self.frontier = ring

    def edges(self) -> np.ndarray:
        """Positions of every edge incident to a region vertex, sorted."""
        adjacency = self.adjacency
        found = set()
        for v in self.vertices:
            found.update(adjacency[v])
        return np.fromiter(sorted(found), dtype=np.int64, count=len(found))


@dataclass
class RegionSolve:
    """The outcome of :func:`solve_region`."""

    iterations: int
    decrement: float
    """The last Newton decrement ``½ gᵀH⁻¹g`` of the region (the step it belongs to was taken)."""
    moved: np.ndarray
    """``(p,)`` ``Δᵀ H_vv Δ`` of each region vertex's total step Δ (its whitened squared move)."""
    cost_before: float
    """The region's cost (its edges and priors) before the solve."""
    ok: bool
    """False when a step raised the cost or the system was not positive definite (poses restored)."""


def _assemble(blocks, li, lj, prior_local, p: int, d: int):
    """The region's normal equations: lower block triplets ``(rows, cols, (q, d, d) blocks)``, ``g``
    ``(p·d,)`` and the diagonal blocks ``(p, d, d)``."""
    h_ii, h_jj, h_ij = blocks.hessian_blocks
    a, b = li >= 0, lj >= 0
    ab = a & b
    diagonal = np.zeros((p, d, d))
    np.add.at(diagonal, li[a], h_ii[a])
    np.add.at(diagonal, lj[b], h_jj[b])
    g = np.zeros((p, d))
    np.add.at(g, li[a], blocks.gradient[a, 0])
    np.add.at(g, lj[b], blocks.gradient[b, 1])
    if blocks.priors is not None:
        np.add.at(diagonal, prior_local, blocks.priors.hessian)
        np.add.at(g, prior_local, blocks.priors.gradient)
    i, j, off = li[ab], lj[ab], h_ij[ab]
    swap = i < j  # keep block (row ≥ column): H_ji = H_ijᵀ
    off = np.where(swap[:, None, None], np.swapaxes(off, 1, 2), off)
    rows, cols = np.where(swap, j, i), np.where(swap, i, j)
    return (rows, cols, off), g.reshape(-1), diagonal


def _dense_solve(triplets, diagonal: np.ndarray, g: np.ndarray, cache: dict) -> np.ndarray:
    from scipy.linalg import cho_factor, cho_solve

    p, d = diagonal.shape[0], diagonal.shape[1]
    rows, cols, off = triplets
    H = np.zeros((p, p, d, d))
    H[np.arange(p), np.arange(p)] = diagonal
    np.add.at(H, (rows, cols), off)
    H = H.transpose(0, 2, 1, 3).reshape(p * d, p * d)
    return cho_solve(cho_factor(H, lower=True, check_finite=False), g, check_finite=False)


def _sparse_solve(triplets, diagonal: np.ndarray, g: np.ndarray, cache: dict) -> np.ndarray:
    """CHOLMOD on the lower triangle (AMD, analysed at the region's first iteration); SuperLU without cvxopt."""
    import scipy.sparse as sp

    from posegraph.linalg import cholmod

    p, d = diagonal.shape[0], diagonal.shape[1]
    rows, cols, off = triplets
    br = np.concatenate([np.arange(p), rows])
    bc = np.concatenate([np.arange(p), cols])
    values = np.concatenate([diagonal, off])
    r = (br[:, None, None] * d + np.arange(d)[None, :, None]) + np.zeros((1, 1, d), np.int64)
    c = (bc[:, None, None] * d + np.arange(d)[None, None, :]) + np.zeros((1, d, 1), np.int64)
    keep = r >= c
    lower = sp.csc_matrix((values[keep], (r[keep], c[keep])), shape=(p * d, p * d))
    if cholmod.load() is None:
        full = lower + sp.tril(lower, -1).T
        from scipy.sparse.linalg import spsolve

        return spsolve(full.tocsc(), g)
    factor = cache.get("cholesky")
    if factor is None or factor.nnz != lower.nnz:
        factor = cache["cholesky"] = cholmod.SparseCholesky(lower.indptr, lower.indices, p * d, "amd")
    factor.factorize(lower.data)
    return factor.solve(g)


def _region_graph(store, vertices: np.ndarray, edges: np.ndarray, held) -> tuple[PoseGraph, np.ndarray, np.ndarray, np.ndarray]:
    """The region's edges (and priors) as a :class:`PoseGraph` over the global poses, and local indices."""
    n = store.num_vertices
    local = np.full(n, -1, dtype=np.int64)
    local[vertices] = np.arange(vertices.shape[0])
    i, j = store.edge_from.view[edges], store.edge_to.view[edges]
    mask = np.zeros(n, dtype=bool)
    mask[vertices] = True
    priors = store.priors(mask)
    graph = PoseGraph(
        ids=store.ids.view, poses=store.poses.view, edge_from=i, edge_to=j,
        measurements=store.measurements.view[edges], information=store.information.view[edges],
        fixed=held, group=store.group, priors=priors,
    )  # fmt: skip
    prior_local = None
    if priors is not None:
        prior_local = local[np.concatenate([priors.pose_vertex, priors.position_vertex])]
    return graph, local[i], local[j], prior_local


def solve_region(store, vertices: np.ndarray, edges: np.ndarray, held, loss, tolerance: float, max_iterations: int = 20) -> RegionSolve:
    """Gauss-Newton on ``vertices`` (free, global indices) over ``edges``, in place on ``store.poses``.

    Stops when the Newton decrement of the region is at most ``tolerance`` (that last step taken).
    A step that raises the region's cost, or an H that is not positive definite, restores the poses
    and returns ``ok=False`` (the caller then runs the damped solver).
    """
    graph, li, lj, prior_local = _region_graph(store, vertices, edges, held)
    objective = Objective(graph, loss)
    poses, group, p, d = store.poses.view, store.group, vertices.shape[0], store.group.dim
    saved = poses[vertices].copy()
    total = np.zeros((p, d))
    evaluation = objective.evaluate(poses)
    cost_before = previous = evaluation.cost
    decrement, diagonal, cache = np.inf, None, {}
    solver = _dense_solve if p * d <= DENSE_LIMIT else _sparse_solve
    for iteration in range(1, max_iterations + 1):
        triplets, g, diagonal = _assemble(objective.linearize(poses, evaluation), li, lj, prior_local, p, d)
        try:
            step = -solver(triplets, diagonal, g, cache).reshape(p, d)
        except (np.linalg.LinAlgError, ArithmeticError, ValueError):
            poses[vertices] = saved
            return RegionSolve(iteration, np.inf, np.zeros(p), cost_before, False)
        decrement = -0.5 * float(g @ step.reshape(-1))
        poses[vertices] = poses[vertices] @ group.exp(step)
        total += step
        if not np.isfinite(decrement) or decrement <= tolerance:
            break
        evaluation = objective.evaluate(poses)
        if not evaluation.cost <= previous + 1e-12 * max(previous, 1.0):
            poses[vertices] = saved
            return RegionSolve(iteration, decrement, np.zeros(p), cost_before, False)
        previous = evaluation.cost
    moved = np.einsum("pi,pij,pj->p", total, diagonal, total)
    return RegionSolve(iteration, decrement, moved, cost_before, bool(np.isfinite(decrement)))


def solve_subgraph(store, vertices: np.ndarray, edges: np.ndarray, held, params) -> RegionSolve:
    """:func:`posegraph.solve.optimize` (``params``) on the region's subgraph: its vertices free, the
    vertices beyond held (``FIX`` in the subgraph), in place on ``store.poses``."""
    from dataclasses import replace

    from posegraph.solve import optimize

    graph, li, lj, prior_local = _region_graph(store, vertices, edges, held)
    inside = np.unique(np.concatenate([vertices, graph.edge_from, graph.edge_to]))
    local = np.full(store.num_vertices, -1, dtype=np.int64)
    local[inside] = np.arange(inside.shape[0])
    fixed = np.ones(inside.shape[0], dtype=bool)
    fixed[local[vertices]] = False
    priors = None if graph.priors is None else graph.priors.remapped(local)
    sub = replace(graph, ids=store.ids.view[inside], poses=store.poses.view[inside], edge_from=local[graph.edge_from],
                  edge_to=local[graph.edge_to], fixed=fixed, priors=priors)
    objective = Objective(sub, params.loss)
    before = store.poses.view[vertices].copy()
    result = optimize(sub, initial=sub.poses, params=params)
    store.poses.view[vertices] = result.poses[local[vertices]]
    group, p, d = store.group, vertices.shape[0], store.group.dim
    total = group.log(group.between(before, store.poses.view[vertices]))
    evaluation = objective.evaluate(result.poses)
    blocks = objective.linearize(result.poses, evaluation)
    _, _, diagonal = _assemble(blocks, li, lj, prior_local, p, d)
    moved = np.einsum("pi,pij,pj->p", total, diagonal, total)
    decrement = result.records[-1].cost_decrease if result.records else 0.0
    return RegionSolve(result.iterations, decrement, moved, result.initial_cost, result.converged)
