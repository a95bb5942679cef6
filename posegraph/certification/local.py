"""A local minimiser of SE-Sync's objective over poses (rank d): damped Newton on SE(d)^n.

``F(t, R) = Σ_e ‖E_e‖_F²`` (:mod:`posegraph.certification.problem`) is quadratic in ``u_i = [t_i | R_i]``;
with the retraction ``t_i ← t_i + ṫ_i``, ``R_i ← R_i Exp(δ_i)`` (right perturbation, the project's
convention) and ``x_i = [ṫ_i; δ_i]`` (d + d(d−1)/2 per vertex), ``u_i(x) = u_i + [ṫ_i | R_i δ_i^] +
[0 | ½ R_i (δ_i^)²] + O(|x|³)``, so the exact Hessian of ``F ∘ retraction`` at ``x = 0`` is

    ``H = 2 Jᵀ J + C``,   ``C_i[a, b] = ⟨∇_{R_i} F, R_i Sym(G_a G_b)⟩``  (block-diagonal),

``J`` the Jacobian of the residuals ``E_e`` in ``x`` and ``G_a`` the generators of so(d). Its
block sparsity is the pose graph's, so it is assembled and factorised with the solver's
:func:`~posegraph.solve.sparsity.analyze_pattern` and CHOLMOD (one vertex held: the problem is
invariant under a global rigid motion). Newton steps with Levenberg damping added only when the
factorisation fails or the cost rises converge quadratically; the certificate needs the gradient
near zero (Λ is read from it), which a few Newton steps give to round-off.
"""

from __future__ import annotations

import numpy as np

from posegraph.certification.problem import SyncProblem, edge_maps, edge_residuals, objective, scatter_to_vertices
from posegraph.linalg.cholmod import NotPositiveDefiniteError
from posegraph.solve.linear import make_linear_solver
from posegraph.solve.sparsity import analyze_pattern, gradient_values, hessian_values

__all__ = ["generators", "newton_blocks", "refine_poses", "translations_given_rotations", "retract_poses"]

MAX_NEWTON_ITERATIONS = 100
RELATIVE_DECREMENT_TOLERANCE = 1e-10
"""Take the last step and stop once the Newton decrement ``−gᵀΔ`` is below this fraction of F: the
cost then agrees with the optimum's to ~10 digits, and after that quadratically convergent step
the gradient is at round-off."""
MIN_DAMPING, MAX_DAMPING = 1e-6, 1e10
"""Marquardt damping μ (relative to diag(H)): the least used when a Newton step fails, and the most tried."""


def generators(d: int) -> np.ndarray:
    """``(k, d, d)`` the basis of so(d) matching the project's ``hat`` (k = 3 for d = 3, 1 for d = 2)."""
    from posegraph.lie import so2, so3

    module = so3 if d == 3 else so2
    k = d * (d - 1) // 2
    return module.hat(np.eye(k))


def _side_jacobian(rotations: np.ndarray, b: np.ndarray, gens: np.ndarray) -> np.ndarray:
    """``(m, d(d+1), p)``: ``∂ vec(E_e) / ∂[ṫ; δ]`` of one end with rotation ``(m, d, d)`` and map ``b``."""
    m, d = rotations.shape[0], rotations.shape[1]
    d_translation = np.einsum("rc,mq->mrqc", np.eye(d), b[:, :, 0])
    rotated = rotations[:, None] @ gens[None]  # (m, k, d, d): R G_a
    d_rotation = np.einsum("mark,mqk->mrqa", rotated, b[:, :, 1:])
    return np.concatenate([d_translation, d_rotation], axis=-1).reshape(m, d * (d + 1), -1)


def newton_blocks(problem: SyncProblem, u: np.ndarray, maps, gens: np.ndarray):
    """Per-edge ``(hessian blocks (m, 3, p, p) [H_ii, H_jj, H_ij], gradient blocks (m, 2, p), F)`` at ``u``."""
    d = problem.d
    residuals = edge_residuals(problem, u, maps)
    flat = residuals.reshape(residuals.shape[0], -1)
    symmetric = 0.5 * (gens[:, None] @ gens[None] + gens[None] @ gens[:, None])  # (k, k, d, d)
    sides, gradients, corrections = [], [], []
    for vertices, b in zip((problem.edge_from, problem.edge_to), maps):
        rotations = u[vertices, :, 1:]
        jac = _side_jacobian(rotations, b, gens)
        sides.append(jac)
        gradients.append(2.0 * np.einsum("mxp,mx->mp", jac, flat))
        euclid = 2.0 * (residuals @ b)[:, :, 1:]  # ∂F_e/∂R of this end
        weight = np.swapaxes(rotations, 1, 2) @ euclid
        corrections.append(np.einsum("mkl,abkl->mab", weight, symmetric))
    jac_i, jac_j = sides
    hessian = np.stack([
        2.0 * np.swapaxes(jac_i, 1, 2) @ jac_i, 2.0 * np.swapaxes(jac_j, 1, 2) @ jac_j,
        2.0 * np.swapaxes(jac_i, 1, 2) @ jac_j,
    ], axis=1)  # fmt: skip
    hessian[:, 0, d:, d:] += corrections[0]
    hessian[:, 1, d:, d:] += corrections[1]
    return hessian, np.stack(gradients, axis=1), float(np.sum(flat**2))


def retract_poses(u: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """``u`` ``(n, d, d+1)`` moved by ``steps`` ``(n, p)`` = ``[ṫ; δ]``: ``t + ṫ``, ``R Exp(δ)``."""
    from posegraph.lie import so2, so3

    d = u.shape[1]
    out = u.copy()
    out[:, :, 0] += steps[:, :d]
    out[:, :, 1:] = u[:, :, 1:] @ (so3 if d == 3 else so2).exp(steps[:, d:])
    return out


def refine_poses(problem: SyncProblem, u: np.ndarray, anchor: int = 0, max_iterations: int = MAX_NEWTON_ITERATIONS):
    """A local minimiser of F from poses ``u`` ``(n, d, d+1)``: ``(u, F, iterations)`` (module docstring).

    Newton steps ``(H + μ D) Δ = −g``, ``D = diag(H)`` (Marquardt's scaling), with μ updated from the
    gain ratio as in Nielsen's rule (Madsen, Nielsen & Tingleff, "Methods for non-linear least
    squares problems", 2004, eq. 2.21) and set to 0 when it falls below :data:`MIN_DAMPING`, so the
    last steps are pure Newton. Stops when the Newton decrement ``−gᵀΔ`` falls below
    :data:`RELATIVE_DECREMENT_TOLERANCE`·F, or when no damping makes a step decrease F.
    """
    d, n = problem.d, problem.num_poses
    held = np.zeros(n, dtype=bool)
    held[anchor] = True
    pattern = analyze_pattern(n, problem.edge_from, problem.edge_to, held, d + d * (d - 1) // 2)
    solver = make_linear_solver("auto", pattern)
    maps, gens = edge_maps(problem), generators(d)
    damping, growth = 0.0, 2.0
    for iteration in range(1, max_iterations + 1):
        blocks, grads, cost = newton_blocks(problem, u, maps, gens)
        data, gradient = hessian_values(pattern, blocks), gradient_values(pattern, grads)
        while damping <= MAX_DAMPING:
            step, decrement, predicted = _damped_step(solver, pattern, data, gradient, damping)
            if step is not None and decrement <= RELATIVE_DECREMENT_TOLERANCE * cost:
                if damping > 0.0 and _damped_step(solver, pattern, data, gradient, 0.0)[0] is not None:
                    step = solver.solve(-gradient)  # H is positive definite here: the pure Newton step
                # at the optimum to round-off: take the last step (the gradient, which Λ is read
                # from, drops to round-off with it) without asking the cost to fall
                return retract_poses(u, pattern.expand(step)), cost - 0.5 * decrement, iteration
            trial = None if step is None else retract_poses(u, pattern.expand(step))
            gain = -np.inf if trial is None else (cost - objective(problem, trial, maps)) / predicted
            if gain > 0.0:
                u, growth = trial, 2.0
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                damping = damping if damping >= MIN_DAMPING else 0.0
                break
            damping, growth = max(damping * growth, MIN_DAMPING), 2.0 * growth
        else:
            return u, cost, iteration
    return u, objective(problem, u, maps), max_iterations


def _damped_step(solver, pattern, data: np.ndarray, gradient: np.ndarray, damping: float):
    """``(Δ, −gᵀΔ, predicted decrease)`` with ``(H + μ diag(H)) Δ = −g``; ``(None, inf, inf)`` when that
    matrix is not positive definite. The model's decrease is ``½(−gᵀΔ + μ ΔᵀDΔ)``."""
    shifted = data.copy()
    diagonal = np.abs(data[pattern.diagonal])
    shifted[pattern.diagonal] += damping * diagonal
    try:
        solver.factorize(shifted)
    except NotPositiveDefiniteError:
        return None, np.inf, np.inf
    step = solver.solve(-gradient)
    decrement = float(-gradient @ step)
    return step, decrement, 0.5 * (decrement + damping * float(step @ (diagonal * step)))


def translations_given_rotations(problem: SyncProblem, rotations: np.ndarray, anchor: int = 0) -> np.ndarray:
    """``(n, d)`` translations minimising F at rotations ``(n, d, d)``, ``t_anchor = 0`` (SE-Sync's
    ``recover_translations``): ``L(W^τ) t = b`` with ``b_j += τ R_i t̃``, ``b_i −= τ R_i t̃``."""
    n, d = problem.num_poses, problem.d
    held = np.zeros(n, dtype=bool)
    held[anchor] = True
    pattern = analyze_pattern(n, problem.edge_from, problem.edge_to, held, 1)
    tau = problem.tau
    blocks = np.stack([tau, tau, -tau], axis=1).reshape(-1, 3, 1, 1)
    solver = make_linear_solver("auto", pattern)
    solver.factorize(hessian_values(pattern, blocks))
    offsets = tau[:, None] * (rotations[problem.edge_from] @ problem.translations[:, :, None])[:, :, 0]
    right = np.stack([gradient_values(pattern, np.stack([-offsets[:, c], offsets[:, c]], axis=1)[:, :, None])
                      for c in range(d)], axis=1)  # fmt: skip
    solution = solver.solve(right)
    out = np.zeros((n, d))
    out[pattern.variable_of >= 0] = solution
    return out
