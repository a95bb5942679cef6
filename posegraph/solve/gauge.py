"""The gauge a landmark graph is solved in: each component's most central pose held, the answer moved back.

A graph without ``FIX`` vertices, priors, ``FIX`` landmarks or point priors is determined only up to one
rigid motion per connected component; the convention (:func:`posegraph.model.graph.component_anchors`)
holds each component's smallest-id pose at its start. Which pose is held does not change the optimum
(every measurement is relative, so ``F(T·X, T·p) = F(X, p)`` for a rigid ``T``), but it changes how
Gauss-Newton gets there: a bend of the whole map about a held pose at one end of it moves far poses
along arcs whose linearisation the retraction leaves behind at every step, and Gauss-Newton then
converges linearly along that weak, curved direction. Held at the pose nearest the centroid of its
component (the lever arms halved), the same solve from the same start takes world-2000-default 16 → 8
LM iterations and world-2000-lownoise-default 22 → 9, and no landmark file tried takes more
(``docs/landmarks.md``).

So the solver holds :func:`central_anchors` instead, and :func:`moved_back` re-expresses its answer
(and :func:`reported_moved_back` each estimate it reports on the way) in the conventional gauge: per component ``T = X⁰_a · X_a⁻¹`` (``a`` the conventional anchor, ``X⁰`` the
start), poses ``T·X``, points ``T·p``, the anchor set to its start exactly. The cost and every
residual are unchanged by ``T``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.model.graph import PoseGraph, component_anchors, landmark_components

__all__ = ["central_anchors", "moved_back", "reported_moved_back"]


def central_anchors(graph: PoseGraph, poses: np.ndarray) -> tuple[PoseGraph, np.ndarray] | None:
    """``(graph with the central poses FIX, conventional anchors (c,))`` for a landmark graph whose every
    component is gauged by its anchor alone; None otherwise (no landmarks, any ``FIX``, prior, point
    prior or ``FIX`` landmark: those fix the gauge themselves). ``poses`` ``(n, k, k)``: the start; the
    central pose of a component is the one nearest the centroid of its positions there."""
    if graph.landmarks is None or graph.priors is not None or graph.num_vertices == 0:
        return None
    count, labels = landmark_components(graph)
    anchors = component_anchors(graph)
    if anchors.shape[0] != count or np.any(graph.fixed):
        return None
    labels = labels[: graph.num_vertices]
    r = graph.group.space_dim
    positions = poses[:, :r, r]
    sizes = np.bincount(labels, minlength=count)
    centroids = np.stack([np.bincount(labels, positions[:, axis], minlength=count) for axis in range(r)], axis=1) / sizes[:, None]
    distance = np.linalg.norm(positions - centroids[labels], axis=1)
    order = np.lexsort((distance, labels))
    central = order[np.r_[True, labels[order][1:] != labels[order][:-1]]]
    fixed = np.zeros(graph.num_vertices, dtype=bool)
    fixed[central] = True
    return replace(graph, fixed=fixed), anchors


def moved_back(graph: PoseGraph, anchors: np.ndarray, start: np.ndarray, poses: np.ndarray,
               points: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """``(poses (n, k, k), points (L, s) or None)`` moved, per component, by ``T = start[a] · poses[a]⁻¹``
    (``a`` its anchor of ``anchors``, as :func:`central_anchors` returned them): the answer in the gauge
    holding each anchor at ``start``. Landmarks no pose observes are left as they are."""
    count, labels = landmark_components(graph)
    n = graph.num_vertices
    component = np.full(count, -1, dtype=np.int64)
    component[labels[anchors]] = np.arange(anchors.shape[0])
    motions = start[anchors] @ graph.group.inverse(poses[anchors])  # (c, k, k)
    moved = motions[component[labels[:n]]] @ poses
    moved[anchors] = start[anchors]
    if points is None:
        return moved, None
    r = graph.group.space_dim
    seen = labels[n:] < count
    motion = motions[component[np.where(seen, labels[n:], 0)]]
    placed = np.einsum("lij,lj->li", motion[:, :r, :r], points) + motion[:, :r, r]
    return moved, np.where(seen[:, None], placed, points)


def reported_moved_back(callback, graph: PoseGraph, anchors: np.ndarray, start: np.ndarray):
    """``callback(record, poses, points)`` (an ``estimate_callback``) given each estimate moved back as
    :func:`moved_back` moves the answer, so that what it records is in the gauge of the output."""

    def reported(record, poses, points):
        callback(record, *moved_back(graph, anchors, start, poses, points))

    return reported
