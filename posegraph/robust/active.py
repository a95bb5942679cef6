"""Weighted least-squares solves that keep one symbolic analysis while edges drop out.

GNC and IRLS solve one graph many times with new per-edge weights ``w`` (cost ``½ Σ w eᵀΩe``).
The symbolic work of a solve — the chordal system's pattern and CHOLMOD analysis
(:func:`posegraph.init.chordal.chordal_problem`), the solver's Hessian pattern and linear solver
(:func:`posegraph.solve.analyze`) — depends only on the edge set. :class:`ActiveEdgeSolves` makes
it for an edge set ``S`` and serves every later *active* set ``A = {w > 0} ⊆ S`` from it: the
solve runs over ``S`` with the edges of ``S ∖ A`` at weight 0 (zero values in the analysed
pattern), and a vertex that the active edges leave without a held vertex in its component — e.g.
one whose every edge has weight 0 — is held at its pose (the start's in LM, the file's in the
chordal solve), exactly as in the subgraph of the active edges, whose problem is solved (round-off
aside: another elimination order). Mechanisms: :meth:`posegraph.init.linear_system.RelativeLeastSquares.restricted`
and ``optimize(..., hold=)`` (:class:`posegraph.solve.sparsity.PinnedVariables`).

A new analysis is made for ``S = A`` when an edge outside ``S`` becomes active, or when
``|A| < reanalyse_fraction · |S|``: an edge of weight 0 adds nothing to the cost, but left in the
pattern its long, random "loop closure" still fills the Cholesky factor (torus3D + 20 % outliers:
97 ms per chordal factorisation over all edges against 21 ms over the weighted ones), and the
analysis itself costs a few ms (CHOLMOD's symbolic factorisation ~3 ms there). The default
``reanalyse_fraction = 0`` (:data:`DEFAULT_REANALYSE_FRACTION`) analyses once — the first solve of
GNC weighs every edge, so no outer iteration analyses again — as the robust-optimisation issue
specifies; ``0.98`` re-analyses when the dropped edges reach 2 % of the pattern, which was
1.4–2.1 × faster end to end with 20 % outliers (more with more: torus3D + 80 % 38 s against 10 s), and ``1`` on every change of ``A`` (``docs/robust.md``, "Symbolic
analyses across outer iterations").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from posegraph.model.graph import EdgeSource, PoseGraph, held_vertices
from posegraph.robust.measurements import (
    num_landmark_measurements, num_priors, poses_of, landmark_subset, weighted_landmarks, weighted_priors,
)

__all__ = ["edge_subgraph", "ActiveEdgeSolves", "AnalysedEdges", "DEFAULT_REANALYSE_FRACTION"]


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


DEFAULT_REANALYSE_FRACTION = 0.0
"""Default of :class:`ActiveEdgeSolves`' ``reanalyse_fraction``: analyse once, so that no outer
iteration of GNC re-analyses (the design the robust-optimisation issue asks for). Measured
(``docs/robust.md``) on sphere2500, parking-garage and torus3D + 20 % outliers, whole ``--robust
gnc`` process, :data:`ROBUST_ORDERING`: 1.69 / 1.68 / 5.78 s with 2 analyses (one per system);
``0.98`` took 1.23 / 1.15 / 2.70 s with 5–7, re-analysing on every change (``1``) 1.28 / 1.22 /
2.73 s with 13–17 — the outliers' fill left in the analysed pattern is what analysing once pays
for. Every variant finds the same outliers and the same optimum."""


@dataclass(frozen=True, eq=False)
class AnalysedEdges:
    """A symbolic analysis and the edge set ``S`` it was made for."""

    edges: np.ndarray
    """``(m,)`` bool over the whole graph's edges: ``S``."""
    graph: PoseGraph
    """The graph of the edges ``S`` (:func:`edge_subgraph`, information as in the file)."""
    analysis: object
    """What was analysed for ``graph``: a chordal problem or a solver ``Analysis``."""


ROBUST_ORDERING = "nesdis"
"""The fill-reducing ordering of the weighted solves when ``SolverParams.ordering`` is ``"auto"``
(and pymetis is installed; else AMD): nested dissection of the vertex graph, whatever its size.
Random wrong loop closures make the graph expander-like, and the analysed pattern keeps them (the
analysis is made over every edge: module docstring); nested dissection fills less than AMD there.
Measured with ``optimize_robust`` in process, analysing once, AMD → nested dissection:
sphere2500 + 20 % 1.92 → 1.73 s, parking-garage + 20 % 1.74 → 1.64 s, torus3D + 20 % 7.07 →
5.83 s, sphere2500 + 50 % 4.93 → 3.94 s, torus3D + 50 % 23.9 → 19.3 s; the same outliers and
optima."""


def robust_ordering(params) -> str:
    """``params.ordering``, with ``"auto"`` read as :data:`ROBUST_ORDERING` when pymetis is installed."""
    from posegraph.linalg.cholmod import nested_dissection_available

    if params.ordering != "auto":
        return params.ordering
    return ROBUST_ORDERING if nested_dissection_available() else "amd"


class ActiveEdgeSolves:
    """Chordal and Levenberg-Marquardt solves of ``graph`` weighted by ``w``, over analysed supersets
    of the edges with ``w > 0`` (module docstring).

    Parameters
    ----------
    graph : PoseGraph
    params : SolverParams, optional
        The Levenberg-Marquardt solves' parameters (its ``linear_solver`` also for the chordal
        solves); ``params.loss`` must be None (the weights are the robust part).
    reanalyse_fraction : float in [0, 1]
        An analysis made for the edge set ``S`` serves the active set ``A`` (``w > 0``) while
        ``A ⊆ S`` and ``|A| ≥ reanalyse_fraction · |S|``; else a new one is made for ``S = A``.
        0: re-analyse only when an edge outside ``S`` becomes active; 1: whenever ``A`` changes.
    """

    def __init__(self, graph: PoseGraph, params=None, *, reanalyse_fraction: float = DEFAULT_REANALYSE_FRACTION):
        from posegraph.solve import SolverParams

        self.graph = graph
        params = SolverParams() if params is None else params
        if params.loss is not None:
            raise ValueError("weighted solves take SolverParams with loss=None")
        self.params = replace(params, ordering=robust_ordering(params))
        if not 0.0 <= reanalyse_fraction <= 1.0:
            raise ValueError(f"reanalyse_fraction must be in [0, 1], got {reanalyse_fraction!r}")
        self.reanalyse_fraction = float(reanalyse_fraction)
        self._chordal: AnalysedEdges | None = None
        self._solver: AnalysedEdges | None = None
        self._pose_part: ActiveEdgeSolves | None = None
        self._analyses = 0

    @property
    def analyses(self) -> int:
        """Symbolic analyses made (chordal and solver, the pose part's included)."""
        return self._analyses + (0 if self._pose_part is None else self._pose_part.analyses)

    def pose_part(self) -> "ActiveEdgeSolves":
        """The solves of the graph without its landmarks (the same parameters), made once: the chordal
        start of a landmark graph weighs its edges and priors only (the chordal relaxation has no points)."""
        if self._pose_part is None:
            self._pose_part = ActiveEdgeSolves(replace(self.graph, landmarks=None), self.params,
                                               reanalyse_fraction=self.reanalyse_fraction)  # fmt: skip
        return self._pose_part

    def serves(self, analysed: AnalysedEdges | None, active: np.ndarray) -> bool:
        """Whether ``analysed`` serves the active edges ``active`` ``(m,)`` bool under the policy."""
        if analysed is None or np.any(active & ~analysed.edges):
            return False
        return np.count_nonzero(active) >= self.reanalyse_fraction * np.count_nonzero(analysed.edges)

    def chordal(self, weights: np.ndarray) -> np.ndarray:
        """``(n, 4, 4)`` chordal start of the weighted graph (:func:`posegraph.init.chordal_initialization`);
        for a landmark graph, of its pose part (:meth:`pose_part`; the landmark weights are ignored)."""
        from posegraph.init.chordal import chordal_initialization, chordal_problem

        if self.graph.landmarks is not None:
            return self.pose_part().chordal(np.asarray(weights)[: self.graph.num_edges + num_priors(self.graph)])
        weights, active = self._checked(weights)
        self._chordal = self._analysed(
            self._chordal, active, lambda sub: chordal_problem(sub, self.params.linear_solver, self.params.ordering)
        )
        weighted, counted, held, _ = self._restriction(self._chordal, weights, active)
        if held is not None and weighted.priors is not None:  # the restricted system holds by today's anchors
            held = held_vertices(edge_subgraph(replace(self._chordal.graph, priors=None), np.flatnonzero(counted)))
        problem = self._chordal.analysis if held is None else self._chordal.analysis.restricted(counted, held)
        return chordal_initialization(weighted, problem=problem)

    def least_squares(self, start, weights: np.ndarray, callback=None, max_iterations: int | None = None):
        """:class:`~posegraph.solve.OptimizeResult` of LM on the weighted graph from ``start``: poses
        ``(n, k, k)``, or a :class:`~posegraph.robust.measurements.Estimate` for a landmark graph.
        ``max_iterations`` caps the LM iterations of this solve (default: the parameters')."""
        from posegraph.solve import analyze, optimize

        weights, active = self._checked(weights)
        self._solver = self._analysed(self._solver, active, lambda sub: analyze(sub, self.params))
        weighted, _, held, held_points = self._restriction(self._solver, weights, active)
        params = self.params if callback is None else replace(self.params, callback=callback)
        params = params if max_iterations is None else replace(params, max_iterations=max_iterations)
        points = None if self.graph.landmarks is None else start.points
        return optimize(weighted, initial=poses_of(start), params=params, analysis=self._solver.analysis, hold=held,
                        initial_points=points, hold_points=held_points)  # fmt: skip

    def _checked(self, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(weights (m + u + q,) float, active (m,) bool)``, after checking shape and values: one weight
        per edge, then one per prior (``u`` of them, :func:`posegraph.robust.measurements.num_priors`),
        then one per landmark measurement (``q``); ``(m,)`` weighs the edges alone, the rest at 1."""
        weights = np.asarray(weights, dtype=np.float64)
        m, u = self.graph.num_edges, num_priors(self.graph) + num_landmark_measurements(self.graph)
        if weights.shape == (m,) and u:
            weights = np.r_[weights, np.ones(u)]
        if weights.shape != (m + u,):
            raise ValueError(f"weights must have shape ({m + u},), got {weights.shape}")
        if not np.all(np.isfinite(weights) & (weights >= 0)):
            raise ValueError("weights must be finite and >= 0")
        return weights, weights[:m] > 0

    def _analysed(self, current: AnalysedEdges | None, active: np.ndarray, analyse) -> AnalysedEdges:
        """``current`` if it :meth:`serves` ``active``, else ``analyse(graph of the active edges)``."""
        if self.serves(current, active):
            return current
        sub = edge_subgraph(self.graph, np.flatnonzero(active))
        self._analyses += 1
        return AnalysedEdges(active.copy(), sub, analyse(sub))

    def _restriction(self, analysed: AnalysedEdges, weights: np.ndarray, active: np.ndarray):
        """``(graph of S weighted by w, counted (|S|,) bool, held (n,) bool or None, held_points (L,) bool
        or None)`` for a solve over ``S`` in which only the active edges, priors and landmark measurements
        count; ``held``: the vertices the graph of the active ones holds
        (:func:`posegraph.model.graph.held_vertices`: fixed, one anchor per component no active prior
        reaches), None when every edge of ``S``, prior and landmark measurement is active;
        ``held_points``: the landmarks no active measurement reaches (None when there are none)."""
        keep = np.flatnonzero(analysed.edges)
        m, u = self.graph.num_edges, num_priors(self.graph)
        information = analysed.graph.information * weights[keep][:, None, None]
        weighted = replace(analysed.graph, information=information, edge_source=None)
        if weighted.priors is not None:
            weighted = weighted_priors(weighted, weights[m : m + u])
        if weighted.landmarks is not None:
            weighted = weighted_landmarks(weighted, weights[m + u :])
        counted = active[keep]
        if counted.all() and np.all(weights[m:] > 0):
            return weighted, counted, None, None
        counting = replace(analysed.graph, priors=weighted.priors)
        held_points = None
        if counting.landmarks is not None:
            counting = landmark_subset(counting, weights[m + u :] > 0)
            held_points = _unmeasured_points(counting.landmarks)
        return weighted, counted, held_vertices(edge_subgraph(counting, np.flatnonzero(counted))), held_points


def _unmeasured_points(landmarks) -> np.ndarray | None:
    """``(L,)`` bool: the landmarks no measurement of ``landmarks`` reaches, None when every one is measured."""
    measured = np.zeros(landmarks.count, dtype=bool)
    for family in landmarks.observations:
        measured[np.asarray(family.landmark, dtype=np.int64)] = True
    return None if measured.all() else ~measured
