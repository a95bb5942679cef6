"""The pieces of one Levenberg-Marquardt / Gauss-Newton iteration: damping, step judgement, line search.

:class:`Damping` holds λ and turns ``H`` into ``H + λD`` (Marquardt's ``D = diag(H)`` clamped, or
``D = I``), shrinking λ after an accepted step and growing it after a rejected one (gtsam's fixed
factor or Nielsen's rule). :func:`model_decrease` is the quadratic model's predicted decrease along a
solved step, the denominator of the gain ratio

    ρ = (F(X) − F(X ⊕ t·δ)) / (L(0) − L(t·δ)).

:func:`backtrack` is the Armijo line search that shortens a step the model over-promised (why it
exists: ``docs/solver.md``, "Ill-conditioned graphs"). :func:`converged` and :func:`negligible`
are the stopping tests on cost decreases.
"""

from __future__ import annotations

import numpy as np

from posegraph.solve.params import SolverParams

__all__ = ["Damping", "model_decrease", "backtrack", "converged", "negligible"]

CONVERGED_RELATIVE = "converged: relative decrease"
CONVERGED_ABSOLUTE = "converged: absolute decrease"
CONVERGED_COST = "converged: cost below tolerance"
CONVERGED_PREDICTED = "converged: predicted decrease below tolerance"
CONVERGED_NOTHING = "converged: nothing to optimise"
CONVERGED_DECREMENT = "converged: Newton decrement below tolerance"
MAX_ITERATIONS = "maximum iterations"
LAMBDA_EXCEEDED = "lambda exceeded bound"
NO_DECREASE = "no decrease"
NOT_POSITIVE_DEFINITE = "linear system not positive definite"
NON_FINITE = "non-finite cost"
CALLBACK = "callback"

# Relative round-off of the cost, with a margin. F = ½ Σ eᵀΩe sums non-negative terms, but each
# residual e = Log(Z⁻¹ X_i⁻¹ X_j) carries an absolute error of ~ε·|t| (ε = 2.2e-16, |t| the size of
# the translations) which information up to 1e7 magnifies: near the optimum of the ill-conditioned
# synthetic graphs (tests/solve/test_ill_conditioned.py) F jitters by up to 1.2e-12·F from one
# evaluation to the next (2.4e-13·F under pose perturbations of 1e-17), on the standard files by
# ~4e-16·F. When no step is accepted and the model predicts less than this, nothing measurable is
# left: the solver reports convergence instead of raising λ or stopping with "no decrease".
COST_ROUNDOFF = 1e-10

# Extra trials when the line search's first interpolation was clamped (see backtrack): measured on
# the synthetic ill-conditioned graphs, two cut the iterations from the ground truth by 15-40 %
# (e.g. 19 -> 13, 51 -> 32); a third changed nothing.
LINE_SEARCH_REFINEMENTS = 2


def converged(decrease: float, cost_before: float, params: SolverParams) -> str | None:
    """gtsam's checkConvergence on an accepted step: the absolute, then the relative decrease test."""
    if decrease <= params.absolute_tolerance:
        return CONVERGED_ABSOLUTE
    if cost_before > 0 and decrease / cost_before <= params.relative_tolerance:
        return CONVERGED_RELATIVE
    return None


def negligible(amount: float, cost_now: float, params: SolverParams) -> bool:
    """Whether a cost change is below the tolerances' reach or the cost's own round-off."""
    return amount <= max(params.absolute_tolerance, max(params.relative_tolerance, COST_ROUNDOFF) * cost_now)


def model_decrease(t: float, slope: float, damping_term: float) -> float:
    """Decrease ``L(0) − L(t·δ)`` of the quadratic model along the solved step δ.

    With ``slope = gᵀδ`` and ``damping_term = λ δᵀDδ``, ``(H + λD)δ = −g`` gives
    ``δᵀHδ = −slope − damping_term``, so
    ``−t gᵀδ − ½ t² δᵀHδ = −t·slope + ½ t² (slope + damping_term)``;
    at ``t = 1`` it is ``½ δᵀ(λDδ − g)``, LM's predicted decrease.
    """
    return -t * slope + 0.5 * t * t * (slope + damping_term)


class Damping:
    """λ and the damping ``D`` of ``(H + λD) δ = −g``; Gauss-Newton is λ = 0 throughout.

    ``D = diag(H)`` clamped to ``[min_diagonal, max_diagonal]`` (Marquardt, ``diagonal_damping``)
    or ``I``. After an accepted step with gain ratio ρ, :meth:`shrink`: λ / ``lambda_factor``
    (``"fixed"``, gtsam's) or λ·max(1/3, 1 − (2ρ − 1)³) (``"nielsen"``); after a rejected one,
    :meth:`grow`: λ·``lambda_factor``, or λ·ν with ν doubling on each consecutive rejection.
    """

    def __init__(self, params: SolverParams):
        self.params = params
        self.active = params.method == "lm"
        self.lam = params.initial_lambda if self.active else 0.0
        self.nu = 2.0  # Nielsen's growth factor for consecutive rejections
        self.diagonal: np.ndarray | None = None

    def shift(self, data: np.ndarray, diagonal: np.ndarray) -> np.ndarray | None:
        """``(dp,)`` the damping ``λ·diag(D)`` to add to the diagonal of H, whose CSC ``data`` has its
        diagonal at positions ``diagonal``; None for Gauss-Newton (no damping). The linear solver
        adds it (:meth:`posegraph.solve.linear.LinearSolver.factorize`), so H itself is kept."""
        if not self.active:
            return None
        h_diagonal = data[diagonal]
        if self.params.diagonal_damping:
            self.diagonal = np.clip(h_diagonal, self.params.min_diagonal, self.params.max_diagonal)
        else:
            self.diagonal = np.ones_like(h_diagonal)
        return self.lam * self.diagonal

    def term(self, step: np.ndarray) -> float:
        """``λ δᵀDδ`` for the step solved with the last :meth:`shift` (0 for Gauss-Newton)."""
        if not self.active:
            return 0.0
        return self.lam * float(np.einsum("i,i,i->", step, self.diagonal, step))

    def shrink(self, gain: float) -> None:
        """After an accepted step with gain ratio ``gain``."""
        if not self.active:
            return
        if self.params.lambda_update == "nielsen":
            self.lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
            self.nu = 2.0
        else:
            self.lam /= self.params.lambda_factor
        self.lam = max(self.lam, self.params.lambda_min)

    def grow(self) -> bool:
        """After a rejected step; False when λ passes ``lambda_max`` (the run then stops)."""
        if self.params.lambda_update == "nielsen":
            self.lam *= self.nu
            self.nu *= 2.0
        else:
            self.lam *= self.params.lambda_factor
        return self.lam <= self.params.lambda_max


def backtrack(cost_at, cost_now: float, slope: float, cost_full: float, params: SolverParams):
    """Armijo backtracking along a step whose full length ``t = 1`` failed.

    ``cost_at(t)`` evaluates ``φ(t) = F(X ⊕ t·δ)`` and returns ``(cost, state)``; ``φ(0) = cost_now``,
    ``φ'(0) = slope < 0``, ``φ(1) = cost_full``. Each new ``t`` minimises the quadratic through
    ``φ(0)``, ``φ'(0)`` and the last trial (Nocedal & Wright, *Numerical Optimization*, §3.5), kept in
    ``[0.1, 0.5]`` of the last ``t`` so that it neither stalls nor collapses, until
    ``φ(t) ≤ φ(0) + c₁ t φ'(0)`` (Armijo). If that ``t`` is the clamp ``0.1·t_fail`` (the parabola
    wanted less), :data:`LINE_SEARCH_REFINEMENTS` log-scale bisections of ``[t, t_fail]`` move it up
    while ``φ`` keeps falling. Returns ``(t, cost, state)``, or None once ``t`` would fall below
    ``params.line_search_min_step``.
    """
    t, cost_t = 1.0, cost_full
    while True:
        curvature = cost_t - cost_now - slope * t  # > 0 when φ lies above its tangent at 0
        if np.isfinite(cost_t) and curvature > 0:
            proposal = -slope * t * t / (2.0 * curvature)
        else:
            proposal = 0.1 * t  # no usable model of φ (non-finite trial): shrink hard
        t_fail, t = t, min(max(proposal, 0.1 * t), 0.5 * t)
        if t < params.line_search_min_step:
            return None
        cost_t, state = cost_at(t)
        if cost_t <= cost_now + params.sufficient_decrease * t * slope:
            break
    # Clamped at 0.1·t_fail, the interpolation may have undershot (φ rising much faster than a
    # parabola beyond t, as along a curved valley): bisect [t, t_fail] in log scale while φ falls.
    if proposal < 0.1 * t_fail:
        for _ in range(LINE_SEARCH_REFINEMENTS):
            t_mid = float(np.sqrt(t * t_fail))
            cost_mid, state_mid = cost_at(t_mid)
            if cost_mid < cost_t:
                t, cost_t, state = t_mid, cost_mid, state_mid
            else:
                t_fail = t_mid
    return t, cost_t, state
