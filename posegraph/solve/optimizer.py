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
``ρ > min_gain_ratio`` is accepted and λ shrinks; otherwise λ grows and the
*same* linearisation is refactorised with the new λ (no relinearisation),
until a step is accepted or λ passes ``lambda_max``.

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
from posegraph.solve.sparsity import analyze_pattern, gradient_values, hessian_values

__all__ = ["optimize"]

CONVERGED_RELATIVE = "converged: relative decrease"
CONVERGED_ABSOLUTE = "converged: absolute decrease"
CONVERGED_COST = "converged: cost below tolerance"
CONVERGED_PREDICTED = "converged: predicted decrease below tolerance"
CONVERGED_NOTHING = "converged: nothing to optimise"
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


def _negligible(amount: float, cost_now: float, params: SolverParams) -> bool:
    """Whether a cost change is below both the absolute and the relative tolerance's reach."""
    return amount <= max(params.absolute_tolerance, params.relative_tolerance * cost_now)


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

    for iteration in range(1, params.max_iterations + 1):
        t0 = time.perf_counter()
        blocks = linearize(poses, graph, information, current_errors)
        t1 = time.perf_counter()
        data = hessian_values(pattern, blocks.hessian)
        gradient = gradient_values(pattern, blocks.gradient)
        t2 = time.perf_counter()
        seconds_factorize = seconds_solve = 0.0
        diagonal = data[pattern.diagonal]
        if params.diagonal_damping:
            damping = np.clip(diagonal, params.min_diagonal, params.max_diagonal)
        else:
            damping = np.ones_like(diagonal)

        accepted, attempts, stop = False, 0, None
        step_norm, gain, lambda_tried = 0.0, float("nan"), lam
        new_cost = current_cost
        while True:
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
                step_norm = float(np.sqrt(np.einsum("i,i->", step, step)))
                # L(0) − L(δ) = −gᵀδ − ½ δᵀHδ = ½ δᵀ(λDδ − g), using (H + λD)δ = −g
                # (einsum, not a BLAS dot: numpy's BLAS threads would then spin against CHOLMOD's)
                predicted = 0.5 * float(np.einsum("i,i->", step, lam * damping * step - gradient))
                if np.all(np.isfinite(step)) and predicted > 0:
                    trial = _retract(poses, free, step.reshape(-1, 6))
                    trial_errors, new_cost = evaluate(trial)
            seconds_solve += time.perf_counter() - tb

            if trial is None:
                if factor_ok and np.isfinite(predicted) and abs(predicted) <= 1e-300:
                    stop = CONVERGED_PREDICTED  # zero gradient: nothing left to decrease
                    break
                # Not positive definite (or the step is garbage): no usable model at this λ.
                if not lm:
                    stop = NOT_POSITIVE_DEFINITE
                    break
            else:
                decrease = current_cost - new_cost
                gain = decrease / predicted
                if not np.isfinite(new_cost):
                    gain = -np.inf
                if not lm:
                    if decrease >= 0:
                        accepted = True
                    elif _negligible(-decrease, current_cost, params) and _negligible(predicted, current_cost, params):
                        stop = CONVERGED_PREDICTED
                    else:
                        stop = NO_DECREASE
                    break
                if gain > params.min_gain_ratio:
                    accepted = True
                    if params.lambda_update == "nielsen":
                        lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                        nu = 2.0
                    else:
                        lam /= params.lambda_factor
                    lam = max(lam, params.lambda_min)
                    break
                if _negligible(predicted, current_cost, params) and _negligible(abs(decrease), current_cost, params):
                    # At round-off level: the model and the cost agree no measurable decrease is left.
                    stop = CONVERGED_PREDICTED
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
            seconds_linearize=t1 - t0,
            seconds_assemble=t2 - t1,
            seconds_factorize=seconds_factorize,
            seconds_solve=seconds_solve,
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
            reason = _converged(decrease, cost_before, params)
            if reason is not None:
                termination, converged = reason, True
                break

    return finish(termination, converged, records, solver.name, seconds_setup)
