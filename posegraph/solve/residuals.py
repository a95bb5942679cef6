"""Edge residuals, the cost and the residual Jacobians of a pose graph, over its group.

Conventions (``docs/architecture.md``): poses are ``(n, k, k)`` world-from-body
matrices of ``graph.group`` (``k = 4`` for SE(3)), tangents have ``d = graph.group.dim``
entries in the group's order (``[ω; v]``, rotation first, for SE(3)), perturbations
are on the right, ``X ⊕ δ = X · Exp(δ)``. Every function here takes the group's
functions from ``graph.group`` (:class:`posegraph.lie.group.LieGroup`); the derivation
below holds for any matrix Lie group.
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph

__all__ = ["edge_residuals", "cost", "weighted_cost", "squared_norms", "weighted_residuals", "edge_jacobians", "edge_errors", "residual_jacobian_factors"]

# The residual of one edge
# ------------------------
# An edge between vertices i and j carries a measurement Z_ij of the pose of
# j seen from i, i.e. of X_i⁻¹ X_j, and an information matrix Ω_ij (the
# inverse covariance of the measurement, [ω; v] order). The pose of j
# predicted from i differs from the measured one by the relative pose
#
#     E_ij = Z_ij⁻¹ · (X_i⁻¹ · X_j),
#
# which is the identity when the measurement is met exactly. The residual is
# that discrepancy expressed in the tangent space at the identity,
#
#     e_ij = Log(E_ij) ∈ R^d (R⁶ for SE(3)),  [ω; v]: rotation error (axis·angle), then translation,
#
# and the cost is the squared Mahalanobis norm summed over edges,
#
#     F(X) = ½ Σ_ij e_ijᵀ Ω_ij e_ij,
#
# exactly gtsam's BetweenFactor<Pose3>: evaluateError returns
# Local(Z, between(X_i, X_j)) = Log(Z⁻¹ X_i⁻¹ X_j) and NonlinearFactorGraph.error
# sums ½ ‖R e‖² with Rᵀ R = Ω. (Ceres' pose_graph_3d example uses a different
# error, 2·vec(q) for rotation and a rotated translation difference, which
# agrees with this one only to first order.)
#
# Jacobians, perturbing X_j ← X_j · Exp(δ_j):
#     E_ij(δ_j) = E_ij · Exp(δ_j)  ⇒  ∂e/∂δ_j = Jr⁻¹(e)   (right Jacobian of Log).
# Perturbing X_i ← X_i · Exp(δ_i): X_i⁻¹ becomes Exp(−δ_i) X_i⁻¹ and
#     E_ij(δ_i) = Z⁻¹ Exp(−δ_i) X_i⁻¹ X_j = E_ij · Exp(−Ad(X_j⁻¹ X_i) δ_i)
# (moving Exp(−δ_i) past T = X_i⁻¹ X_j: Exp(a) T = T Exp(Ad(T⁻¹) a)), so
#     ∂e/∂δ_i = −Jr⁻¹(e) · Ad(X_j⁻¹ X_i).


CHUNK_EDGES = 8192
"""Edges per pass of the per-edge arithmetic (:func:`edge_errors`, :func:`posegraph.solve.linearize.linearize`).

It runs on slices of this many edges (a loop over ~m/8192 slices, never over edges) so that its
temporaries (~0.3 kB per edge each) stay in the caches: in one pass over all edges the cost per
edge grew with the graph — B, Ad and the three Hessian blocks took 1.13 µs per edge at 100,000
edges and 1.49 µs at 800,000, the temporaries streaming through memory — and by slices it stays at
0.91–0.97 µs (measured here). A graph of up to 8192 edges is one slice."""


def edge_slices(m: int):
    """``slice`` objects covering ``range(m)`` in runs of :data:`CHUNK_EDGES` (none when ``m == 0``)."""
    step = CHUNK_EDGES
    return [slice(start, min(start + step, m)) for start in range(0, m, step)]


def by_slices(m: int, compute):
    """``compute(part)`` for each slice of :func:`edge_slices`, its arrays joined along the edges.

    ``compute`` returns a tuple of arrays whose first axis is the slice's edges. One slice (up to
    :data:`CHUNK_EDGES` edges) returns them as they are; several are written into arrays allocated
    once, from the first slice's shapes and dtypes.
    """
    parts = edge_slices(m)
    if len(parts) <= 1:
        return compute(slice(0, m))
    first = compute(parts[0])
    out = tuple(np.empty((m,) + a.shape[1:], dtype=a.dtype) for a in first)
    for target, value in zip(out, first):
        target[parts[0]] = value
    for part in parts[1:]:
        for target, value in zip(out, compute(part)):
            target[part] = value
    return out


def edge_errors(poses: np.ndarray, graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
    """Relative poses ``X_i⁻¹ X_j`` ``(m, k, k)`` and residuals ``Log(Z⁻¹ X_i⁻¹ X_j)`` ``(m, d)``."""
    poses = np.asarray(poses, dtype=np.float64)
    group = graph.group

    fused = group.edge_errors if group.residual_log is None else None

    def compute(part):
        if fused is not None:  # one pass over the three operands (bit for bit the two below)
            return fused(graph.measurements[part], poses[graph.edge_from[part]], poses[graph.edge_to[part]])
        relative = group.between(poses[graph.edge_from[part]], poses[graph.edge_to[part]])
        return relative, group.edge_log(group.between(graph.measurements[part], relative))

    return by_slices(graph.num_edges, compute)  # slices, for the caches (CHUNK_EDGES)


def edge_residuals(poses: np.ndarray, graph: PoseGraph) -> np.ndarray:
    """Residuals ``e_ij = Log(Z_ij⁻¹ · X_i⁻¹ · X_j)`` of all edges, ``(m, d)`` in the group's tangent order.

    ``poses`` is ``(n, k, k)`` in the graph's vertex order.
    """
    return edge_errors(poses, graph)[1]


def weighted_residuals(residuals: np.ndarray, information: np.ndarray) -> np.ndarray:
    """``(m, d)``: ``Ω_k r_k`` for residuals ``(m, d)`` and informations ``(m, d, d)``. An ``einsum``: a
    batched ``@`` of d×d by d×1 costs ~2× as much per edge (3 and 6, 50 to 20,000 edges; docs/incremental.md)."""
    return np.einsum("mij,mj->mi", information, residuals)


def weighted_cost(residuals: np.ndarray, information: np.ndarray) -> float:
    """``½ Σ_k r_kᵀ Ω_k r_k`` for residuals ``(m, d)`` and informations ``(m, d, d)``."""
    return 0.5 * float(np.einsum("mi,mi->", residuals, weighted_residuals(residuals, information)))


def squared_norms(residuals: np.ndarray, information: np.ndarray) -> np.ndarray:
    """``(m,)`` squared Mahalanobis norms ``s_k = r_kᵀ Ω_k r_k``: what a robust loss ``ρ(s)`` reads."""
    return np.einsum("mi,mi->m", residuals, weighted_residuals(residuals, information))


def cost(graph: PoseGraph, poses: np.ndarray | None = None, points: np.ndarray | None = None) -> float:
    """``½ Σ e_ijᵀ Ω_ij e_ij`` at ``poses`` ``(n, k, k)`` (the graph's own poses if None), priors' and
    landmark measurements' terms included.

    Landmarks (``graph.landmarks``) at ``points`` ``(L, s)``; if None, the graph's own positions when
    ``poses`` is None too, else each landmark from its measurements given ``poses``
    (:func:`posegraph.init.landmarks.initialize_landmarks`), as :func:`posegraph.solve.optimize` starts.
    Equals gtsam's ``NonlinearFactorGraph.error(values)`` for the graph ``gtsam.readG2o`` builds.
    """
    if graph.landmarks is not None and points is None:
        if poses is None:
            points = graph.landmarks.positions
        else:
            from posegraph.init.landmarks import initialize_landmarks

            points = initialize_landmarks(graph, poses)[0]
    if poses is None:
        poses = graph.poses
    total = weighted_cost(edge_residuals(poses, graph), graph.information)
    if graph.priors is not None:  # unary edges (posegraph.solve.unary)
        from posegraph.solve.unary import prior_cost

        total += prior_cost(np.asarray(poses, dtype=np.float64), graph)
    if graph.landmarks is not None:
        from posegraph.solve.landmark_residuals import landmark_cost

        total += landmark_cost(graph.group, poses, points, graph.landmarks)
    return total


def edge_jacobians(
    poses: np.ndarray, graph: PoseGraph, residuals: np.ndarray | None = None, relative: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians ``(∂e/∂δ_i, ∂e/∂δ_j)`` of every edge residual, each ``(m, d, d)``.

    With right perturbations ``X ← X · Exp(δ)`` (derivation above :func:`edge_residuals`)::

        ∂e/∂δ_j = Jr⁻¹(e),      ∂e/∂δ_i = −Jr⁻¹(e) · Ad(X_j⁻¹ X_i).

    ``residuals`` and ``relative`` (``X_i⁻¹ X_j``) may be passed to avoid recomputing them.
    """
    if residuals is None or relative is None:
        relative, residuals = edge_errors(poses, graph)
    jr_inv, adjoint = residual_jacobian_factors(graph.group, residuals, relative)
    return -jr_inv @ adjoint, jr_inv


def residual_jacobian_factors(group, residuals: np.ndarray, relative: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Jr⁻¹(e), Ad(X_j⁻¹ X_i))``, each ``(m, d, d)``: ``∂e/∂δ_j = Jr⁻¹(e)``, ``∂e/∂δ_i = −Jr⁻¹(e)·Ad``.

    ``group`` is a :class:`posegraph.lie.group.LieGroup`; ``relative`` is ``X_i⁻¹ X_j`` ``(m, k, k)``.
    """
    adjoint = group.adjoint(group.inverse(relative)) if group.adjoint_of_inverse is None else group.adjoint_of_inverse(relative)
    return group.right_jacobian_inverse(residuals), adjoint
