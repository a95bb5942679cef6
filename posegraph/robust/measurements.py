"""The measurements GNC weighs: the edges, then the priors (unary edges), then the landmark
measurements (every family's, in family order) of a graph.

Their squared whitened residuals ``s = eᵀΩe``, residual dimensions (for the χ² thresholds), the
trusted ones (known inliers), and the graph with each measurement's information scaled by its
weight. The weighted solves (:mod:`posegraph.robust.active`), the robust starts
(:mod:`posegraph.robust.starts`) and the pipeline (:mod:`posegraph.robust.pipeline`) all take them
from here: this module imports none of them, so a GNC run walks up the floors once.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from posegraph.model.graph import PoseGraph

__all__ = ["squared_residuals", "num_priors", "num_landmark_measurements", "num_measurements", "Estimate", "estimate_of",
           "poses_of", "measurement_residuals", "measurement_known", "measurement_dimensions", "weighted_priors",
           "weighted_landmarks", "landmark_subset", "weighted_graph", "known_inlier_mask"]


@dataclass(frozen=True, eq=False)
class Estimate:
    """The state of a landmark graph that GNC moves: poses and landmark positions. A pose graph's
    state is its ``(n, k, k)`` poses array alone (as before landmarks)."""

    poses: np.ndarray
    """``(n, k, k)`` poses."""
    points: np.ndarray
    """``(L, s)`` landmark positions."""


def estimate_of(graph: PoseGraph, result):
    """The state of ``result`` (an ``OptimizeResult``): its poses, or an :class:`Estimate` with landmarks."""
    return result.poses if graph.landmarks is None else Estimate(result.poses, result.points)


def poses_of(state) -> np.ndarray:
    """The poses of a state (:class:`Estimate` or a poses array)."""
    return state.poses if isinstance(state, Estimate) else state


def squared_residuals(graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """``(m,)`` squared whitened residuals ``s = eᵀΩe`` of every edge at ``poses`` ``(n, k, k)``."""
    from posegraph.solve.residuals import edge_residuals, squared_norms

    return squared_norms(edge_residuals(poses, graph), graph.information)


def num_priors(graph: PoseGraph) -> int:
    """The number of priors (unary edges) of ``graph``, 0 without."""
    return 0 if graph.priors is None else len(graph.priors)


def num_landmark_measurements(graph: PoseGraph) -> int:
    """The number ``q`` of landmark measurements (every family's, priors on points included), 0 without."""
    return 0 if graph.landmarks is None else graph.landmarks.num_measurements


def num_measurements(graph: PoseGraph) -> int:
    """``m + u + q``: edges, priors and landmark measurements: the length of GNC's weight vector."""
    return graph.num_edges + num_priors(graph) + num_landmark_measurements(graph)


def measurement_residuals(graph: PoseGraph, state) -> np.ndarray:
    """``(m + u + q,)`` squared whitened residuals of every measurement at ``state`` (poses ``(n, k, k)``,
    or an :class:`Estimate` for a landmark graph): the edges, then the ``u`` priors (pose priors, then
    position priors), then the ``q`` landmark measurements: what GNC weighs, a wrong GNSS fix or a
    wrong data association being an outlier like a wrong loop closure."""
    poses = np.asarray(poses_of(state), dtype=np.float64)
    s = squared_residuals(graph, poses)
    if num_priors(graph):
        from posegraph.solve.unary import prior_errors, prior_squared_norms

        s = np.concatenate([s, prior_squared_norms(prior_errors(poses, graph), graph.priors)])
    if graph.landmarks is not None:
        from posegraph.solve.landmark_terms import landmark_errors

        if not isinstance(state, Estimate):
            raise TypeError("a landmark graph's residuals need an Estimate (poses and points)")
        s = np.concatenate([s, landmark_errors(graph, poses, state.points).squared])
    return s


def measurement_known(graph: PoseGraph, known_inliers) -> np.ndarray:
    """``(m + u + q,)`` bool: the trusted measurements — :func:`known_inlier_mask` over the edges, no
    prior, no landmark measurement — or ``known_inliers`` itself when it is already such a mask."""
    total, m = num_measurements(graph), graph.num_edges
    if total > m and not isinstance(known_inliers, str) and np.shape(known_inliers) == (total,):
        return np.asarray(known_inliers, dtype=bool)
    return np.r_[known_inlier_mask(graph, known_inliers), np.zeros(total - m, dtype=bool)]


def measurement_dimensions(graph: PoseGraph):
    """The residual dimension of every measurement (for GNC's χ² thresholds): ``d``, or ``(m + u + q,)``
    with priors or landmarks (``d`` per edge and pose prior, ``r`` per position prior, and per landmark
    measurement its residual's rows ``r``: :func:`posegraph.model.landmarks.measurement_size`)."""
    if num_measurements(graph) == graph.num_edges:
        return graph.group.dim
    parts = [np.full(graph.num_edges, graph.group.dim)]
    if num_priors(graph):
        priors = graph.priors
        parts += [np.full(priors.num_pose, graph.group.dim), np.full(priors.num_position, graph.group.space_dim)]
    if graph.landmarks is not None:
        parts += [np.full(f.count, f.measurements.shape[1]) for f in graph.landmarks.observations]
    return np.concatenate(parts).astype(np.int64)


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


def weighted_landmarks(graph: PoseGraph, weights: np.ndarray) -> PoseGraph:
    """``graph`` with landmark measurement ``k``'s information scaled by ``weights[k]`` ``(q,)`` (families
    in order). Measurements of weight 0 stay (zero information), so the solver's pattern is unchanged."""
    weights, start, families = np.asarray(weights, dtype=np.float64), 0, []
    for family in graph.landmarks.observations:
        w = weights[start : start + family.count]
        families.append(replace(family, information=np.asarray(family.information) * w[:, None, None], text=None))
        start += family.count
    return replace(graph, landmarks=replace(graph.landmarks, observations=tuple(families)))


def landmark_subset(graph: PoseGraph, keep: np.ndarray) -> PoseGraph:
    """``graph`` with only the landmark measurements ``keep`` ``(q,)`` bool (families in order; the
    landmarks themselves all stay): the graph whose components and anchors a weighted solve has."""
    start, families = 0, []
    for family in graph.landmarks.observations:
        rows = np.flatnonzero(np.asarray(keep, dtype=bool)[start : start + family.count])
        start += family.count
        pick = {name: (None if getattr(family, name) is None else np.asarray(getattr(family, name))[rows])
                for name in ("pose", "landmark", "measurements", "information", "offsets", "lines", "offset_ids")}  # fmt: skip
        families.append(replace(family, text=None, **pick))
    return replace(graph, landmarks=replace(graph.landmarks, observations=tuple(families)))


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
