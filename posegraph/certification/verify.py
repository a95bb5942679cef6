"""The certificate: Λ(Y), S = M − Λ, and whether S is positive semidefinite (SE-Sync's verification).

At a first-order critical point ``Y`` (rank ``r ≥ d``, blocks ``Y_i`` r×d) of SE-Sync's relaxation,
its Lagrange multiplier is the block-diagonal ``Λ = SymBlockDiag(Yᵀ Y Q)`` (Rosen et al., IJRR
2019, eq. 119; ``compute_Lambda_blocks`` of SE-Sync's C++):

    ``Λ_i = Sym(Y_iᵀ (Y Q)_i) = ½ Sym(Y_iᵀ ∇_{Y_i} F)``,

with Q the reduced data matrix (translations eliminated) — equal, when the translations are
optimal, to the rotation part of ``∇F = 2 X M`` used here. The certificate matrix is, as SE-Sync
verifies it, the translation-explicit ``S = M − diag(0, Λ)`` ((d+1)n square; it is PSD exactly
when ``Q − Λ`` is, M's translation block being a connected Laplacian). ``S ⪰ 0`` proves ``Yᵀ Y``
optimal for the semidefinite relaxation, and ``tr Λ`` is then a lower bound on the optimum of the
pose-graph problem: ``F(x̂) − tr Λ`` bounds the suboptimality of any estimate x̂ (Theorem 7).

Test (SE-Sync's ``fast_verification``): S is numerically PSD when ``S + η I`` has a Cholesky
factorisation (CHOLMOD, the pattern of the pose graph with (d+1)×(d+1) blocks), ``η`` =
:data:`DEFAULT_ETA` as SE-Sync's ``min_eig_num_tol``. The minimum eigenvalue is then estimated by
block inverse iteration with that factor; when the factorisation fails, by inverse iteration with
``S + σ I`` for the smallest ``σ = 2^k η`` that factorises — its eigenvector is the direction in which
the Riemannian staircase escapes the saddle.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from posegraph.certification.problem import SyncProblem, data_matrix_blocks, euclidean_gradient
from posegraph.cholmod import NotPositiveDefiniteError
from posegraph.solve.linear import make_linear_solver
from posegraph.solve.sparsity import HessianPattern, analyze_pattern, hessian_values

__all__ = ["DEFAULT_ETA", "CertificateMatrix", "lambda_blocks", "certificate_matrix", "Verification", "verify"]

DEFAULT_ETA = 1e-3
"""SE-Sync's ``min_eig_num_tol``: S counts as PSD when ``λ_min(S) > −η``."""
RITZ_ITERATIONS = (4, 40)
"""Block inverse iterations for the minimum eigenvalue estimate (each one solve with d+3 columns) when S
is PSD (the null vectors seed the block: λ_min ≈ 0 at once) and when it is not (the eigenvector is
the staircase's escape direction)."""
MAX_SHIFT_DOUBLINGS = 60
GOLDEN_ANGLE = 2.399963229728653
"""Frequency step of the generic starting columns (an irrational multiple of π, so no column aliases)."""


def lambda_blocks(problem: SyncProblem, u: np.ndarray, gradient: np.ndarray | None = None) -> np.ndarray:
    """``(n, d, d)`` the blocks ``Λ_i = ½ Sym(Y_iᵀ ∇_{Y_i} F)`` at ``u`` ``(n, r, d+1)`` (module docstring)."""
    gradient = euclidean_gradient(problem, u) if gradient is None else gradient
    product = 0.5 * np.swapaxes(u[:, :, 1:], 1, 2) @ gradient[:, :, 1:]
    return 0.5 * (product + np.swapaxes(product, 1, 2))


@dataclass(frozen=True, eq=False)
class CertificateMatrix:
    """``S = M − diag(0, Λ)`` as the lower triangle of a block-sparse matrix on the pose graph's pattern
    (vertex ``i``'s rows: ``[t_i, Y_i columns]``, :mod:`posegraph.certification.problem`)."""

    pattern: HessianPattern
    """The block pattern (block size d+1, no vertex held)."""
    data: np.ndarray
    """``(nnz,)`` CSC values of the lower triangle of S."""

    @cached_property
    def _columns(self) -> np.ndarray:
        """``(nnz,)`` column of each stored entry (:attr:`HessianPattern.entry_columns`, made once here)."""
        return self.pattern.entry_columns

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``S x`` for ``x`` ``((d+1)n,)`` (lower triangle, its transpose, less the diagonal counted twice)."""
        p, dim, columns = self.pattern, self.pattern.dimension, self._columns
        lower = np.bincount(p.indices, weights=self.data * x[columns], minlength=dim)
        upper = np.bincount(columns, weights=self.data * x[p.indices], minlength=dim)
        return lower + upper - self.data[p.diagonal] * x

    def dense(self) -> np.ndarray:
        """S as a dense array (small graphs, tests)."""
        p, dim = self.pattern, self.pattern.dimension
        out = np.zeros((dim, dim))
        out[p.indices, self._columns] = self.data
        return out + np.tril(out, -1).T


def _diagonal_block_positions(pattern: HessianPattern, problem: SyncProblem) -> np.ndarray:
    """``(n, q, q)`` positions in ``data`` of each vertex's diagonal block (``nnz`` above the diagonal)."""
    q, m, n = pattern.block_size, problem.num_edges, problem.num_poses
    positions = pattern.hessian_positions.reshape(3, m, q, q)
    out = np.empty((n, q, q), dtype=positions.dtype)
    for side, vertices in ((1, problem.edge_to), (0, problem.edge_from)):  # edge_from wins where both
        out[vertices] = positions[side]
    return out


def certificate_matrix(problem: SyncProblem, lambdas: np.ndarray) -> CertificateMatrix:
    """S for the multiplier blocks ``lambdas`` ``(n, d, d)``."""
    n = problem.num_poses
    pattern = analyze_pattern(n, problem.edge_from, problem.edge_to, np.zeros(n, dtype=bool), problem.d + 1)
    data = np.append(hessian_values(pattern, data_matrix_blocks(problem)), 0.0)
    data[_diagonal_block_positions(pattern, problem)[:, 1:, 1:]] -= lambdas
    return CertificateMatrix(pattern, data[: pattern.nnz])


@dataclass(frozen=True)
class Verification:
    """The outcome of the PSD test of S."""

    positive_semidefinite: bool
    """Whether ``S + η I`` factorised (S numerically PSD, SE-Sync's test)."""
    min_eigenvalue: float
    """Estimate of ``λ_min(S)`` (smallest Ritz value of the block inverse iteration)."""
    eigenvector: np.ndarray
    """``((d+1)n,)`` unit vector of that Ritz value (the escape direction when negative)."""
    shift: float
    """The σ of the factorised ``S + σ I`` (η when PSD)."""


def verify(matrix: CertificateMatrix, u: np.ndarray, eta: float = DEFAULT_ETA, seed: int = 0) -> Verification:
    """Test ``S ⪰ −η I`` by Cholesky and estimate ``λ_min(S)`` (module docstring); ``u`` seeds the
    iteration with S's known null vectors (the rows of X at a critical point)."""
    solver = make_linear_solver("auto", matrix.pattern)
    diagonal = matrix.pattern.diagonal
    shift, psd = eta, True
    for _ in range(MAX_SHIFT_DOUBLINGS):
        shifted = matrix.data.copy()
        shifted[diagonal] += shift
        try:
            solver.factorize(shifted)
            break
        except NotPositiveDefiniteError:
            psd, shift = False, 2.0 * shift
    else:
        raise NotPositiveDefiniteError("the certificate matrix did not factorise for any shift")
    value, vector = _smallest_ritz_pair(matrix, solver, u, seed, RITZ_ITERATIONS[0 if psd else 1])
    return Verification(psd, value, vector, shift)


def _smallest_ritz_pair(matrix: CertificateMatrix, solver, u: np.ndarray, seed: int, iterations: int):
    """Block inverse iteration with the factorised ``S + σ I``: the smallest Ritz pair of S."""
    dim = matrix.pattern.dimension
    rows = np.swapaxes(u, 0, 1).reshape(u.shape[1], -1).T  # (dim, r): the rows of X
    # three fixed, deterministic, generic columns (numpy.random would cost ~17 ms of imports per process)
    generic = np.cos(np.outer(np.arange(dim) + 1.0, (seed + np.arange(1, 4)) * GOLDEN_ANGLE))
    block = np.concatenate([rows, generic], axis=1)
    for _ in range(iterations):
        block, _ = np.linalg.qr(solver.solve(block))
    applied = np.stack([matrix.matvec(column) for column in block.T], axis=1)
    values, vectors = np.linalg.eigh(block.T @ applied)
    vector = block @ vectors[:, 0]
    return float(values[0]), vector / np.linalg.norm(vector)
