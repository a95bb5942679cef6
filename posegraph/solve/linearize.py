"""Per-edge blocks of the Gauss-Newton normal equations, all edges in one batch.

For an edge with Jacobians ``A_i = ∂e/∂δ_i``, ``A_j = ∂e/∂δ_j`` (see
:mod:`posegraph.solve.residuals`) and information Ω, its share of
``H = Jᵀ Ω J`` and ``g = Jᵀ Ω e`` is::

    H_ii = A_iᵀ Ω A_i,  H_jj = A_jᵀ Ω A_j,  H_ij = A_iᵀ Ω A_j  (H_ji = H_ijᵀ),
    g_i  = A_iᵀ Ω e,    g_j  = A_jᵀ Ω e.

Because ``A_j = Jr⁻¹(e) =: B`` and ``A_i = −B · Ad`` with ``Ad = Ad(X_j⁻¹ X_i)``,
every product goes through ``W = Bᵀ Ω B`` and ``w = Bᵀ Ω e``::

    H_jj = W,  H_ij = −Adᵀ W,  H_ii = Adᵀ W Ad = −H_ij Ad,  g_j = w,  g_i = −Adᵀ w,

four batched 6×6 products per edge instead of forming ``A_i`` and three
weighted products.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from posegraph.graph import PoseGraph
from posegraph.lie import se3
from posegraph.solve import residuals as _residuals
from posegraph.solve.residuals import edge_errors

__all__ = ["EdgeBlocks", "linearize"]


@dataclass(frozen=True, eq=False)
class EdgeBlocks:
    """The linearisation of every edge at one set of poses.

    The gradient blocks are computed at once; the Hessian blocks on first use of
    :attr:`hessian_blocks` (then kept): a solver that finds from the gradient alone that it has
    converged (:mod:`posegraph.solve.optimizer`, Newton decrement) never pays for them.
    """

    residuals: np.ndarray
    """``(m, 6)`` residuals ``e``."""
    cost: float
    """``½ Σ eᵀ Ω e``."""
    gradient: np.ndarray
    """``(m, 2, 6)``: ``[g_i, g_j]`` per edge."""
    jacobian_inverse: np.ndarray
    """``(m, 6, 6)``: ``B = Jr⁻¹(e) = ∂e/∂δ_j``."""
    adjoint: np.ndarray
    """``(m, 6, 6)``: ``Ad(X_j⁻¹ X_i)`` (so ``∂e/∂δ_i = −B·Ad``)."""
    information: np.ndarray
    """``(m, 6, 6)``: Ω, C-contiguous."""

    @cached_property
    def hessian_blocks(self) -> tuple:
        """``(H_ii, H_jj, H_ij)``, each ``(m, 6, 6)``: ``W = BᵀΩB``, ``H_jj = W``, ``H_ij = −AdᵀW``,
        ``H_ii = −H_ij Ad`` (kept apart: stacking them would copy ~5 MB per iteration on a
        6,000-edge graph for nothing, the assembly reads them one by one)."""
        def compute(part):
            b, adjoint = self.jacobian_inverse[part], self.adjoint[part]
            w = np.swapaxes(b, -1, -2) @ (self.information[part] @ b)  # H_jj = Bᵀ Ω B
            h_ij = np.swapaxes(adjoint, -1, -2) @ w
            np.negative(h_ij, out=h_ij)  # H_ij = −Adᵀ W
            h_ii = h_ij @ adjoint
            np.negative(h_ii, out=h_ii)  # H_ii = Adᵀ W Ad
            return h_ii, w, h_ij

        return _residuals.by_slices(self.residuals.shape[0], compute)  # slices, for the caches

    @property
    def hessian(self) -> np.ndarray:
        """``(m, 3, 6, 6)``: ``[H_ii, H_jj, H_ij]`` per edge (a stacked copy)."""
        return np.stack(self.hessian_blocks, axis=1)


def linearize(
    poses: np.ndarray,
    graph: PoseGraph,
    information: np.ndarray | None = None,
    errors: tuple[np.ndarray, np.ndarray] | None = None,
) -> EdgeBlocks:
    """Residuals, cost and per-edge normal-equation blocks at ``poses`` ``(n, 4, 4)``.

    ``information`` defaults to ``graph.information``; the solver passes a C-contiguous copy made
    once (batched 6×6 products are several times slower on other memory layouts). ``errors`` is
    ``edge_errors(poses, graph)`` if already computed (the solver has it from evaluating the step).
    """
    relative, residuals = edge_errors(poses, graph) if errors is None else errors
    if information is None:
        information = np.ascontiguousarray(graph.information)
    def compute(part):
        e = residuals[part]
        b = se3.right_jacobian_inverse(e)  # ∂e/∂δ_j = B
        adjoint = se3.adjoint(se3.inverse(relative[part]))  # Ad(X_j⁻¹ X_i)
        omega_e = information[part] @ e[..., None]
        g_j = np.swapaxes(b, -1, -2) @ omega_e  # g_j = Bᵀ Ω e
        g_i = -(np.swapaxes(adjoint, -1, -2) @ g_j)  # g_i = −Adᵀ g_j
        terms = np.einsum("mi,mi->m", e, omega_e[..., 0])  # eᵀ Ω e per edge
        return b, adjoint, np.stack([g_i[..., 0], g_j[..., 0]], axis=1), terms

    b, adjoint, gradient, terms = _residuals.by_slices(residuals.shape[0], compute)  # for the caches
    cost = 0.5 * float(np.sum(terms))
    return EdgeBlocks(
        residuals=residuals,
        cost=cost,
        gradient=gradient,
        jacobian_inverse=b,
        adjoint=adjoint,
        information=information,
    )
