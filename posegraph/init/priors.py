"""Starts for graphs with priors: each component a prior reaches moved rigidly to where its priors say.

The initialisers solve for the relative configuration of each component with one vertex held at
its file pose (:func:`without_priors`, today's gauge); a component tied to the world by priors
(:mod:`posegraph.model.priors`) is then moved as one rigid body, ``X ← T X``, by the motion ``T`` that
best fits its priors (:func:`align_to_priors`): least squares over point pairs (weighted Kabsch /
Umeyama without scale, Umeyama 1991) — each position prior gives ``(t(X_k), z)``; each pose prior,
whose measured pose of the vertex is ``Z O⁻¹``, gives its origin and the tips of its unit axes,
``(X_k p, Z O⁻¹ p)`` for ``p ∈ {0, e_1, …, e_r}``. With a single point (one position prior), the
rotation stays as the initialiser made it and only the translation moves. Components with a
``FIX`` vertex stay where the file put them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.model.graph import PoseGraph, connected_components

__all__ = ["without_priors", "align_to_priors", "rigid_fit"]


def without_priors(graph: PoseGraph) -> PoseGraph:
    """``graph`` without its priors (so that its components hold today's anchors)."""
    return graph if graph.priors is None else replace(graph, priors=None)


def rigid_fit(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(r+1, r+1)`` rigid motion ``T`` minimising ``Σ ‖T p − q‖²`` over pairs ``source``/``target`` ``(s, r)``.

    Kabsch: ``H = Σ (p − p̄)(q − q̄)ᵀ = U S Vᵀ``, ``R = V diag(1, …, det(V Uᵀ)) Uᵀ``,
    ``t = q̄ − R p̄``. One pair (``H = 0``): ``R = I``.
    """
    r = source.shape[1]
    p_mean, q_mean = source.mean(axis=0), target.mean(axis=0)
    cross = (source - p_mean).T @ (target - q_mean)
    out = np.eye(r + 1)
    if len(source) > 1 and np.any(cross):
        u, _, vt = np.linalg.svd(cross)
        sign = np.ones(r)
        sign[-1] = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
        out[:r, :r] = vt.T @ np.diag(sign) @ u.T
    out[:r, r] = q_mean - out[:r, :r] @ p_mean
    return out


def _point_pairs(graph: PoseGraph, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(vertex (s,), source (s, r), target (s, r))``: the point pairs every prior gives (module docstring)."""
    priors, group = graph.priors, graph.group
    r = group.space_dim
    tips = np.vstack([np.zeros(r), np.eye(r)])  # origin and unit axes
    measured = priors.pose_measurements @ group.inverse(priors.pose_offsets)
    at = poses[priors.pose_vertex]
    source = at[:, None, :r, :r] @ tips[None, :, :, None] + at[:, None, :r, r:]
    target = measured[:, None, :r, :r] @ tips[None, :, :, None] + measured[:, None, :r, r:]
    vertex = np.concatenate([np.repeat(priors.pose_vertex, r + 1), priors.position_vertex])
    source = np.concatenate([source[..., 0].reshape(-1, r), poses[priors.position_vertex, :r, r]])
    target = np.concatenate([target[..., 0].reshape(-1, r), priors.position_measurements])
    return vertex, source, target


def align_to_priors(graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """``poses`` ``(n, k, k)`` with each component a prior reaches (and no ``FIX`` vertex) moved to fit its priors."""
    if graph.priors is None or len(graph.priors) == 0:
        return poses
    count, labels = connected_components(graph)
    fixed = np.zeros(count, dtype=bool)
    fixed[labels[graph.fixed]] = True
    vertex, source, target = _point_pairs(graph, poses)
    poses = np.array(poses, copy=True)
    for c in np.unique(labels[vertex]).tolist():  # one fit per component a prior reaches (few)
        if fixed[c]:
            continue
        pairs = labels[vertex] == c
        members = labels == c
        poses[members] = rigid_fit(source[pairs], target[pairs]) @ poses[members]
    return poses
