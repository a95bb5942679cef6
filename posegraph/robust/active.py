"""Weighted least-squares solves over the edges with nonzero weight, analysed once per edge set.

GNC and IRLS solve one graph many times with new per-edge weights ``w`` (cost ``½ Σ w eᵀΩe``).
An edge of weight 0 contributes nothing to that cost, but left in the system its long, random
"loop closure" still fills the Cholesky factor: on sphere2500 with 490 random outliers a chordal
factorisation of all edges took 78 ms, of the edges still weighted ~10 ms. So each solve here
runs on the subgraph of the edges with ``w > 0`` (information scaled by ``w``), and the symbolic
work — the chordal system's pattern and factorisation analysis
(:func:`posegraph.init.chordal.chordal_problem`), the solver's Hessian pattern and linear solver
(:func:`posegraph.solve.analyze`) — is made when that edge set changes and reused while it does
not (in GNC it settles after a few outer iterations: on sphere2500 + 20 % outliers, 12 distinct
edge sets in 24 iterations).

A vertex whose every edge has weight 0 is its own component in the subgraph: it is held at its
pose (the start's, or the file's in the chordal solve) — no edge of positive weight constrains it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.graph import EdgeSource, PoseGraph

__all__ = ["edge_subgraph", "ActiveEdgeSolves"]


def edge_subgraph(graph: PoseGraph, keep: np.ndarray, weights: np.ndarray | None = None) -> PoseGraph:
    """``graph`` with only the edges ``keep`` (indices ``(k,)`` in edge order, with their file line
    numbers ``edge_lines``), their information scaled by ``weights[keep]`` when given. The file's edge lines (``edge_source``) stay with the
    kept edges only when they stated the edges before (checksum) and no weight changed them."""
    keep = np.asarray(keep, dtype=np.int64)
    information = graph.information[keep]
    if weights is not None:
        information = information * np.asarray(weights, dtype=np.float64)[keep, None, None]
    sub = replace(
        graph,
        edge_from=graph.edge_from[keep],
        edge_to=graph.edge_to[keep],
        measurements=graph.measurements[keep],
        information=information,
        edge_source=None,
        edge_lines=None if graph.edge_lines is None else graph.edge_lines[keep],
    )
    source = graph.edge_source
    if weights is None and source is not None and source.matches(graph):
        lines = [source.lines[k] for k in keep.tolist()]
        sub = replace(sub, edge_source=EdgeSource.of(sub, source.format, lines))
    return sub


class ActiveEdgeSolves:
    """Chordal and Levenberg-Marquardt solves of ``graph`` weighted by ``w``, over the edges with ``w > 0``.

    Parameters
    ----------
    graph : PoseGraph
    params : SolverParams, optional
        The Levenberg-Marquardt solves' parameters (its ``linear_solver`` also for the chordal
        solves); ``params.loss`` must be None (the weights are the robust part).
    """

    def __init__(self, graph: PoseGraph, params=None):
        from posegraph.solve import SolverParams

        self.graph = graph
        self.params = SolverParams() if params is None else params
        if self.params.loss is not None:
            raise ValueError("weighted solves take SolverParams with loss=None")
        self._chordal = (None, None)  # (active-edge key, analysed chordal problem)
        self._solver = (None, None)  # (active-edge key, solver Analysis)
        self.analyses = 0
        """Symbolic analyses made (chordal and solver)."""

    def subgraph(self, weights: np.ndarray) -> tuple[bytes, PoseGraph]:
        """``(key, weighted subgraph)`` of the edges with ``weights > 0``; ``key`` names the edge set."""
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != (self.graph.num_edges,):
            raise ValueError(f"weights must have shape ({self.graph.num_edges},), got {weights.shape}")
        if not np.all(np.isfinite(weights) & (weights >= 0)):
            raise ValueError("weights must be finite and >= 0")
        active = weights > 0
        return np.packbits(active).tobytes(), edge_subgraph(self.graph, np.flatnonzero(active), weights)

    def chordal(self, weights: np.ndarray) -> np.ndarray:
        """``(n, 4, 4)`` chordal start of the weighted graph (:func:`posegraph.init.chordal_initialization`)."""
        from posegraph.init.chordal import chordal_initialization, chordal_problem

        key, sub = self.subgraph(weights)
        if self._chordal[0] != key:
            self._chordal = (key, chordal_problem(sub, self.params.linear_solver))
            self.analyses += 1
        return chordal_initialization(sub, problem=self._chordal[1])

    def least_squares(self, start: np.ndarray, weights: np.ndarray, callback=None):
        """:class:`~posegraph.solve.OptimizeResult` of LM on the weighted graph from ``start`` ``(n, 4, 4)``."""
        from posegraph.solve import analyze, optimize

        key, sub = self.subgraph(weights)
        if self._solver[0] != key:
            self._solver = (key, analyze(sub, self.params))
            self.analyses += 1
        params = self.params if callback is None else replace(self.params, callback=callback)
        return optimize(sub, initial=start, params=params, analysis=self._solver[1])
