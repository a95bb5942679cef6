"""Per-edge blocks of the Gauss-Newton normal equations, all edges in one batch.

For an edge with Jacobians ``A_i = ∂e/∂δ_i``, ``A_j = ∂e/∂δ_j`` (see
:mod:`posegraph.solve.residuals`), information Ω and weight ``w`` (1 without a
robust loss), its share of ``H = Jᵀ W Ω J`` and ``g = Jᵀ W Ω e`` is::

    H_ii = w A_iᵀ Ω A_i,  H_jj = w A_jᵀ Ω A_j,  H_ij = w A_iᵀ Ω A_j  (H_ji = H_ijᵀ),
    g_i  = w A_iᵀ Ω e,    g_j  = w A_jᵀ Ω e.

Because ``A_j = Jr⁻¹(e) =: B`` and ``A_i = −B · Ad`` with ``Ad = Ad(X_j⁻¹ X_i)``,
every product goes through ``W = w Bᵀ Ω B`` and ``g_j = w Bᵀ Ω e``::

    H_jj = W,  H_ij = −Adᵀ W,  H_ii = Adᵀ W Ad = −H_ij Ad,  g_i = −Adᵀ g_j,

four batched d×d products per edge (d = ``graph.group.dim``, 6 for SE(3)) instead
of forming ``A_i`` and three weighted products.

Weights: a robust loss ``ρ`` of the squared norm ``s = eᵀΩe`` (cost ``½ Σ ρ(s)``) has
the gradient ``Σ ρ'(s) Jᵀ Ω e``, so its iteratively reweighted least-squares
(IRLS) system is this one with ``w = ρ'(s)`` per edge (:mod:`posegraph.solve.objective`).
``weights=None`` skips the products altogether; ``weights = 1`` gives bit-identical
blocks (a product by 1.0 is exact).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.solve import residuals as _residuals
from posegraph.solve.residuals import edge_errors, residual_jacobian_factors, weighted_residuals

__all__ = ["EdgeBlocks", "linearize"]


@dataclass(frozen=True, eq=False)
class EdgeBlocks:
    """The linearisation of every edge at one set of poses (``d`` = the group's tangent dimension).

    The gradient blocks are computed at once; the Hessian blocks on demand, a slice of edges at a
    time (:meth:`hessian_slice`, what the solver assembles H from: the blocks of all edges never
    exist at once) or all together (:attr:`hessian_blocks`): a solver that finds from the gradient
    alone that it has converged (:mod:`posegraph.solve.optimizer`, Newton decrement) never pays for them.
    """

    residuals: np.ndarray
    """``(m, d)`` residuals ``e``."""
    cost: float
    """``½ Σ eᵀ Ω e`` (unweighted: the cost without a loss)."""
    gradient: np.ndarray
    """``(m, 2, d)``: ``[g_i, g_j]`` per edge, weights applied."""
    jacobian_inverse: np.ndarray
    """``(m, d, d)``: ``B = Jr⁻¹(e) = ∂e/∂δ_j``."""
    adjoint: np.ndarray
    """``(m, d, d)``: ``Ad(X_j⁻¹ X_i)`` (so ``∂e/∂δ_i = −B·Ad``)."""
    information: np.ndarray
    """``(m, d, d)``: Ω, C-contiguous."""
    weights: np.ndarray | None = None
    """``(m,)`` per-edge weights ``w`` scaling every block of the edge, or None (all 1, no products)."""
    priors: object | None = None
    """The priors' blocks (:class:`posegraph.solve.unary.PriorBlocks`), None for a graph without priors."""
    landmarks: object | None = None
    """The landmark families' blocks (:class:`posegraph.solve.landmark_terms.LandmarkBlocks`), None without landmarks."""

    def hessian_slice(self, part: slice) -> tuple:
        """``(H_ii, H_jj, H_ij)`` of the edges in ``part``, each ``(k, d, d)``: ``W = w BᵀΩB``,
        ``H_jj = W``, ``H_ij = −AdᵀW``, ``H_ii = −H_ij Ad`` (what the solver assembles H from, a
        slice at a time: :func:`posegraph.solve.sparsity.hessian_values`)."""
        b, adjoint = self.jacobian_inverse[part], self.adjoint[part]
        w = np.swapaxes(b, -1, -2) @ (self.information[part] @ b)  # H_jj = Bᵀ Ω B
        if self.weights is not None:
            w *= self.weights[part, None, None]
        h_ij = np.swapaxes(adjoint, -1, -2) @ w
        np.negative(h_ij, out=h_ij)  # H_ij = −Adᵀ W
        h_ii = h_ij @ adjoint
        np.negative(h_ii, out=h_ii)  # H_ii = Adᵀ W Ad
        return h_ii, w, h_ij

    @cached_property
    def hessian_blocks(self) -> tuple:
        """``(H_ii, H_jj, H_ij)`` of every edge, each ``(m, d, d)`` (:meth:`hessian_slice`; kept apart:
        stacking them would copy them for nothing, the assembly reads them one by one)."""
        return _residuals.by_slices(self.residuals.shape[0], self.hessian_slice)  # slices, for the caches

    @property
    def hessian(self) -> np.ndarray:
        """``(m, 3, d, d)``: ``[H_ii, H_jj, H_ij]`` per edge (a stacked copy)."""
        return np.stack(self.hessian_blocks, axis=1)


def linearize(
    poses: np.ndarray,
    graph: PoseGraph,
    information: np.ndarray | None = None,
    errors: tuple[np.ndarray, np.ndarray] | None = None,
    weights: np.ndarray | None = None,
    weighted: np.ndarray | None = None,
) -> EdgeBlocks:
    """Residuals, cost and per-edge normal-equation blocks at ``poses`` ``(n, k, k)``.

    ``information`` defaults to ``graph.information``; the solver passes a C-contiguous copy made
    once (batched d×d products are several times slower on other memory layouts). ``errors`` is
    ``edge_errors(poses, graph)`` if already computed (the solver has it from evaluating the step).
    ``weights`` ``(m,)`` scales each edge's gradient and Hessian blocks (IRLS weights of a robust
    loss, see the module docstring); None is the plain least-squares system. ``weighted`` ``(m, d)`` is
    ``Ω e`` if already computed (an evaluation's, :attr:`posegraph.solve.objective.Evaluation.weighted_residuals`).
    """
    relative, residuals = edge_errors(poses, graph) if errors is None else errors
    if information is None:
        information = np.ascontiguousarray(graph.information)
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != (graph.num_edges,):
            raise ValueError(f"weights must have shape ({graph.num_edges},), got {weights.shape}")

    def compute(part):
        e = residuals[part]
        b, adjoint = residual_jacobian_factors(graph.group, e, relative[part])  # ∂e/∂δ_j = B
        omega_e = weighted_residuals(e, information[part]) if weighted is None else weighted[part]
        gradient = np.empty(e.shape[:1] + (2,) + e.shape[1:])
        g_j = gradient[:, 1]
        g_j[:] = (np.swapaxes(b, -1, -2) @ omega_e[..., None])[..., 0]  # g_j = Bᵀ Ω e
        if weights is not None:
            g_j *= weights[part, None]
        np.einsum("mji,mj->mi", adjoint, g_j, out=gradient[:, 0])  # einsum: see residuals.weighted_residuals
        np.negative(gradient[:, 0], out=gradient[:, 0])  # g_i = −Adᵀ g_j
        terms = np.einsum("mi,mi->m", e, omega_e)  # eᵀ Ω e per edge
        return b, adjoint, gradient, terms

    b, adjoint, gradient, terms = _residuals.by_slices(residuals.shape[0], compute)  # for the caches
    return EdgeBlocks(
        residuals=residuals,
        cost=0.5 * float(np.sum(terms)),
        gradient=gradient,
        jacobian_inverse=b,
        adjoint=adjoint,
        information=information,
        weights=weights,
    )
