"""The scale part of a Sim(3) start: rotation blocks without their scale, log-scales by least squares.

A Sim(3) pose is ``[[s R, t], [0, 1]]`` (:mod:`posegraph.lie.sim3`). Its edge residual's log-scale
component is exactly ``λ_j − λ_i − λ_z`` (scales multiply, whatever the rotations and translations),
so once the chordal stage has the rotations the log-scales minimising ``½ Σ Ω_λλ (λ_j − λ_i − λ_z)²``
are one sparse linear solve (block 1), the held vertices' log-scales given. With rotations and
scales known, the translation part of the residual is affine in the translations
(:func:`posegraph.init.chordal.translations_given_rotations`, whose per-edge terms take
:func:`edge_scale_terms`). For the rigid groups every function here is the identity on its input.
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.init.linear_system import RelativeLeastSquares
from posegraph.init.weights import WEIGHT_FLOOR

__all__ = ["rotation_blocks", "log_scales", "edge_scale_terms"]


def rotation_blocks(matrices: np.ndarray, group) -> tuple[np.ndarray, np.ndarray]:
    """``(R (…, r, r), λ (…))``: the rotation block without its scale and the log-scale ``λ = log s``
    (``s = det(s R)^{1/3}``; 0 for the rigid groups, whose blocks are returned as they are)."""
    r = group.space_dim
    block = matrices[..., :r, :r]
    if not group.scale_axes:
        return block, np.zeros(block.shape[:-2])
    s = np.cbrt(np.linalg.det(block))
    return block / s[..., None, None], np.log(s)


def log_scales(graph: PoseGraph, held: np.ndarray, linear_solver: str = "auto") -> np.ndarray:
    """``(n,)`` log-scales minimising ``½ Σ w_e (λ_j − λ_i − λ_z)²``, ``w_e = Ω_λλ`` floored; held
    vertices keep their file log-scale. Zeros for the rigid groups."""
    if not graph.group.scale_axes:
        return np.zeros(graph.num_vertices)
    _, file_log_scales = rotation_blocks(graph.poses, graph.group)
    _, measured = rotation_blocks(graph.measurements, graph.group)
    axis = graph.group.scale_axes[0]
    weights = graph.information[:, axis, axis]
    weights = np.maximum(weights, WEIGHT_FLOOR * max(float(weights.max(initial=0.0)), 1e-300))
    problem = RelativeLeastSquares(held, graph.edge_from, graph.edge_to, linear_solver=linear_solver, block=1)
    solution = problem.solve(
        file_log_scales[:, None, None], transfer=np.ones((graph.num_edges, 1, 1)),
        weight=weights[:, None, None], weighted_offset=(weights * measured)[:, None, None],
    )  # fmt: skip
    return solution[:, 0, 0]


def edge_scale_terms(graph: PoseGraph, scales: np.ndarray | None):
    """Per edge ``(1/(s_z s_i), 1/s_z, λ_j − λ_i − λ_z)``, each ``(m,)``; ``(1, 1, 0)`` for the rigid groups.

    ``Z⁻¹ X_i⁻¹ X_j`` has the translation ``R_zᵀ (R_iᵀ (t_j − t_i)/s_i − t_z)/s_z``: the first two are the
    factors of its two terms, the third the residual's log-scale component."""
    m = graph.num_edges
    if scales is None or not graph.group.scale_axes:
        return np.ones(m), np.ones(m), np.zeros(m)
    _, measured = rotation_blocks(graph.measurements, graph.group)
    i, j = graph.edge_from, graph.edge_to
    return np.exp(-(measured + scales[i])), np.exp(-measured), scales[j] - scales[i] - measured
