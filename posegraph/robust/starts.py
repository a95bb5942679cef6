"""Starts for robust optimisation that outliers do not corrupt.

The chordal start trusts every loop closure, and the odometry start's breadth-first spanning tree
takes the shortest hop path from the anchor — which runs through any long wrong loop closure.
For graduated non-convexity the start must rely on the known inliers only, or discount the rest:

* :func:`inlier_chain_start` — measurements composed along a spanning tree of the known inliers
  alone (by default the odometry chain): no loop closure is used.
* :func:`downweighted_chordal_start` — the chordal start (rotations by chordal relaxation,
  translations given them) with every other edge's information scaled by ``factor``.
* :func:`robust_chordal_start` — the chordal start robustified the same way as the solve: GNC
  (:func:`posegraph.robust.gnc.run_gnc`) whose weighted solve is the chordal start of the
  weighted graph (a global, linear-algebra solve that needs no start of its own).

``docs/robust.md`` measures them on sphere2500 with 20 % injected outliers.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.graph import PoseGraph
from posegraph.robust.active import ActiveEdgeSolves
from posegraph.robust.gnc import GncParams, GncResult, run_gnc

__all__ = ["known_inlier_mask", "inlier_chain_start", "downweighted_chordal_start", "robust_chordal_start", "squared_residuals",
           "weighted_graph", "measurement_residuals", "measurement_dimensions", "num_priors"]


def squared_residuals(graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """``(m,)`` squared whitened residuals ``s = eᵀΩe`` of every edge at ``poses`` ``(n, k, k)``."""
    from posegraph.solve.residuals import edge_residuals, squared_norms

    return squared_norms(edge_residuals(poses, graph), graph.information)


def num_priors(graph: PoseGraph) -> int:
    """The number of priors (unary edges) of ``graph``, 0 without."""
    return 0 if graph.priors is None else len(graph.priors)


def measurement_residuals(graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """``(m + u,)`` squared whitened residuals of every measurement: the edges, then the ``u`` priors
    (pose priors, then position priors): what GNC weighs, a wrong GNSS fix being an outlier like a
    wrong loop closure."""
    s = squared_residuals(graph, poses)
    if not num_priors(graph):
        return s
    from posegraph.solve.unary import prior_errors, prior_squared_norms

    return np.concatenate([s, prior_squared_norms(prior_errors(np.asarray(poses, dtype=np.float64), graph), graph.priors)])


def measurement_known(graph: PoseGraph, known_inliers) -> np.ndarray:
    """``(m + u,)`` bool: the trusted measurements — :func:`known_inlier_mask` over the edges, no prior —
    or ``known_inliers`` itself when it is already such a mask."""
    u = num_priors(graph)
    if u and not isinstance(known_inliers, str) and np.shape(known_inliers) == (graph.num_edges + u,):
        return np.asarray(known_inliers, dtype=bool)
    return np.r_[known_inlier_mask(graph, known_inliers), np.zeros(u, dtype=bool)]


def measurement_dimensions(graph: PoseGraph):
    """The residual dimension of every measurement (for GNC's χ² thresholds): ``d``, or ``(m + u,)``
    with priors (``d`` per edge and pose prior, ``r`` per position prior)."""
    if not num_priors(graph):
        return graph.group.dim
    priors = graph.priors
    return np.r_[np.full(graph.num_edges + priors.num_pose, graph.group.dim),
                 np.full(priors.num_position, graph.group.space_dim)]


def weighted_priors(graph: PoseGraph, weights: np.ndarray) -> PoseGraph:
    """``graph`` with prior ``k``'s information scaled by ``weights[k]`` ``(u,)``, the priors of weight 0 dropped."""
    from posegraph.priors import Priors

    priors = graph.priors
    a = priors.num_pose
    pose, position = np.flatnonzero(weights[:a] > 0), np.flatnonzero(weights[a:] > 0)
    kept = Priors(
        priors.pose_vertex[pose], priors.pose_measurements[pose], priors.pose_offsets[pose],
        priors.pose_information[pose] * weights[pose, None, None], priors.position_vertex[position],
        priors.position_measurements[position], priors.position_information[position] * weights[a + position, None, None],
    )  # fmt: skip
    return replace(graph, priors=kept)


def weighted_graph(graph: PoseGraph, weights: np.ndarray) -> PoseGraph:
    """``graph`` with edge ``k``'s information scaled by ``weights[k]`` (cost ``½ Σ w eᵀΩe``)."""
    return replace(graph, information=graph.information * np.asarray(weights, dtype=np.float64)[:, None, None], edge_source=None)


def known_inlier_mask(graph: PoseGraph, known_inliers="odometry") -> np.ndarray:
    """``(m,)`` bool from ``"odometry"`` (:meth:`PoseGraph.odometry_mask`, also for None),
    ``"none"``, or a ``(m,)`` bool mask."""
    if known_inliers is None or (isinstance(known_inliers, str) and known_inliers == "odometry"):
        return graph.odometry_mask()
    if isinstance(known_inliers, str):
        if known_inliers != "none":
            raise ValueError(f"known_inliers must be 'odometry', 'none' or a bool mask, got {known_inliers!r}")
        return np.zeros(graph.num_edges, dtype=bool)
    known = np.asarray(known_inliers)
    if known.dtype != bool or known.shape != (graph.num_edges,):
        raise ValueError(f"known_inliers must be a ({graph.num_edges},) bool mask, got {known.dtype} {known.shape}")
    return known


def inlier_chain_start(graph: PoseGraph, known_inliers: np.ndarray | None = None) -> np.ndarray:
    """``(n, 4, 4)`` poses composed along a spanning tree of the known inliers (default: the
    odometry edges, :meth:`PoseGraph.odometry_mask`). Vertices the known inliers do not reach
    from a held vertex keep their file pose."""
    from posegraph.init.odometry import odometry_initialization

    known = known_inlier_mask(graph, known_inliers)
    keep = np.flatnonzero(known)
    inliers_only = replace(
        graph,
        edge_from=graph.edge_from[keep],
        edge_to=graph.edge_to[keep],
        measurements=graph.measurements[keep],
        information=graph.information[keep],
        edge_source=None,
    )
    return odometry_initialization(inliers_only)


def downweighted_chordal_start(graph: PoseGraph, factor: float = 1e-3, known_inliers: np.ndarray | None = None) -> np.ndarray:
    """``(n, 4, 4)`` chordal start with the information of every edge that is not a known inlier
    multiplied by ``factor`` (0 < factor ≤ 1)."""
    from posegraph.init.chordal import chordal_initialization

    if not 0.0 < factor <= 1.0:
        raise ValueError(f"factor must be in (0, 1], got {factor!r}")
    known = known_inlier_mask(graph, known_inliers)
    return chordal_initialization(weighted_graph(graph, np.where(known, 1.0, factor)))


def robust_chordal_start(
    graph: PoseGraph,
    known_inliers: np.ndarray | None = None,
    params: GncParams | None = None,
    *,
    solves: ActiveEdgeSolves | None = None,
    progress=None,
) -> GncResult:
    """GNC over chordal starts: each outer iteration's weighted solve is the chordal start of the
    weighted graph, evaluated on the true residuals. Returns the :class:`GncResult` (its
    ``poses`` are the start; its ``weights`` a first guess at the inliers).

    The weighted chordal solves run over the edges of nonzero weight, analysed once per edge set
    (:class:`~posegraph.robust.active.ActiveEdgeSolves`; pass ``solves`` to share its analyses).
    ``progress`` gets each outer iteration's :class:`~posegraph.robust.gnc.GncIteration`.
    """
    known = measurement_known(graph, known_inliers)
    solves = ActiveEdgeSolves(graph) if solves is None else solves
    return run_gnc(
        lambda poses: measurement_residuals(graph, poses),
        lambda _start, weights: solves.chordal(weights),
        solves.chordal(np.ones(graph.num_edges + num_priors(graph))),
        known,
        params,
        dimension=measurement_dimensions(graph),  # the χ² thresholds: 6 for SE(3), 3 for SE(2); r for position priors
        progress=progress,
        start_solved=True,
    )
