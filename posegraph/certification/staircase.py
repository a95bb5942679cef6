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

from dataclasses import dataclass, field

import numpy as np

from posegraph.certification.local import refine_poses, translations_given_rotations
from posegraph.certification.problem import SyncProblem, edge_maps, objective
from posegraph.certification.verify import Verification, certificate_matrix, verify_point
from posegraph.solve.linear import make_linear_solver

__all__ = ["StaircaseResult", "DataMatrix", "riemannian_staircase", "round_solution", "trust_region"]

GRADIENT_TOLERANCE = 1e-6
"""Stop the trust region when ``⟨grad F, P grad F⟩`` (the squared gradient in the preconditioner's norm,
which has the units of F: a Newton-decrement-like measure) falls below this fraction of F."""
RELATIVE_DECREASE_TOLERANCE = 1e-5
"""… or when an accepted step lowers F by less than this fraction of F (SE-Sync's ``rel_func_decrease_tol``,
1e-6 there): the level's point is then good enough to escape from and to round; the certificate itself is
read at rank d after Newton's refinement, or from the bound, which holds at any point. (1e-4 halves the
time on the noisy grids but weakens their proven bounds by 1–2 %; 1e-6 costs 1.5–2× for the same bounds.)"""
POLISH = ((1e-10, 0.0), 50)
"""``((gradient test, decrease test), iterations)`` of the last level's second run (when it ended below the
rank cap)."""
TCG_KAPPA = 0.1
MAX_TRUST_REGION_ITERATIONS = 500
ESCAPE_ROWS = 5
"""Rows added at an escape at most, one per clearly negative eigenvalue of Q − Λ found (fewer levels to
climb: the noisy 2D grid of 900 poses took 3.1 s with 3 rows at a time, 1.9 s with 5; 8 were no faster)."""
MAX_CG_ITERATIONS = 2000
PRECONDITIONER_REGULARISATION = 1e-6
"""λ / max diag(M) of the preconditioner M + λI (SE-Sync caps its condition number at 10⁶)."""


@dataclass
class StaircaseResult:
    """The best estimate the staircase found and the best lower bound it proved."""

    best: np.ndarray
    """``(n, d, d+1)`` the rank-d estimate ``[t_i | R_i]``: the start, or the best level's rounding refined by
    Newton when that is lower — never worse than the start."""
    best_value: float
    """``F`` at :attr:`best`."""
    verification: Verification
    """The test of Q − Λ that proved the largest lower bound (the start's, or a level's)."""
    rank: int
    """The last rank r reached."""
    levels: list = field(default_factory=list)
    """Per level ``(rank, F at the critical point, F of its rounding, lower bound, θ)``."""

    @property
    def lower_bound(self) -> float:
        """The largest lower bound any level proved (:attr:`Verification.lower_bound`)."""
        return self.verification.lower_bound


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


def _hessian(u: np.ndarray, multipliers: np.ndarray, direction: np.ndarray, data: "DataMatrix") -> np.ndarray:
    """Riemannian Hessian of F at ``u`` applied to the tangent ``direction``: ``P_u(2 Ẋ M − Ẏ Sym(Yᵀ ∇_Y F))``,
    ``multipliers`` the blocks ``Sym(Y_iᵀ ∇_{Y_i} F)`` (:func:`_multipliers`, made once per point)."""
    out = data.gradient(direction)  # 2 Ẋ M (∇F is linear in u)
    out[:, :, 1:] -= direction[:, :, 1:] @ multipliers
    return _project(u, out)


def _multipliers(u: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """``(n, d, d)`` ``Sym(Y_iᵀ ∇_{Y_i} F)`` (twice Λ_i) for ``gradient`` = ∇F(u)."""
    product = np.swapaxes(u[:, :, 1:], 1, 2) @ gradient[:, :, 1:]
    return 0.5 * (product + np.swapaxes(product, 1, 2))


class DataMatrix:
    """M as a sparse matrix, for ``∇F = 2 X M``, and the factor of ``M + λ``, λ =
    :data:`PRECONDITIONER_REGULARISATION`·max diag(M) over the translation rows and over the rotation rows, for ``Ẋ ↦ P_u((M + λI)⁻¹ Ẋ)`` rowwise (SE-Sync's
    regularised Cholesky preconditioner, with its 10⁶ condition-number cap); both made once for the
    whole staircase (M does not depend on the rank)."""

    def __init__(self, problem: SyncProblem):
        matrix = certificate_matrix(problem, np.zeros((problem.num_poses, problem.d, problem.d)))  # S with Λ = 0: M
        self.sparse = matrix.sparse
        # λ apart for the translation and the rotation rows (each 10⁻⁶ of its largest diagonal entry), so
        # that metres as millimetres scale the preconditioner as they scale M: the path does not change
        diagonal = matrix.data[matrix.pattern.diagonal]
        translation = np.arange(diagonal.size) % matrix.pattern.block_size == 0
        regularisation = np.where(translation, np.max(diagonal[translation]), np.max(diagonal[~translation]))
        self._solver = make_linear_solver("auto", matrix.pattern)
        self._solver.factorize(matrix.data, PRECONDITIONER_REGULARISATION * regularisation)

    @staticmethod
    def _columns(z: np.ndarray) -> np.ndarray:
        """``(n, r, q)`` blocks → ``(nq, r)``: the rows of X as columns."""
        n, r, q = z.shape
        return np.swapaxes(z, 1, 2).reshape(n * q, r)

    @staticmethod
    def _blocks(columns: np.ndarray, shape) -> np.ndarray:
        n, r, q = shape
        return np.swapaxes(columns.reshape(n, q, r), 1, 2)

    def gradient(self, u: np.ndarray) -> np.ndarray:
        """``∇F = 2 X M`` at ``u`` ``(n, r, q)``, as blocks."""
        return self._blocks(2.0 * (self.sparse @ self._columns(u)), u.shape)

    def __call__(self, u: np.ndarray, z: np.ndarray) -> np.ndarray:
        """The preconditioned tangent ``P_u((M + λI)⁻¹ z)``."""
        return _project(u, self._blocks(self._solver.solve(self._columns(z)), z.shape))


def _truncated_cg(u, gradient, rgrad, z, radius, data: DataMatrix, value):
    """Preconditioned Steihaug-Toint tCG for ``min ⟨g, η⟩ + ½⟨η, H η⟩`` within ``‖η‖_P ≤ radius``
    (Absil et al. Alg. 11; the norm of the preconditioner, as Manopt's ``trs_tCG``), from ``z = P g``:
    ``(η, H η, ‖η‖_P²)``. It stops at ``‖r‖_P ≤ κ ‖g‖_P``, κ = 0.1 (SE-Sync's STPCG test without its
    superlinear term ``‖g‖^θ``, which has units; measured in the P-norm so that it does not depend on
    the scale of the data)."""
    eta, h_eta = np.zeros_like(u), np.zeros_like(u)
    multipliers = _multipliers(u, gradient)
    residual = rgrad.copy()
    direction, z_r = -z, np.sum(z * rgrad)
    e_pe, e_pd, d_pd = 0.0, 0.0, z_r
    target = z_r * TCG_KAPPA**2
    for _ in range(MAX_CG_ITERATIONS):
        h_dir = _hessian(u, multipliers, direction, data)
        curvature = np.sum(direction * h_dir)
        alpha = z_r / curvature if curvature > 0 else np.inf
        e_pe_new = e_pe + 2.0 * alpha * e_pd + alpha**2 * d_pd
        if curvature <= 0 or e_pe_new >= radius**2:
            tau = (-e_pd + np.sqrt(max(e_pd**2 + d_pd * (radius**2 - e_pe), 0.0))) / d_pd
            return eta + tau * direction, h_eta + tau * h_dir, radius**2
        eta, h_eta, e_pe = eta + alpha * direction, h_eta + alpha * h_dir, e_pe_new
        residual = residual + alpha * h_dir
        z = data(u, residual)
        z_r_new = np.sum(z * residual)
        if z_r_new <= target:
            break
        beta, z_r = z_r_new / z_r, z_r_new
        direction = -z + beta * direction
        e_pd, d_pd = beta * (e_pd + alpha * d_pd), z_r + beta**2 * d_pd
    return eta, h_eta, e_pe


def trust_region(problem: SyncProblem, u: np.ndarray, data: DataMatrix | None = None, radius: float | None = None,
                 tolerances: tuple[float, float] = (None, None),
                 max_iterations: int = MAX_TRUST_REGION_ITERATIONS) -> np.ndarray:  # fmt: skip
    """A first-order critical point of F on ``(ℝ^r × St(d, r))^n`` from ``u`` (module docstring):
    until ``‖grad F‖_P² ≤`` :data:`GRADIENT_TOLERANCE`·F, P the preconditioner of ``data``
    (:class:`DataMatrix`, made here if not given), or an accepted step lowers F by less than
    :data:`RELATIVE_DECREASE_TOLERANCE`·F (``tolerances`` overrides the two); ``radius`` the first trust
    radius in the P-norm (default √F); at most ``max_iterations`` iterations."""
    gradient_tolerance = GRADIENT_TOLERANCE if tolerances[0] is None else tolerances[0]
    decrease_tolerance = RELATIVE_DECREASE_TOLERANCE if tolerances[1] is None else tolerances[1]
    data = DataMatrix(problem) if data is None else data
    maps = edge_maps(problem)
    value = objective(problem, u, maps)
    radius = np.sqrt(value) if radius is None else radius
    for _ in range(max_iterations):
        gradient = data.gradient(u)
        rgrad = _project(u, gradient)
        z = data(u, rgrad)
        if np.sum(z * rgrad) <= gradient_tolerance * value:
            break
        step, h_step, step_norm_sq = _truncated_cg(u, gradient, rgrad, z, radius, data, value)
        predicted = -np.sum(rgrad * step) - 0.5 * np.sum(step * h_step)
        trial = _retract(u, step)
        trial_value = objective(problem, trial, maps)
        gain = (value - trial_value) / predicted if predicted > 0 else -1.0
        if gain < 0.25:
            radius *= 0.25
        elif gain > 0.75 and step_norm_sq >= 0.98 * radius**2:
            radius *= 2.0
        if gain > 0.1:
            decrease, u, value = value - trial_value, trial, trial_value
            if decrease <= decrease_tolerance * value:
                break
        if radius**2 < 1e-28 * value or predicted <= 1e-15 * value:
            break
    return u


def _escape(problem: SyncProblem, u: np.ndarray, check: Verification, rows: int = ESCAPE_ROWS) -> np.ndarray | None:
    """Up to ``rows`` ranks up from the saddle ``u``, each new row along one of the negative eigenvectors of
    Q − Λ (:attr:`Verification.escape_directions`; SE-Sync's ``escape_saddle`` takes one)."""
    n, r, q = u.shape
    directions = check.escape_directions[:rows]
    lifted = np.concatenate([u, np.zeros((n, len(directions), q))], axis=1)
    step = np.zeros_like(lifted)
    step[:, r:, :] = np.swapaxes(directions.reshape(len(directions), n, q), 0, 1)
    value = objective(problem, u)
    # each eigenvector's rotation part is a unit vector over all n blocks: a step of √n moves a block
    # by O(1) when it is spread evenly; halve until F falls (SE-Sync's backtracking)
    alpha = np.sqrt(n)
    while alpha >= 1e-6 * np.sqrt(n):
        trial = _retract(lifted, alpha * step)
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


def riemannian_staircase(problem: SyncProblem, u: np.ndarray, check: Verification, budget, max_rank: int = 10,
                         anchor: int = 0) -> StaircaseResult:  # fmt: skip
    """Climb from the rank-d point ``u`` (with its failed ``check``) until a level's relaxation is solved
    (Q − Λ proven above −σ with ``dn σ`` within ``budget``'s allowance,
    :class:`~posegraph.certification.verify.Budget`: no higher rank can raise the bound by more),
    an escape fails, or rank ``max_rank``. Each level's point is rounded; the best rounding is refined
    by Newton at the end and verified at rank d, which certifies it when the relaxation is tight."""
    result = StaircaseResult(u, objective(problem, u), check, u.shape[1])
    data, best_rounded = DataMatrix(problem), None
    while result.rank < max_rank and not check.positive_semidefinite:
        lifted = _escape(problem, u, check, min(ESCAPE_ROWS, max_rank - result.rank))
        if lifted is None:
            break
        u, check, best_rounded = _level(problem, lifted, data, budget, anchor, result, best_rounded)
    if best_rounded is None:
        return result
    if result.rank < max_rank:
        # the level solved, or whose escape failed, once more to the polish tolerance: its bound is the
        # one reported, and the levels' looser stop can leave it well short of the relaxation's value
        _, _, best_rounded = _level(problem, u, data, budget, anchor, result, best_rounded, POLISH)
    refined = refine_poses(problem, best_rounded, anchor)[0]
    refined[:, :, 0] = translations_given_rotations(problem, refined[:, :, 1:], anchor)
    value = objective(problem, refined)
    if value < result.best_value:
        result.best, result.best_value = refined, value
        _keep_bound(result, verify_point(problem, refined, value, budget, anchor))
    return result


def _level(problem, start, data, budget, anchor, result: StaircaseResult, best_rounded, settings=((None, None), None)):
    """One level from ``start``: the trust region, the rounding (the best kept), the test of Q − Λ (the best
    bound kept in ``result``); ``(point, its Verification, best rounding so far)``."""
    tolerances, iterations = settings
    u = trust_region(problem, start, data, tolerances=tolerances,
                     max_iterations=MAX_TRUST_REGION_ITERATIONS if iterations is None else iterations)
    result.rank = u.shape[1]
    rounded = round_solution(problem, u, anchor)
    value = objective(problem, rounded)
    if best_rounded is None or value < objective(problem, best_rounded):
        best_rounded = rounded
    check = verify_point(problem, u, min(value, result.best_value), budget, anchor)
    _keep_bound(result, check)
    result.levels.append((result.rank, objective(problem, u), value, check.lower_bound, check.min_eigenvalue))
    return u, check, best_rounded


def _keep_bound(result: StaircaseResult, check: Verification) -> None:
    """Keep ``check`` in ``result`` when its lower bound is the best so far."""
    if check.lower_bound > result.lower_bound:
        result.verification = check
