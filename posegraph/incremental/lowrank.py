"""Solving with the held factor when a few edges' blocks are outside the held pattern.

A loop closure ``(i, j)`` whose block ``H_ij`` is not in the pattern the symbolic analysis was made for
would need a new analysis. Instead the edge is left out of the factorised matrix ``A`` (its gradient
stays in ``g``: the gradient needs no pattern) and put back exactly as a low-rank term. An edge's
Hessian is ``w JᵀΩJ`` with ``J = [A_i, A_j]`` ``(d, 2d)``, ``A_j = B = Jr⁻¹(e)``, ``A_i = −B·Ad``
(:mod:`posegraph.solve.linearize`), so with ``w Ω = L Lᵀ`` it is ``U_e U_eᵀ``, ``U_e = Jᵀ L`` ``(2d, d)``
on the rows of ``i`` and ``j``. With ``U`` ``(D, k)`` the ``U_e`` of the ``p`` left-out edges side by side
(``k = p·d``), ``H = A + U Uᵀ`` and, by the Woodbury identity,

    H⁻¹ b = x − Z C⁻¹ Uᵀ x,   x = A⁻¹ b,   Z = A⁻¹ U (D, k),   C = I + Uᵀ Z (k, k, positive definite),

``Z`` and ``C⁻¹`` made once per numeric factorisation (k solves with the held factor) and reused by every
solve on it. ``A`` must stay positive definite without the left-out edges (they close loops; odometry
keeps the graph connected); where it is not, the caller analyses again with every edge in the pattern.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LowRankCorrection", "edge_factors"]


def edge_factors(blocks, edges: np.ndarray, ci: np.ndarray, cj: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray]:
    """``(rows (2dp,), values (2dp, k))``: ``U`` of the ``p`` edges ``edges`` of the linearisation ``blocks``
    (:class:`~posegraph.solve.linearize.EdgeBlocks`), joining free variables ``ci``, ``cj`` ``(p,)``, as the
    scalar row of each of its stored entries and their values (edge ``e``'s columns ``e·d .. e·d + d``;
    rows may repeat across edges, each with its own columns)."""
    b, adjoint = blocks.jacobian_inverse[edges], blocks.adjoint[edges]
    lower = np.linalg.cholesky(blocks.information[edges])
    if blocks.weights is not None:  # w Ω = (√w L)(√w L)ᵀ, w = ρ' ≥ 0
        lower = lower * np.sqrt(blocks.weights[edges])[:, None, None]
    u_j = np.swapaxes(b, 1, 2) @ lower  # A_jᵀ L
    u_i = -np.swapaxes(adjoint, 1, 2) @ u_j  # A_iᵀ L = −Adᵀ Bᵀ L
    p = edges.shape[0]
    values = np.zeros((p, 2, d, p, d))
    values[np.arange(p), 0, :, np.arange(p), :] = u_i
    values[np.arange(p), 1, :, np.arange(p), :] = u_j
    rows = d * np.stack([ci, cj], axis=1)[:, :, None] + np.arange(d)
    return rows.reshape(-1), values.reshape(2 * d * p, p * d)


class LowRankCorrection:
    """``H⁻¹ b`` from ``x = A⁻¹ b`` for ``H = A + U Uᵀ`` (module docstring).

    ``solve``: ``(D, r) -> (D, r)``, ``A⁻¹`` by the held factor; ``rows``, ``values``: ``U`` from
    :func:`edge_factors`; ``dimension`` D.
    """

    def __init__(self, solve, rows: np.ndarray, values: np.ndarray, dimension: int):
        u = np.zeros((dimension, values.shape[1]))
        np.add.at(u, rows, values)
        self.z = solve(u)  # A⁻¹ U
        self.rows, self.values = rows, values
        self.inverse = np.linalg.inv(np.eye(values.shape[1]) + values.T @ self.z[rows])  # C⁻¹

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``x − Z C⁻¹ Uᵀ x`` for ``x = A⁻¹ b`` ``(D,)`` or ``(D, r)``: ``H⁻¹ b``."""
        return x - self.z @ (self.inverse @ (self.values.T @ x[self.rows]))
