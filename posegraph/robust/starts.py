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

from posegraph.model.graph import PoseGraph
from posegraph.robust.active import ActiveEdgeSolves
from posegraph.robust.gnc import GncParams, GncResult, run_gnc
from posegraph.robust.measurements import (
    known_inlier_mask, measurement_dimensions, measurement_known, measurement_residuals, num_priors, weighted_graph,
)

__all__ = ["inlier_chain_start", "downweighted_chordal_start", "robust_chordal_start"]


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
