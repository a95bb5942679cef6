"""Gauss-Newton and Levenberg-Marquardt over SE(3) pose graphs.

Each iteration linearises every edge at the current poses
(:func:`posegraph.solve.linearize.linearize`), scatters the blocks into the
sparse normal equations ``H δ = −g`` (:mod:`posegraph.solve.sparsity`), solves
them (:mod:`posegraph.solve.linear`) and retracts ``X_k ← X_k · Exp(δ_k)``.

Levenberg-Marquardt solves ``(H + λ D) δ = −g`` with ``D = diag(H)`` clamped to
``[min_diagonal, max_diagonal]`` (Marquardt) or ``D = I``, and judges the step
by the gain ratio

    ρ = (F(X) − F(X ⊕ δ)) / (L(0) − L(δ)),   L(0) − L(δ) = ½ δᵀ (λ D δ − g),

the actual over the predicted decrease of the cost. A step with
``ρ > min_gain_ratio`` is accepted and λ shrinks. Otherwise (with
``line_search``, the default) the step is first shortened, ``X ⊕ t·δ``, by an
Armijo backtracking line search on ``φ(t) = F(X ⊕ t·δ)`` (:func:`_backtrack`;
``φ'(0) = gᵀδ`` exactly, since ``g`` is the gradient in the same right-perturbation
coordinates); an accepted shortened step counts as a success and λ shrinks.
Only when no ``t ≥ line_search_min_step`` decreases the cost enough does λ grow
and the *same* linearisation get refactorised with the new λ (no
relinearisation), until a step is accepted or λ passes ``lambda_max``.

Gauss-Newton takes the full step when it satisfies the Armijo condition, else
the same line search; it stops with ``"no decrease"`` only when that fails too.

Why the line search: on graphs whose information spans many orders of magnitude
with rotation–translation coupling, H has eigenvalues down to ~1e-7 in directions
where the Gauss-Newton model is poor (the neglected second-order term
``Σ (Ωe)ᵀ ∇²e`` is as large as ``JᵀΩJ`` there; plain GN is even locally divergent
at some optima). Marquardt's ``λ·diag(H)`` is ≫ those eigenvalues for any λ that
tames the step, so raising λ freezes exactly the directions still to be solved
(a crawl of hundreds of iterations), whereas shortening the step scales all
directions alike (``docs/solver.md``, "Ill-conditioned graphs").

Convergence (after an accepted step): gtsam's relative / absolute decrease test,
applied to the larger of the actual decrease and the full step's predicted one
— a shortened or over-promised step leaves the latter on the table.

Chord steps (``reuse_factorization``): in Newton's region H changes little from one iterate to
the next, so after a full step whose gain ratio was within :data:`CHORD_MIN_GAIN` of 1, the next
iteration first solves its new system with the factorisation it still holds (Shamanskii's
"chord" Newton step: one triangular solve instead of a factorisation). The step is taken only if
H still agrees with that factorisation along it (:data:`CHORD_AGREEMENT`), it promises a fast
enough decrease (:data:`CHORD_CONTRACTION` of the last one, or already within the tolerances) and
the cost confirms it (gain ratio); the factorisation is then kept for the iteration after. Else
the iteration factorises as usual, one solve later (:func:`_chord_step`, :func:`_chord_step_decrease`).
Before any of this, the same solve gives the Newton decrement under the held factorisation: when
it is negligible the run stops without assembling H (:func:`_decrement_negligible`).

Gauge: fixed vertices and the anchor of every component without one
(:func:`posegraph.graph.held_vertices`) have no variables at all — their
columns are not in the system — so the cost is exactly the graph's, with no
prior added.
"""

from __future__ import annotations

import time

import numpy as np

from posegraph.graph import PoseGraph, held_vertices
from posegraph.lie import se3
from posegraph.solve.linear import NotPositiveDefiniteError, make_linear_solver
from posegraph.solve.linearize import linearize
from posegraph.solve.params import SolverParams
from posegraph.solve.residuals import edge_errors, weighted_cost
from posegraph.solve.result import IterationRecord, OptimizeResult
from posegraph.solve.sparsity import analyze_pattern, gradient_values, hessian_values, lower_matvec

__all__ = ["optimize"]

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


def _initial_poses(graph: PoseGraph, initial) -> np.ndarray:
    if initial is None:
        initial = "chordal"
    if isinstance(initial, str):
        if initial == "file":
            poses = graph.poses
        else:
            from posegraph.init import initialize

            poses = initialize(graph, initial)
    else:
        poses = initial
    poses = np.array(poses, dtype=np.float64, copy=True)
    if poses.shape != (graph.num_vertices, 4, 4):
        raise ValueError(f"initial poses must have shape ({graph.num_vertices}, 4, 4), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise ValueError("initial poses contain NaN or infinite values")
    return poses


def _retract(poses: np.ndarray, free: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """``X_k · Exp(δ_k)`` for the free vertices; held vertices are copied unchanged."""
    out = poses.copy()
    out[free] = poses[free] @ se3.exp(steps)
    return out


def _converged(decrease: float, cost_before: float, params: SolverParams) -> str | None:
    """gtsam's checkConvergence on an accepted step (plus the cost tolerance)."""
    if decrease <= params.absolute_tolerance:
        return CONVERGED_ABSOLUTE
    if cost_before > 0 and decrease / cost_before <= params.relative_tolerance:
        return CONVERGED_RELATIVE
    return None


# Relative round-off of the cost, with a margin. F = ½ Σ eᵀΩe sums non-negative terms, but each
# residual e = Log(Z⁻¹ X_i⁻¹ X_j) carries an absolute error of ~ε·|t| (ε = 2.2e-16, |t| the size of
# the translations) which information up to 1e7 magnifies: near the optimum of the ill-conditioned
# synthetic graphs (tests/solve/test_ill_conditioned.py) F jitters by up to 1.2e-12·F from one
# evaluation to the next (2.4e-13·F under pose perturbations of 1e-17), on the standard files by
# ~4e-16·F. When no step is accepted and the model predicts less than this, nothing measurable is
# left: the solver reports convergence instead of raising λ or stopping with "no decrease".
COST_ROUNDOFF = 1e-10

# Extra trials when the line search's first interpolation was clamped (see _backtrack): measured on
# the synthetic ill-conditioned graphs, two cut the iterations from the ground truth by 15-40 %
# (e.g. 19 -> 13, 51 -> 32); a third changed nothing.
LINE_SEARCH_REFINEMENTS = 2


def _negligible(amount: float, cost_now: float, params: SolverParams) -> bool:
    """Whether a cost change is below the tolerances' reach or the cost's own round-off."""
    return amount <= max(params.absolute_tolerance, max(params.relative_tolerance, COST_ROUNDOFF) * cost_now)


def _model_decrease(t: float, slope: float, damping_term: float) -> float:
    """Decrease ``L(0) − L(t·δ)`` of the quadratic model along the solved step δ.

    With ``slope = gᵀδ`` and ``damping_term = λ δᵀDδ``, ``(H + λD)δ = −g`` gives
    ``δᵀHδ = −slope − damping_term``, so
    ``−t gᵀδ − ½ t² δᵀHδ = −t·slope + ½ t² (slope + damping_term)``;
    at ``t = 1`` it is ``½ δᵀ(λDδ − g)``, LM's predicted decrease.
    """
    return -t * slope + 0.5 * t * t * (slope + damping_term)


def _backtrack(cost_at, cost_now: float, slope: float, cost_full: float, params: SolverParams):
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


CHORD_CONTRACTION = 0.1
"""A step from the previous factorisation is taken when its predicted decrease is at most this
fraction of the last actual decrease (or within the convergence tolerances): the chord iteration
then still converges at least this fast, so it cannot crawl where a new factorisation would leap.
Measured from the chordal start, chord steps and the decrement stop together, against
``reuse_factorization=False``: 2 factorisations instead of 4 on sphere2500, torus3D and
parking-garage, 3 instead of 5 on smallGrid3D, 2 instead of 5 on tinyGrid3D, 3 instead of 4 on
sphere_bignoise_vertex3, 6 either way on cubicle; the same numbers of iterations; final costs
within 8.2e-10 relative."""

CHORD_AGREEMENT = 0.9
"""A step from the previous factorisation ``M`` is taken only if its model decrease under the new
H is at least this fraction of ``−½gᵀδ``, its value were H equal to M (see :func:`_chord_step_decrease`)."""

CHORD_MIN_GAIN = 0.9
"""The previous factorisation is tried only after a full step whose gain ratio was at least this
(and at most its inverse): the quadratic model was accurate there, i.e. the run is in Newton's
region, where H changes little from one iterate to the next."""


def _in_newton_region(gain: float) -> bool:
    """Whether a full step's gain ratio was within :data:`CHORD_MIN_GAIN` of 1 (the model was accurate)."""
    return CHORD_MIN_GAIN <= gain <= 1.0 / CHORD_MIN_GAIN


def _chord_step(solver, gradient: np.ndarray):
    """``(δ, gᵀδ)`` for the chord step ``δ = −M⁻¹ g`` with the factorisation ``M`` the solver holds.

    ``M`` is the (damped) matrix of an earlier iteration of this run, whose full step was accepted
    with a gain ratio near 1. ``−½gᵀδ = ½gᵀM⁻¹g`` is the Newton decrement under ``M``
    (:func:`_decrement_negligible`). ``δ`` is None if it is not finite.
    """
    step = solver.solve(-gradient)
    if not np.all(np.isfinite(step)):
        return None, float("nan")
    return step, float(np.einsum("i,i->", gradient, step))


def _chord_step_decrease(
    pattern, data, step: np.ndarray, slope: float, cost_now: float, params: SolverParams, last_decrease: float
) -> float | None:
    """The model decrease of the chord step ``δ`` under the *new* H, if the step is worth taking.

    Near the optimum H barely changes between iterations, so ``δ`` is nearly the Gauss-Newton step
    (Shamanskii's "chord" Newton method), for one triangular solve instead of a factorisation. Its
    model decrease under the new H (lower triangle ``data``),

        L(0) − L(δ) = −gᵀδ − ½ δᵀHδ,

    is what LM's gain ratio divides by. Returned when it is at least :data:`CHORD_AGREEMENT` of
    ``−½gᵀδ`` (its value if H were M) and either within the convergence tolerances or at most
    :data:`CHORD_CONTRACTION` times ``last_decrease``; else None: then the caller factorises as
    usual, having spent one solve and one sparse product.
    """
    # δᵀHδ from the lower triangle only: 2 δᵀ(tril(H) δ) − Σ H_kk δ_k²
    lower_product = lower_matvec(pattern, data, step)
    curvature = 2.0 * float(np.einsum("i,i->", step, lower_product)) - float(
        np.einsum("i,i,i->", step, data[pattern.diagonal], step)
    )
    predicted = -slope - 0.5 * curvature
    # With M = H the model decrease of δ = −M⁻¹g is exactly −½gᵀδ; the ratio measures how far H has
    # moved from M along δ. Below CHORD_AGREEMENT, δ is a stale direction whose small decrease says
    # nothing about how far the optimum still is (sphere_bignoise: 0.24, and a Newton step then
    # still found twice the chord step's decrease), so a new factorisation is due.
    if not predicted > 0 or predicted < CHORD_AGREEMENT * (-0.5 * slope):
        return None
    if _converged(predicted, cost_now, params) is None and predicted > CHORD_CONTRACTION * last_decrease:
        return None
    return predicted


DECREMENT_MARGIN = 100.0
"""The run stops without a new factorisation when the Newton decrement under the held one,
``½ gᵀM⁻¹g``, is this many times below the convergence tolerances (and M was barely damped)."""

DECREMENT_MAX_LAMBDA = 1e-6
"""The held factorisation's λ up to which ``M = H_old + λD`` stands for ``H_old`` in that test."""


def _decrement_negligible(decrement: float, cost_now: float, held_lambda: float, params: SolverParams) -> bool:
    """Whether ``decrement = ½ gᵀM⁻¹g`` (M the held factorisation) shows the optimum already reached.

    ``½ gᵀH⁻¹g`` is the decrease a Newton step would still promise; with M the (barely damped) H of
    a nearby iterate it differs by the spread of the eigenvalues of ``M⁻¹H``, so the test leaves a
    factor :data:`DECREMENT_MARGIN` for it. This ends runs whose last step fell just short of the
    relative tolerance but whose chord step is not worth taking (parking-garage from the chordal
    start: decrement 2.7e-10 at a cost of 0.634, where a new factorisation's step then gained 1.2e-10).
    """
    if not (np.isfinite(decrement) and decrement >= 0 and held_lambda <= DECREMENT_MAX_LAMBDA):
        return False
    return _converged(DECREMENT_MARGIN * decrement, cost_now, params) is not None


def optimize(graph: PoseGraph, initial=None, params: SolverParams | None = None) -> OptimizeResult:
    """Minimise ``½ Σ eᵀ Ω e`` over the free poses by Levenberg-Marquardt or Gauss-Newton.

    Parameters
    ----------
    graph : PoseGraph
    initial : None, str or (n, 4, 4) array
        Starting poses: an array, or the name of an initialiser — ``"file"`` (the graph's own
        poses), ``"chordal"`` or ``"odometry"`` (:func:`posegraph.init.initialize`). ``None`` means
        ``"chordal"``.
    params : SolverParams, optional
        Method, tolerances, damping and linear solver; defaults as documented in
        :class:`~posegraph.solve.params.SolverParams`.

    Returns
    -------
    OptimizeResult
        Final poses (held vertices unchanged), costs, per-iteration records, termination reason
        and the linear solver that ran.
    """
    start = time.perf_counter()
    params = SolverParams() if params is None else params
    poses = _initial_poses(graph, initial)

    setup_start = time.perf_counter()
    held = held_vertices(graph)
    free = ~held
    pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held)
    information = np.ascontiguousarray(graph.information)

    def evaluate(poses):
        errors = edge_errors(poses, graph)
        return errors, weighted_cost(errors[1], information)

    current_errors, current_cost = evaluate(poses)
    initial_cost = current_cost
    if not np.isfinite(initial_cost):
        raise ValueError("the cost at the initial poses is not finite")

    def finish(termination: str, converged: bool, records: list, solver_name: str, setup: float) -> OptimizeResult:
        return OptimizeResult(
            poses=poses,
            initial_cost=initial_cost,
            final_cost=current_cost,
            iterations=len(records),
            termination=termination,
            converged=converged,
            linear_solver=solver_name,
            method=params.method,
            records=records,
            seconds_setup=setup,
            seconds_total=time.perf_counter() - start,
        )

    if pattern.num_variables == 0 or graph.num_edges == 0:
        return finish(CONVERGED_NOTHING, True, [], "none", time.perf_counter() - setup_start)
    solver = make_linear_solver(params.linear_solver, pattern, params.ordering, params.blas_threads)
    seconds_setup = time.perf_counter() - setup_start
    if current_cost <= params.cost_tolerance:
        return finish(CONVERGED_COST, True, [], solver.name, seconds_setup)

    lm = params.method == "lm"
    lam = params.initial_lambda if lm else 0.0
    nu = 2.0  # Nielsen's growth factor for consecutive rejections
    records: list[IterationRecord] = []
    termination, converged = MAX_ITERATIONS, False
    reusable = None  # λ of the factorisation the solver holds, when its full step was just accepted
    last_decrease = np.inf

    def shrink_lambda(lam: float, gain: float) -> float:
        nonlocal nu
        if params.lambda_update == "nielsen":
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
            nu = 2.0
        else:
            lam /= params.lambda_factor
        return max(lam, params.lambda_min)

    for iteration in range(1, params.max_iterations + 1):
        t0 = time.perf_counter()
        blocks = linearize(poses, graph, information, current_errors)  # gradient; H blocks on demand
        t1 = time.perf_counter()
        gradient = gradient_values(pattern, blocks.gradient)
        t2 = time.perf_counter()
        seconds_linearize, seconds_assemble = t1 - t0, t2 - t1
        seconds_factorize = seconds_solve = 0.0

        accepted, attempts, stop = False, 0, None
        step_norm, gain, lambda_tried, scale = 0.0, float("nan"), lam, float("nan")
        predicted = float("nan")
        new_cost = current_cost
        chord, slope = None, float("nan")
        if reusable is not None:
            # Near the optimum the held factorisation may show, from the gradient alone, that the
            # run has converged (then H is never assembled), or give a chord step (see _chord_step).
            tc = time.perf_counter()
            chord, slope = _chord_step(solver, gradient)
            if _decrement_negligible(-0.5 * slope, current_cost, reusable, params):
                stop = CONVERGED_DECREMENT
            seconds_solve += time.perf_counter() - tc
        if stop is None:
            ta = time.perf_counter()
            hessian_blocks = blocks.hessian_blocks
            tb = time.perf_counter()
            data = hessian_values(pattern, hessian_blocks)
            seconds_linearize += tb - ta
            seconds_assemble += time.perf_counter() - tb
            diagonal = data[pattern.diagonal]
            if params.diagonal_damping:
                damping = np.clip(diagonal, params.min_diagonal, params.max_diagonal)
            else:
                damping = np.ones_like(diagonal)
        if chord is not None and stop is None:
            tc = time.perf_counter()
            chord_predicted = _chord_step_decrease(pattern, data, chord, slope, current_cost, params, last_decrease)
            if chord_predicted is not None:
                step, predicted = chord, chord_predicted
                trial = _retract(poses, free, step.reshape(-1, 6))
                trial_errors, new_cost = evaluate(trial)
                decrease = current_cost - new_cost
                gain = decrease / predicted if np.isfinite(new_cost) else -np.inf
                if gain > params.min_gain_ratio:
                    accepted, scale, lambda_tried = True, 1.0, reusable
                    step_norm = float(np.sqrt(np.einsum("i,i->", step, step)))
                else:
                    new_cost, predicted, gain = current_cost, float("nan"), float("nan")
            seconds_solve += time.perf_counter() - tc
        reusable = None
        if accepted and _in_newton_region(gain):
            reusable = lambda_tried  # the same factorisation may serve the next iteration too
        while not accepted and stop is None:  # (every accepting branch below also breaks)
            attempts += 1
            lambda_tried = lam
            ta = time.perf_counter()
            damped = data
            if lm:
                damped = data.copy()
                damped[pattern.diagonal] += lam * damping
            try:
                solver.factorize(damped)
                factor_ok = True
            except NotPositiveDefiniteError:
                factor_ok = False
            tb = time.perf_counter()
            seconds_factorize += tb - ta
            predicted = float("nan")
            trial = None
            if factor_ok:
                step = solver.solve(-gradient)
                steps = step.reshape(-1, 6)
                step_norm = float(np.sqrt(np.einsum("i,i->", step, step)))
                # (einsum, not a BLAS dot: numpy's BLAS threads would then spin against CHOLMOD's)
                slope = float(np.einsum("i,i->", gradient, step))  # φ'(0) = gᵀδ
                damping_term = lam * float(np.einsum("i,i,i->", step, damping, step)) if lm else 0.0
                predicted = _model_decrease(1.0, slope, damping_term)
                if np.all(np.isfinite(step)) and predicted > 0:
                    trial = _retract(poses, free, steps)
                    trial_errors, new_cost = evaluate(trial)

            if trial is None:
                seconds_solve += time.perf_counter() - tb
                if factor_ok and np.isfinite(predicted) and abs(predicted) <= 1e-300:
                    stop = CONVERGED_PREDICTED  # zero gradient: nothing left to decrease
                    break
                # Not positive definite (or the step is garbage): no usable model at this λ.
                if not lm:
                    stop = NOT_POSITIVE_DEFINITE
                    break
            else:
                decrease = current_cost - new_cost
                gain = decrease / predicted if np.isfinite(new_cost) else -np.inf
                if lm:
                    full_ok = gain > params.min_gain_ratio
                elif params.line_search:
                    full_ok = new_cost <= current_cost + params.sufficient_decrease * slope  # Armijo
                else:
                    full_ok = decrease >= 0  # plain Gauss-Newton (gtsam's): any step that does not increase F
                scale = 1.0
                if not full_ok and params.line_search:

                    def cost_at(t, steps=steps):
                        moved = _retract(poses, free, t * steps)
                        errors, value = evaluate(moved)
                        return value, (moved, errors)

                    found = _backtrack(cost_at, current_cost, slope, new_cost, params)
                    if found is not None:
                        scale, new_cost, (trial, trial_errors) = found
                        decrease = current_cost - new_cost
                        gain = decrease / _model_decrease(scale, slope, damping_term)
                        full_ok = True
                seconds_solve += time.perf_counter() - tb
                if full_ok:
                    accepted = True
                    if lm:
                        lam = shrink_lambda(lam, gain)
                    if scale == 1.0 and params.reuse_factorization and _in_newton_region(gain):
                        reusable = lambda_tried  # the factorisation behind this step, for the next iteration
                    break
                scale = float("nan")
                if _negligible(predicted, current_cost, params) and _negligible(abs(decrease), current_cost, params):
                    # At round-off level: the model and the cost agree no measurable decrease is left.
                    stop = CONVERGED_PREDICTED
                    break
                if not lm:
                    stop = NO_DECREASE
                    break
            # rejected: raise λ and refactorise the same linearisation
            if params.lambda_update == "nielsen":
                lam *= nu
                nu *= 2.0
            else:
                lam *= params.lambda_factor
            if lam > params.lambda_max:
                stop = LAMBDA_EXCEEDED
                break

        decrease = 0.0
        if accepted:
            decrease = current_cost - new_cost
            last_decrease = decrease
            cost_before = current_cost
            poses, current_cost, current_errors = trial, new_cost, trial_errors
        record = IterationRecord(
            iteration=iteration,
            cost=current_cost,
            cost_decrease=decrease,
            lambda_=lambda_tried if lm else 0.0,
            step_norm=step_norm,
            gain_ratio=gain,
            accepted=accepted,
            attempts=attempts,
            seconds_linearize=seconds_linearize,
            seconds_assemble=seconds_assemble,
            seconds_factorize=seconds_factorize,
            seconds_solve=seconds_solve,
            step_scale=scale,
        )
        records.append(record)
        if params.callback is not None:
            try:
                if params.callback(record) is True:
                    stop = stop or CALLBACK
            except StopIteration:
                stop = stop or CALLBACK
        if stop is not None:
            termination = stop
            converged = stop.startswith("converged")
            break
        if accepted:
            if not np.isfinite(current_cost):
                termination = NON_FINITE
                break
            if current_cost <= params.cost_tolerance:
                termination, converged = CONVERGED_COST, True
                break
            # A small actual decrease alone can mislead: a shortened step, or a full step the model
            # over-promised (gain well below 1), leaves up to `predicted` on the table, which must be
            # small too. At a full step with gain ≈ 1 (every standard file) the two agree.
            reason = _converged(max(decrease, predicted), cost_before, params)
            if reason is not None:
                termination, converged = reason, True
                break

    return finish(termination, converged, records, solver.name, seconds_setup)
