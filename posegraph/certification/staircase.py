"""The Riemannian staircase: SE-Sync's relaxation at ranks r = d+1, d+2, … and its rounding.

Boumal, "A Riemannian low-rank method for optimization over semidefinite matrices with
block-diagonal constraints" (2015); Rosen et al., IJRR 2019, Algorithm 1. At rank r the variable is
``u`` ``(n, r, d+1)``: translations ``t_i ∈ ℝ^r`` and ``Y_i ∈ St(d, r)`` (r×d, ``Y_iᵀ Y_i = I``) — SE-Sync's
translation-explicit form — and the objective ``F = tr(X M Xᵀ)`` (:mod:`posegraph.certification.problem`).

* Riemannian gradient: ``P_Y(∇F)``, ``P_Y(Z)_i = Z_i − Y_i Sym(Y_iᵀ Z_i)`` on the Stiefel blocks,
  identity on the translations; Hessian: ``P_Y(2 Ẋ M − Ẏ SymBlockDiag(Yᵀ ∇_Y F))`` (eq. 44).
* Trust region with Steihaug-Toint truncated CG (Absil, Mahony & Sepulchre, "Optimization algorithms
  on matrix manifolds", 2008, Alg. 10-11), preconditioned by ``P_Y((M + λI)⁻¹ ·)`` rowwise (one
  CHOLMOD factor for the whole staircase: M does not depend on the rank); retraction by the polar
  factor of ``Y_i + Ẏ_i``.
* A critical point whose certificate S has a negative eigenvalue ``θ`` with eigenvector ``v`` is a
  saddle: one rank up, ``Ẋ = e_{r+1} vᵀ`` is a descent direction of curvature ``θ``; a backtracking
  line search along it starts the next level (SE-Sync's ``escape_saddle``).
* Rounding (SE-Sync's ``round_solution``): the rank-d truncated SVD ``R = Σ_d V_dᵀ`` of the rotation
  blocks, reflected when fewer than half of its blocks have positive determinant, each block
  projected onto SO(d); then the optimal translations given them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from posegraph.certification.local import translations_given_rotations
from posegraph.certification.problem import SyncProblem, euclidean_gradient, objective
from posegraph.certification.verify import Verification, certificate_matrix, lambda_blocks, verify
from posegraph.solve.linear import make_linear_solver

__all__ = ["StaircaseResult", "Preconditioner", "riemannian_staircase", "round_solution", "trust_region"]

GRADIENT_TOLERANCE = 1e-9
"""Stop the trust region when ‖grad F‖ falls below this, relative to ``max(F, 1)``."""
MAX_TRUST_REGION_ITERATIONS = 500
MAX_CG_ITERATIONS = 2000
PRECONDITIONER_REGULARISATION = 1e-6
"""λ / max diag(M) of the preconditioner M + λI (SE-Sync caps its condition number at 10⁶)."""


@dataclass
class StaircaseResult:
    """The staircase's last level and its rounding."""

    rounded: np.ndarray
    """``(n, d, d+1)`` the rounded estimate ``[t_i | R_i]``."""
    objective: float
    """``F`` at the rounded estimate."""
    lambdas: np.ndarray
    """``(n, d, d)`` Λ at the last critical point."""
    verification: Verification
    """The PSD test of S there."""
    rank: int
    """The last rank r."""
    rounding_seconds: float


def _project(u: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Tangent projection ``P_u(z)`` (module docstring)."""
    y, out = u[:, :, 1:], z.copy()
    sym = np.swapaxes(y, 1, 2) @ z[:, :, 1:]
    out[:, :, 1:] -= y @ (0.5 * (sym + np.swapaxes(sym, 1, 2)))
    return out


def _retract(u: np.ndarray, step: np.ndarray) -> np.ndarray:
    """``t + ṫ`` and the polar factor of ``Y_i + Ẏ_i``."""
    out = u + step
    left, _, right = np.linalg.svd(out[:, :, 1:], full_matrices=False)
    out[:, :, 1:] = left @ right
    return out


def _hessian(problem: SyncProblem, u: np.ndarray, gradient: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Riemannian Hessian of F at ``u`` applied to the tangent ``direction`` (``gradient`` = ∇F(u))."""
    out = euclidean_gradient(problem, direction)  # 2 Ẋ M (∇F is linear in u)
    sym = np.swapaxes(u[:, :, 1:], 1, 2) @ gradient[:, :, 1:]
    out[:, :, 1:] -= direction[:, :, 1:] @ (0.5 * (sym + np.swapaxes(sym, 1, 2)))
    return _project(u, out)


class Preconditioner:
    """``Ẋ ↦ P_u((M + λI)⁻¹ Ẋ)`` rowwise, λ = :data:`PRECONDITIONER_REGULARISATION`·max diag(M) (SE-Sync's
    regularised Cholesky preconditioner, with its 10⁶ condition-number cap); factorised once."""

    def __init__(self, problem: SyncProblem):
        matrix = certificate_matrix(problem, np.zeros((problem.num_poses, problem.d, problem.d)))  # S with Λ = 0: M
        data = matrix.data.copy()
        data[matrix.pattern.diagonal] += PRECONDITIONER_REGULARISATION * float(np.max(data[matrix.pattern.diagonal]))
        self._solver = make_linear_solver("auto", matrix.pattern)
        self._solver.factorize(data)

    def __call__(self, u: np.ndarray, z: np.ndarray) -> np.ndarray:
        n, r, q = z.shape
        columns = self._solver.solve(np.swapaxes(z, 0, 1).reshape(r, n * q).T)
        return _project(u, np.swapaxes(columns.T.reshape(r, n, q), 0, 1))


def _truncated_cg(problem, u, gradient, rgrad, radius, precondition):
    """Preconditioned Steihaug-Toint tCG for ``min ⟨g, η⟩ + ½⟨η, H η⟩`` within ``‖η‖_P ≤ radius``
    (Absil et al. Alg. 11; the norm of the preconditioner, as Manopt's ``trs_tCG``): ``(η, H η, ‖η‖_P²)``."""
    eta, h_eta = np.zeros_like(u), np.zeros_like(u)
    residual = rgrad.copy()
    z = precondition(u, residual)
    direction, z_r = -z, np.sum(z * residual)
    e_pe, e_pd, d_pd = 0.0, 0.0, z_r
    r0 = np.sqrt(np.sum(residual**2))
    for _ in range(MAX_CG_ITERATIONS):
        h_dir = _hessian(problem, u, gradient, direction)
        curvature = np.sum(direction * h_dir)
        alpha = z_r / curvature if curvature > 0 else np.inf
        e_pe_new = e_pe + 2.0 * alpha * e_pd + alpha**2 * d_pd
        if curvature <= 0 or e_pe_new >= radius**2:
            tau = (-e_pd + np.sqrt(max(e_pd**2 + d_pd * (radius**2 - e_pe), 0.0))) / d_pd
            return eta + tau * direction, h_eta + tau * h_dir, radius**2
        eta, h_eta, e_pe = eta + alpha * direction, h_eta + alpha * h_dir, e_pe_new
        residual = residual + alpha * h_dir
        if np.sqrt(np.sum(residual**2)) <= r0 * min(0.1, np.sqrt(r0)):  # κ = 0.1, θ = 1/2, as SE-Sync's STPCG
            break
        z = precondition(u, residual)
        z_r_new = np.sum(z * residual)
        beta, z_r = z_r_new / z_r, z_r_new
        direction = -z + beta * direction
        e_pd, d_pd = beta * (e_pd + alpha * d_pd), z_r + beta**2 * d_pd
    return eta, h_eta, e_pe


def trust_region(problem: SyncProblem, u: np.ndarray, precondition=None, radius: float = 1.0) -> np.ndarray:
    """A first-order critical point of F on ``(ℝ^r × St(d, r))^n`` from ``u`` (module docstring);
    ``precondition(u, z)`` a tangent preconditioner (:class:`Preconditioner`; default: none)."""
    precondition = (lambda _, z: z) if precondition is None else precondition
    value = objective(problem, u)
    for _ in range(MAX_TRUST_REGION_ITERATIONS):
        gradient = euclidean_gradient(problem, u)
        rgrad = _project(u, gradient)
        if np.sqrt(np.sum(rgrad**2)) <= GRADIENT_TOLERANCE * max(value, 1.0):
            break
        step, h_step, step_norm_sq = _truncated_cg(problem, u, gradient, rgrad, radius, precondition)
        predicted = -np.sum(rgrad * step) - 0.5 * np.sum(step * h_step)
        trial = _retract(u, step)
        trial_value = objective(problem, trial)
        gain = (value - trial_value) / predicted if predicted > 0 else -1.0
        if gain < 0.25:
            radius *= 0.25
        elif gain > 0.75 and step_norm_sq >= 0.98 * radius**2:
            radius *= 2.0
        if gain > 0.1:
            u, value = trial, trial_value
        if radius < 1e-14 or predicted <= 1e-15 * max(value, 1.0):
            break
    return u


def _escape(problem: SyncProblem, u: np.ndarray, check: Verification) -> np.ndarray | None:
    """One rank up from the saddle ``u``, along the eigenvector of S (SE-Sync's ``escape_saddle``)."""
    n, r, q = u.shape
    lifted = np.concatenate([u, np.zeros((n, 1, q))], axis=1)
    direction = np.zeros_like(lifted)
    direction[:, r, :] = check.eigenvector.reshape(n, q)
    value = objective(problem, u)
    alpha = max(16e-6, 10 * 1e-2 / abs(check.min_eigenvalue))
    while alpha >= 1e-6:
        trial = _retract(lifted, alpha * direction)
        if objective(problem, trial) < value:
            return trial
        alpha /= 2
    return None


def round_solution(problem: SyncProblem, u: np.ndarray, anchor: int = 0) -> np.ndarray:
    """SE-Sync's rounding of ``u`` ``(n, r, d+1)`` to poses ``(n, d, d+1)`` (module docstring)."""
    n, d = problem.num_poses, problem.d
    stacked = np.swapaxes(u[:, :, 1:], 0, 1).reshape(u.shape[1], n * d)  # Y = [Y_1 … Y_n], r × dn
    left, _, _ = np.linalg.svd(stacked, full_matrices=False)
    rotations = (left[:, :d].T @ stacked).reshape(d, n, d).swapaxes(0, 1)  # Σ_d V_dᵀ, by blocks
    if np.count_nonzero(np.linalg.det(rotations) > 0) < n / 2:
        rotations[:, d - 1, :] *= -1.0
    projected_u, _, projected_v = np.linalg.svd(rotations)
    flip = np.sign(np.linalg.det(projected_u @ projected_v))
    projected_u[:, :, -1] *= flip[:, None]
    rotations = projected_u @ projected_v
    out = np.zeros((n, d, d + 1))
    out[:, :, 1:] = rotations
    out[:, :, 0] = translations_given_rotations(problem, rotations, anchor)
    return out


def riemannian_staircase(problem: SyncProblem, u: np.ndarray, check: Verification, eta: float,
                         max_rank: int = 10) -> StaircaseResult:  # fmt: skip
    """Climb from the rank-d saddle ``u`` (with its failed ``check``) until S ⪰ −ηI or rank ``max_rank``."""
    rank = u.shape[1]
    lambdas = lambda_blocks(problem, u)
    precondition = Preconditioner(problem) if not check.positive_semidefinite else None
    while not check.positive_semidefinite and rank < max_rank:
        lifted = _escape(problem, u, check)
        if lifted is None:
            break
        u, rank = trust_region(problem, lifted, precondition), rank + 1
        lambdas = lambda_blocks(problem, u)
        check = verify(certificate_matrix(problem, lambdas), u, eta)
    start = time.perf_counter()
    rounded = round_solution(problem, u)
    return StaircaseResult(rounded, objective(problem, rounded), lambdas, check, rank, time.perf_counter() - start)
