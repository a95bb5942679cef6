"""The certificate: Λ(Y), S = M − diag(0, Λ), and a proven lower bound on λ_min(Q − Λ).

At a first-order critical point ``Y`` (rank ``r ≥ d``, blocks ``Y_i`` r×d) of SE-Sync's relaxation,
its Lagrange multiplier is the block-diagonal ``Λ = SymBlockDiag(Yᵀ Y Q)`` (Rosen et al., IJRR
2019, eq. 119; ``compute_Lambda_blocks`` of SE-Sync's C++):

    ``Λ_i = Sym(Y_iᵀ (Y Q)_i) = ½ Sym(Y_iᵀ ∇_{Y_i} F)``,

with Q the reduced data matrix (translations eliminated) — equal, when the translations are
optimal, to the rotation part of ``∇F = 2 X M`` used here.

**Weak duality with slack.** For *any* symmetric block-diagonal Λ and any feasible Z of the
relaxation (``Z ⪰ 0``, ``Z_ii = I_d``): ``tr(QZ) = tr((Q − Λ)Z) + tr Λ ≥ tr Λ + dn·min(λ_min(Q − Λ), 0)``,
since ``tr Z = dn``. So if ``Q − Λ + σI ≻ 0`` then every pose estimate — indeed the relaxation's
optimum — has ``F ≥ tr Λ − dn·σ``: :attr:`Verification.lower_bound`. This holds whether or not the
point is optimal; at an optimal point of a tight relaxation it equals F up to ``dn·σ``.

**The test is on Q − Λ, not on S.** ``Q − Λ`` is the Schur complement of the translation block of
``S = M − diag(0, Λ)`` ((d+1)n square, vertex-interleaved, the pose graph's block pattern). With
the anchor's translation held (``α e eᵀ`` added to its translation diagonal, α > 0: it leaves the
Schur complement unchanged because M's translation block is a connected Laplacian ``L`` with
``1ᵀ [L Ṽ] = 0``) and σ added to the *rotation* diagonal only,

    ``P_σ = S + α e_a e_aᵀ + σ diag(0, I)  ≻ 0   ⇔   Q − Λ + σ I ≻ 0``

(Haynsworth: the translation block ``L + α e eᵀ`` is positive definite). So one sparse Cholesky of
``P_σ`` (CHOLMOD, no dense Q) proves ``λ_min(Q − Λ) > −σ``. Unlike SE-Sync's test on ``S + ηI``
(shift on every row), this does not depend on the units of the translations nor on whether they
are eliminated, and a shift relative to the data (below) makes it invariant under scaling all
information: S's translation rows scale with ``τ ∝ 1/metre²``, Q and Λ do not.

**The minimum eigenvalue** is estimated with the same factor: block inverse (subspace) iteration on
``(Q − Λ + σI)⁻¹`` in rotation space — ``P_σ⁻¹ [0; x]`` has rotation part ``(Q − Λ + σI)⁻¹ x`` and
translation part the optimal translations for it — seeded with the rows of Y (Q − Λ's kernel at a
critical point) and generic columns, with Rayleigh-Ritz on Q − Λ each step (``S w`` of such a
full vector has rotation part ``(Q − Λ) y`` and translation part 0). It stops when the smallest
Ritz pair's residual ``‖(Q − Λ)v − θv‖`` is below :data:`RESIDUAL_TOLERANCE` of the mean rotation
diagonal: then Q − Λ has an eigenvalue in ``[θ − ρ, θ + ρ]``, and the factor proves none below −σ.

Shifts tried: :data:`SHIFT_FLOOR` of the mean rotation diagonal of M (round-off: it succeeds at a
certified point), then ``budget`` (the largest shift the caller's tolerance allows), then ×8 until
the factorisation succeeds; after a failure, one more factorisation at ``−θ + ρ`` (the eigenvalue
estimate) tightens the proven σ. Up to the Cholesky factorisation's round-off (backward error
~ε‖P_σ‖, below :data:`SHIFT_FLOOR`), the bound is rigorous.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from posegraph.certification.problem import SyncProblem, data_matrix_blocks, euclidean_gradient
from posegraph.linalg.cholmod import NotPositiveDefiniteError
from posegraph.solve.linear import make_linear_solver
from posegraph.solve.sparsity import HessianPattern, analyze_pattern, hessian_values

__all__ = ["DEFAULT_TOLERANCE", "CertificateMatrix", "lambda_blocks", "certificate_matrix", "Verification", "verify",
           "data_scale", "Budget", "verify_point"]  # fmt: skip

DEFAULT_TOLERANCE = 1e-6
"""η: certified when the proven lower bound L has ``F − L ≤ η F`` (plus round-off, :data:`ROUND_OFF`)."""
ROUND_OFF = 1e-12
"""Gap allowed beyond ``η F``, relative to :func:`data_scale` (``tr`` of M's rotation block): what
rounding alone makes of ``F − tr Λ`` (Λ's entries are sums of ~κ·degree terms), so that a noise-free
graph (F = 0 to round-off) certifies. It scales with the information and not with the units."""
SHIFT_FLOOR = 1e-13
"""The first shift tried, relative to the mean rotation diagonal of M: above Cholesky's round-off on
the exactly singular Q − Λ of a certified point, and small enough that its slack ``dn σ`` stays
under :data:`ROUND_OFF`."""
SHIFT_GROWTH = 8.0
MAX_SHIFT_STEPS = 40
RESIDUAL_TOLERANCE = 1e-9
"""Stop the eigenvalue iteration when the Ritz residual is below this, relative to the mean rotation diagonal."""
MAX_ITERATIONS = (8, 100)
"""Subspace iterations at most when the first shift factorises (the kernel seeds converge at once)
and when it does not (a negative eigenvalue to find: the staircase's escape direction)."""
GENERIC_COLUMNS = 3
GOLDEN_ANGLE = 2.399963229728653
"""Frequency step of the generic starting columns (an irrational multiple of π, so no column aliases)."""


def lambda_blocks(problem: SyncProblem, u: np.ndarray, gradient: np.ndarray | None = None) -> np.ndarray:
    """``(n, d, d)`` the blocks ``Λ_i = ½ Sym(Y_iᵀ ∇_{Y_i} F)`` at ``u`` ``(n, r, d+1)`` (module docstring)."""
    gradient = euclidean_gradient(problem, u) if gradient is None else gradient
    product = 0.5 * np.swapaxes(u[:, :, 1:], 1, 2) @ gradient[:, :, 1:]
    return 0.5 * (product + np.swapaxes(product, 1, 2))


def data_scale(problem: SyncProblem) -> float:
    """``tr`` of M's rotation block, ``Σ_e 2dκ_e + τ_e‖t̃_e‖²``: the size of F's data, scaled with the
    information and invariant under a change of units (the unit of :data:`ROUND_OFF` and the shifts)."""
    d = problem.d
    return float(np.sum(2 * d * problem.kappa + problem.tau * np.sum(problem.translations**2, axis=1)))


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

    @cached_property
    def sparse(self):
        """S as a symmetric scipy CSR matrix (the staircase's products; the verification needs no scipy)."""
        import scipy.sparse as sp

        p = self.pattern
        lower = sp.csc_matrix((self.data, p.indices, p.indptr), shape=(p.dimension, p.dimension))
        return (lower + lower.T - sp.diags(self.data[p.diagonal])).tocsr()

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``S x`` for ``x`` ``((d+1)n,)`` or ``((d+1)n, k)``: by scipy's sparse product once scipy.sparse is
        loaded (the staircase loads it; 20–40× faster), else by bincount, column by column (the lower
        triangle, its transpose, less the diagonal counted twice), so that certifying at rank d imports no scipy."""
        if "scipy.sparse" in sys.modules:
            return self.sparse @ x
        if x.ndim == 2:
            return np.stack([self.matvec(column) for column in x.T], axis=1)
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

    @property
    def rotation_rows(self) -> np.ndarray:
        """``(dn,)`` the rows of S that belong to rotation (Y) columns, in order."""
        q = self.pattern.block_size
        return np.flatnonzero(np.arange(self.pattern.dimension) % q)


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
    """What the test of ``Q − Λ`` found (module docstring)."""

    positive_semidefinite: bool
    """Whether ``Q − Λ + σI ≻ 0`` was proven for the ``budget`` shift asked for (or the floor): the slack
    ``dn σ`` within the caller's tolerance."""
    min_eigenvalue: float
    """θ: the smallest Ritz value of ``Q − Λ`` found (its smallest eigenvalue to within :attr:`residual`)."""
    residual: float
    """``‖(Q − Λ)v − θ v‖`` for the unit Ritz vector v: Q − Λ has an eigenvalue within this of θ."""
    proven_shift: float
    """σ ≥ 0 with ``Q − Λ + σI ≻ 0`` proven by Cholesky: ``λ_min(Q − Λ) > −σ``."""
    dual_bound: float
    """``tr Λ``."""
    lower_bound: float
    """``tr Λ − dn σ``: a lower bound on the global minimum of F (module docstring)."""
    escape_directions: np.ndarray
    """``(k, (d+1)n)`` the vectors ``[t; v]`` with v a unit Ritz vector and t its optimal translations, so that
    ``wᵀ S w = vᵀ(Q − Λ)v``: θ's first, then those of the Ritz values at most a tenth of θ < 0 (k = 1 when
    θ ≥ 0); the staircase's escape directions."""
    factorizations: int
    """Cholesky factorisations tried."""

    @property
    def eigenvector(self) -> np.ndarray:
        """``((d+1)n,)`` θ's ``[t; v]`` (the first of :attr:`escape_directions`)."""
        return self.escape_directions[0]


def verify(matrix: CertificateMatrix, u: np.ndarray, lambdas: np.ndarray, budget: float, scale: float,
           anchor: int = 0) -> Verification:  # fmt: skip
    """Prove ``λ_min(Q − Λ) > −σ`` for the smallest σ tried and estimate λ_min (module docstring).

    ``u`` ``(n, r, d+1)``: the point (its rows seed the iteration); ``lambdas`` its Λ blocks;
    ``budget``: the largest σ whose slack ``dn σ`` the caller's tolerance allows (``positive_semidefinite``
    says whether it was proven); ``scale``: :func:`data_scale`.
    """
    dn = lambdas.shape[0] * lambdas.shape[1]
    floor = SHIFT_FLOOR * scale / dn
    solver = make_linear_solver("auto", matrix.pattern)
    shift, failed, tried = _first_factorisation(matrix, solver, anchor, [floor, max(budget, floor)])
    psd = shift <= max(budget, floor)
    iterations = MAX_ITERATIONS[0 if psd else 1]
    # a failed shift proves an eigenvalue at or below −failed: iterate until the Ritz value is there too
    value, residual, vectors = _smallest_ritz_pair(matrix, solver, u, iterations, RESIDUAL_TOLERANCE * scale / dn,
                                                   -failed)  # fmt: skip
    tighter = max(-value, 0.0) + residual + floor
    if tighter < shift:
        tried += 1
        try:
            _factorize(matrix, solver, anchor, tighter)
            shift = tighter
        except NotPositiveDefiniteError:
            pass
    trace = float(np.trace(lambdas, axis1=1, axis2=2).sum())
    return Verification(bool(psd), value, residual, shift, trace, trace - dn * shift, vectors, tried)


def _factorize(matrix: CertificateMatrix, solver, anchor: int, shift: float) -> None:
    """Factorise ``P_σ`` (module docstring); :class:`NotPositiveDefiniteError` when it is not positive definite."""
    q, dim = matrix.pattern.block_size, matrix.pattern.dimension
    translation = np.arange(dim) % q == 0
    diagonal = np.where(translation, 0.0, shift)
    diagonal[anchor * q] = float(np.mean(matrix.data[matrix.pattern.diagonal][translation]))
    solver.factorize(matrix.data, diagonal)


def _first_factorisation(matrix, solver, anchor: int, shifts: list[float]) -> tuple[float, float, int]:
    """``(σ, the largest σ that failed (−inf: none), factorisations tried)``: the first of ``shifts``, then
    ×:data:`SHIFT_GROWTH`, whose ``P_σ`` factorises."""
    tried, failed = 0, -np.inf
    candidates = list(dict.fromkeys(shifts)) + [shifts[-1] * SHIFT_GROWTH**k for k in range(1, MAX_SHIFT_STEPS)]
    for shift in candidates:
        tried += 1
        try:
            _factorize(matrix, solver, anchor, shift)
            return shift, failed, tried
        except NotPositiveDefiniteError:
            failed = shift
    raise NotPositiveDefiniteError(f"the certificate matrix did not factorise for any shift up to {failed:.3g}")


def _orthonormalising(columns: np.ndarray) -> np.ndarray:
    """``T`` ``(k, k)`` with ``columns @ T`` orthonormal: CholeskyQR2 (two passes of ``R⁻¹`` from the Cholesky
    factor of the Gram matrix; Fukaya et al. 2014) — one small Gram matrix each, where Householder QR of
    a tall block costs ~20× more — with an eigenvalue fallback for a rank-deficient block."""
    transform = np.eye(columns.shape[1])
    for _ in range(2):
        gram = columns.T @ columns
        try:
            step = np.linalg.inv(np.linalg.cholesky(gram).T)
        except np.linalg.LinAlgError:
            values, vectors = np.linalg.eigh(gram)
            keep = values > 1e-14 * values[-1]
            step = np.zeros_like(gram)
            step[:, keep] = vectors[:, keep] / np.sqrt(values[keep])
        columns, transform = columns @ step, transform @ step
    return transform


def _smallest_ritz_pair(matrix: CertificateMatrix, solver, u: np.ndarray, iterations: int, tolerance: float,
                        ceiling: float = np.inf):  # fmt: skip
    """``(θ, residual, [[t; v], …])`` (v a unit Ritz vector, t its optimal translations; θ's first, then those
    of the other clearly negative Ritz values): subspace iteration with the factorised ``P_σ`` (module docstring),
    until the smallest Ritz pair's residual is below ``tolerance`` and its value at most ``ceiling``."""
    rows = matrix.rotation_rows
    dim, r = matrix.pattern.dimension, u.shape[1]
    seeds = np.swapaxes(u, 0, 1).reshape(r, -1).T[rows]  # (dn, r): the rows of Y
    # fixed, deterministic, generic columns (numpy.random would cost ~17 ms of imports per process)
    generic = np.cos(np.outer(np.arange(rows.size) + 1.0, np.arange(1, GENERIC_COLUMNS + 1) * GOLDEN_ANGLE))
    block = np.linalg.qr(np.concatenate([seeds, generic], axis=1))[0]
    for _ in range(iterations):
        full = np.zeros((dim, block.shape[1]))
        full[rows] = block
        full = solver.solve(full)
        full = full @ _orthonormalising(full[rows])  # rotation part orthonormal, translations follow linearly
        basis = full[rows]
        applied = matrix.matvec(full)[rows]
        ritz = basis.T @ applied
        values, vectors = np.linalg.eigh(0.5 * (ritz + ritz.T))
        residuals = np.linalg.norm(applied @ vectors - (basis @ vectors) * values, axis=0)
        block = basis @ vectors
        if residuals[0] <= tolerance and values[0] <= ceiling:
            break
    # the Ritz vectors of clearly negative values (at least a tenth of the smallest): escape directions
    count = max(1, int(np.count_nonzero(values <= 0.1 * min(values[0], 0.0)))) if values[0] < 0 else 1
    chosen = full @ vectors[:, :count]
    return float(values[0]), float(residuals[0]), (chosen / np.linalg.norm(chosen[rows], axis=0)).T


@dataclass(frozen=True)
class Budget:
    """The certification tolerance for one component: ``F − L ≤ eta F + ROUND_OFF scale``."""

    eta: float
    scale: float
    """:func:`~posegraph.certification.verify.data_scale` of the component."""

    def allowed(self, value: float) -> float:
        """The largest gap ``F − L`` certified at ``F = value``."""
        return self.eta * max(value, 0.0) + ROUND_OFF * self.scale

    def shift(self, value: float, dn: int) -> float:
        """The σ whose slack ``dn σ`` is the whole allowance at ``F = value``: a level whose Q − Λ is proven
        above −σ is solved (no higher rank can raise its bound by more than the tolerance)."""
        return self.allowed(value) / dn


def verify_point(problem: SyncProblem, u: np.ndarray, value: float, budget: Budget, anchor: int = 0) -> Verification:
    """The :class:`Verification` of the critical point ``u`` ``(n, r, d+1)`` whose rounded estimate has F = ``value``."""
    lambdas = lambda_blocks(problem, u)
    dn = lambdas.shape[0] * lambdas.shape[1]
    return verify(certificate_matrix(problem, lambdas), u, lambdas, budget.shift(value, dn), budget.scale, anchor)
