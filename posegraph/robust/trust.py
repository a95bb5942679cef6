"""Which edges robust optimisation trusts, and the check of that trust at its result.

:func:`posegraph.robust.optimize_robust` keeps its known inliers (by default the odometry edges,
:meth:`~posegraph.model.graph.PoseGraph.odometry_mask`) at weight 1 whatever their residual. One wrong
known inlier then bends the whole answer, and the test that rejects wrong loop closures can no
longer see it: the edges that disagree with it are rejected instead. Two guards:

* **Ambiguous pairs** (:func:`parallel_odometry_mask`): two vertices that are neighbours in id
  order but joined by more than one edge (a duplicate, or a false match parallel to the
  odometry). Which of the parallel edges is the odometry cannot be told from the file, so none
  of them is trusted at first; GNC keeps the one the rest of the graph agrees with. Where it
  keeps none (nothing else spans the pair, or too weakly), the one that fits best where the rest
  of the graph put the two vertices is trusted after all (:func:`best_edges_of_unkept_pairs`), so
  the graph does not fall apart there.
* **The check**, at the result: a known inlier whose squared whitened residual ``s = eᵀΩe``
  exceeds the inlier threshold ``c̄²`` would have been rejected had it not been trusted
  (:func:`known_inliers_above`); and a trusted odometry edge that fits exactly because every edge
  spanning it was rejected is contradicted by all of them (:func:`contradicted_odometry`). Such
  edges are released (GNC runs again without trusting them) unless the caller asks for
  strictness, and named either way.

The caller chooses the thresholds: :func:`posegraph.robust.pipeline.optimize_robust` doubts by residual
only above the family-wise χ² quantile over the trusted edges (``pipeline.doubt_thresholds``), since at
``c̄²`` itself ~1 % of right trusted edges lie above it.
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph, neighbour_pairs, vertex_ranks

__all__ = [
    "parallel_odometry_mask", "best_edges_of_unkept_pairs", "contradicted_odometry", "known_inliers_above",
    "truncated_cost", "known_chi2_per_dof",
]


def parallel_odometry_mask(graph: PoseGraph) -> np.ndarray:
    """``(m,)`` bool: the edges between neighbours in id order whose two vertices are joined by
    more than one edge (either way round)."""
    pair = neighbour_pairs(graph)
    neighbours = pair >= 0
    edges_per_pair = np.bincount(pair[neighbours], minlength=max(graph.num_vertices, 1))
    return neighbours & (edges_per_pair[np.maximum(pair, 0)] > 1)


def best_edges_of_unkept_pairs(graph: PoseGraph, parallel: np.ndarray, kept: np.ndarray, squared_residuals: np.ndarray) -> np.ndarray:
    """``(m,)`` bool: for each ambiguous pair (``parallel``, :func:`parallel_odometry_mask`) none of
    whose edges is ``kept`` ``(m,)`` bool, its edge of least ``squared_residuals`` ``(m,)``: the one
    the rest of the graph, placing the two vertices without any of them, agrees with best (ties:
    the first in file order)."""
    pair = neighbour_pairs(graph)
    has_kept = np.zeros(max(graph.num_vertices, 1), dtype=bool)
    has_kept[pair[parallel & kept]] = True
    candidates = np.flatnonzero(parallel & ~has_kept[np.maximum(pair, 0)])
    order = candidates[np.lexsort((candidates, np.asarray(squared_residuals)[candidates], pair[candidates]))]
    first_of_pair = np.r_[True, pair[order][1:] != pair[order][:-1]] if len(order) else np.zeros(0, dtype=bool)
    best = np.zeros(graph.num_edges, dtype=bool)
    best[order[first_of_pair]] = True
    return best


MIN_CONTRADICTING_EDGES = 3
"""A trusted odometry edge is contradicted (:func:`contradicted_odometry`) when at least this many
other edges span it and every one of them was rejected. One or two rejected edges across a stretch
of trajectory are what random wrong loop closures look like where no true one spans it (the end of
a trajectory that never returns); a wrong odometry edge cuts every cycle through it, and GNC then
rejects every edge spanning it (on the 48-vertex grid of the tests: 21 loop closures)."""


def contradicted_odometry(graph: PoseGraph, known: np.ndarray, kept: np.ndarray, minimum: int = MIN_CONTRADICTING_EDGES) -> np.ndarray:
    """``(m,)`` bool: the trusted edges between neighbours in id order (``known`` ``(m,)``) that at
    least ``minimum`` untrusted edges span, none of them ``kept`` ``(m,)`` bool.

    An edge joining ranks ``a < b`` spans the pair ``(p, p + 1)`` when ``a ≤ p < b``: the odometry
    chain from ``a`` to ``b`` runs through it, so the edge closes a cycle with it. A wrong trusted
    odometry edge bends every such cycle, and the inlier test then rejects all of them while the
    trusted edge itself fits exactly: its residual alone cannot tell (:func:`known_inliers_above`).

    Only pairs between two pairs that kept edges span count: a stretch that no kept edge spans out
    to the first or the last vertex is one no true loop closure reaches (a trajectory that never
    returns there), and the random wrong loop closures across it, all rejected, say nothing of its
    odometry. A wrong edge in the middle of the trajectory leaves kept edges on both sides of it.
    """
    rank = vertex_ranks(graph)
    low = np.minimum(rank[graph.edge_from], rank[graph.edge_to])
    high = np.maximum(rank[graph.edge_from], rank[graph.edge_to])
    candidates = ~np.asarray(known, dtype=bool)

    def spanning(mask):  # (n,) edges of ``mask`` spanning each pair (p, p + 1), by a difference array
        steps = np.bincount(low[mask], minlength=graph.num_vertices + 1) - np.bincount(high[mask], minlength=graph.num_vertices + 1)
        return np.cumsum(steps)[: max(graph.num_vertices, 1)]

    total, held = spanning(candidates), spanning(candidates & np.asarray(kept, dtype=bool))
    pair = neighbour_pairs(graph)
    odometry = np.asarray(known, dtype=bool) & (pair >= 0)
    where = np.maximum(pair, 0)
    covered = np.flatnonzero(held[: graph.num_vertices - 1] > 0)
    between_covered = np.zeros(max(graph.num_vertices, 1), dtype=bool)
    if len(covered):
        between_covered[covered[0] : covered[-1] + 1] = True
    return odometry & (total[where] >= minimum) & (held[where] == 0) & between_covered[where]


def known_inliers_above(squared_residuals: np.ndarray, known: np.ndarray, thresholds) -> np.ndarray:
    """``(m,)`` bool: the known inliers whose ``s = eᵀΩe`` exceeds their inlier threshold ``c̄²``
    (a scalar or ``(m,)``): the ones GNC would have rejected had they not been trusted."""
    return np.asarray(known, dtype=bool) & (np.asarray(squared_residuals) > thresholds)


def truncated_cost(squared_residuals: np.ndarray, thresholds) -> float:
    """``½ Σ min(s, c̄²)``: the truncated-least-squares cost with every edge judged alike (none
    trusted), by which two answers to one graph are compared."""
    return 0.5 * float(np.sum(np.minimum(squared_residuals, thresholds)))


def known_chi2_per_dof(squared_residuals: np.ndarray, known: np.ndarray, dimension: int) -> float:
    """``Σ s / (d · count)`` over the known inliers: ≈ 1 when their residuals are as their
    information matrices predict (``E[s] = d`` for a d-dimensional Gaussian residual); NaN for none.

    A per-edge ratio, not χ²/dof of the graph: the known inliers alone (a chain) leave no degree of
    freedom, yet each is measured against the same poses as every other edge."""
    count = int(np.count_nonzero(known))
    return float(np.sum(np.asarray(squared_residuals)[known]) / (dimension * count)) if count else float("nan")
