"""The measurements GNC weighs: the edges, then the priors (unary edges), of a graph.

Their squared whitened residuals ``s = eᵀΩe``, residual dimensions (for the χ² thresholds), the
trusted ones (known inliers), and the graph with each measurement's information scaled by its
weight. The weighted solves (:mod:`posegraph.robust.active`), the robust starts
(:mod:`posegraph.robust.starts`) and the pipeline (:mod:`posegraph.robust.pipeline`) all take them
from here: this module imports none of them, so a GNC run walks up the floors once.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.model.graph import PoseGraph

__all__ = ["squared_residuals", "num_priors", "measurement_residuals", "measurement_known", "measurement_dimensions",
           "weighted_priors", "weighted_graph", "known_inlier_mask"]


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
    from posegraph.model.priors import Priors

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
