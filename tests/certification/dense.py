"""Dense reference constructions of SE-Sync's matrices, written from the paper's definitions
(Rosen et al., IJRR 2019, eqs. 13-16 and 119) in SE-Sync's own layout ``X = [t | R]``, for comparison
with :mod:`posegraph.certification`'s block-sparse ones on small graphs."""

from __future__ import annotations

import numpy as np


def sesync_data_matrix(problem) -> np.ndarray:
    """``M = [[L(W^τ), Ṽ], [Ṽᵀ, L(G̃^ρ) + Σ̃]]`` ``((d+1)n, (d+1)n)``, translations first (eq. 16)."""
    n, d = problem.num_poses, problem.d
    m = np.zeros(((d + 1) * n, (d + 1) * n))
    rot = lambda k: slice(n + d * k, n + d * (k + 1))  # noqa: E731
    for i, j, r, t, kappa, tau in zip(problem.edge_from, problem.edge_to, problem.rotations, problem.translations,
                                      problem.kappa, problem.tau):  # fmt: skip
        m[i, i] += tau
        m[j, j] += tau
        m[i, j] -= tau
        m[j, i] -= tau
        m[i, rot(i)] += tau * t
        m[j, rot(i)] -= tau * t
        m[rot(i), i] += tau * t
        m[rot(i), j] -= tau * t
        m[rot(i), rot(i)] += kappa * np.eye(d) + tau * np.outer(t, t)
        m[rot(j), rot(j)] += kappa * np.eye(d)
        m[rot(i), rot(j)] -= kappa * r
        m[rot(j), rot(i)] -= kappa * r.T
    return m


def reduced_data_matrix(problem) -> np.ndarray:
    """``Q = L(G̃^ρ) + Σ̃ − Ṽᵀ L(W^τ)† Ṽ`` ``(dn, dn)``: the translations eliminated (eq. 20)."""
    n = problem.num_poses
    m = sesync_data_matrix(problem)
    laplacian, coupling, rotations = m[:n, :n], m[:n, n:], m[n:, n:]
    return rotations - coupling.T @ np.linalg.pinv(laplacian) @ coupling


def interleave(n: int, d: int) -> np.ndarray:
    """The permutation taking SE-Sync's ``[t_1 … t_n | R_1 … R_n]`` columns to the vertex-interleaved
    ``[t_1, R_1, t_2, R_2, …]``: ``ours = sesync[perm]``."""
    perm = []
    for k in range(n):
        perm += [k] + list(range(n + d * k, n + d * (k + 1)))
    return np.array(perm)


def sesync_lambda(problem, rotations: np.ndarray) -> np.ndarray:
    """``(n, d, d)`` Λ_i = Sym((Q Yᵀ)_i Y_i) for ``Y = [R_1 … R_n]`` (rank d: ``rotations`` (n, d, d))."""
    n, d = problem.num_poses, problem.d
    y = np.concatenate(list(rotations), axis=1)
    product = reduced_data_matrix(problem) @ y.T @ y
    blocks = np.stack([product[d * k: d * (k + 1), d * k: d * (k + 1)] for k in range(n)])
    return 0.5 * (blocks + np.swapaxes(blocks, 1, 2))
