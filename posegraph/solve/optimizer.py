"""Levenberg-Marquardt and Gauss-Newton over pose graphs of any Lie group, as one trust-region loop.

Each iteration of :func:`optimize`:

1. **linearise** the cost at the current poses: gradient ``g`` at once, ``H`` on first use
   (:class:`_System`; :mod:`posegraph.solve.objective`, :mod:`posegraph.solve.sparsity`);
2. **try the held factorisation** ``M`` (:func:`_try_held_factorization`, only after a full step
   whose gain ratio was near 1): its Newton decrement ``½gᵀM⁻¹g`` may show the optimum reached
   (stop without assembling H, after taking the chord step ``−M⁻¹g`` if the cost confirms it), or
   the chord step may be good enough to take;
3. else **damp, factorise, solve** ``(H + λD) δ = −g`` (:func:`_solve_damped`,
   :class:`~posegraph.solve.trust_region.Damping`) and **judge the step** (:func:`_judge`) by
   the gain ratio ``ρ`` of actual to predicted decrease, shortening an over-promising step by an
   Armijo line search (:func:`~posegraph.solve.trust_region.backtrack`); **accept** (λ shrinks)
   or **adapt λ** (grows) and refactorise the same linearisation (:func:`_trust_region_step`);
4. **test convergence** (:func:`_termination`): gtsam's relative / absolute decrease test on
   the larger of the actual and the full step's predicted decrease.

Gauss-Newton is the same loop with λ = 0 and one attempt per iteration. The group (tangent
dimension, Exp) comes from ``graph.group``; the cost and its linearisation from
:class:`~posegraph.solve.objective.Objective`, which takes the robust loss of
``SolverParams.loss`` (None: least squares, exactly).

Chord steps (``reuse_factorization``, Shamanskii's chord Newton method): in Newton's region H
changes little between iterates, so after a full step with gain ratio within
:data:`CHORD_MIN_GAIN` of 1 the next iteration first solves its system with the factorisation it
still holds. The step is taken only if H still agrees with ``M`` along it
(:data:`CHORD_AGREEMENT`), it promises a fast enough decrease (:data:`CHORD_CONTRACTION` of the
last one, or already within the tolerances) and the cost confirms it (gain ratio); ``M`` is then
kept for the iteration after. Measured effects: ``docs/solver.md``.

Gauge: fixed vertices and the anchor of every component without one and without priors
(:func:`posegraph.model.graph.held_vertices`) have no variables at all, so the cost is exactly the
graph's, with no prior added. The graph's own priors (unary edges, :mod:`posegraph.solve.unary`)
are terms of the cost like the edges.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from posegraph.model.graph import PoseGraph, held_vertices
from posegraph.solve.clock import PhaseClock
from posegraph.solve.gauge import central_anchors, moved_back, reported_moved_back
from posegraph.solve.linear import NotPositiveDefiniteError, make_linear_solver
from posegraph.solve.objective import Evaluation, Objective
from posegraph.solve.params import SolverParams
from posegraph.solve.result import IterationRecord, OptimizeResult
from posegraph.solve.sparsity import (
    HessianPattern, PinnedVariables, analyze_pattern, gradient_values, hessian_values, lower_matvec,
)
from posegraph.solve.unary import add_prior_gradient, add_prior_hessian
from posegraph.solve.trust_region import (  # noqa: F401  (the termination reasons, re-exported)
    CALLBACK, CONVERGED_ABSOLUTE, CONVERGED_COST, CONVERGED_DECREMENT, CONVERGED_NOTHING, CONVERGED_PREDICTED,
    CONVERGED_RELATIVE, LAMBDA_EXCEEDED, MAX_ITERATIONS, NO_DECREASE, NON_FINITE, NOT_POSITIVE_DEFINITE,
    Damping, backtrack, converged, model_decrease, negligible,
)

__all__ = ["optimize", "Analysis", "analyze"]


@dataclass(frozen=True, eq=False)
class Analysis:
    """The symbolic work of :func:`optimize` for one graph structure, reusable across calls.

    Depends only on the edges ``(edge_from, edge_to)``, the held vertices and the group's
    tangent dimension — not on measurements, information or poses — so a caller that solves the
    same graph many times with new information (IRLS, GNC outer iterations) builds it once with
    :func:`analyze` and passes it to every :func:`optimize` call: the Hessian's block pattern and
    scatter positions, and the linear solver with its fill-reducing ordering and symbolic
    factorisation, are then made once.
    """

    edge_from: np.ndarray
    """``(m,)`` the edges' first vertices, as analysed."""
    edge_to: np.ndarray
    """``(m,)`` the edges' second vertices."""
    held: np.ndarray
    """``(n,)`` bool, vertices without variables (:func:`posegraph.model.graph.held_vertices`)."""
    pattern: HessianPattern
    """Block pattern of H (:func:`posegraph.solve.sparsity.analyze_pattern`)."""
    solver: object
    """The linear solver, symbolic analysis done (:mod:`posegraph.solve.linear`); None when nothing is free."""
    seconds: float
    """Seconds spent analysing."""

    def matches(self, graph: PoseGraph) -> bool:
        """Whether ``graph`` has exactly the edges this analysis was made for."""
        return np.array_equal(self.edge_from, graph.edge_from) and np.array_equal(self.edge_to, graph.edge_to)


def analyze(graph: PoseGraph, params: SolverParams | None = None) -> Analysis:
    """The :class:`Analysis` of ``graph`` for the linear solver, ordering and threads of ``params``."""
    start = time.perf_counter()
    params = SolverParams() if params is None else params
    held = held_vertices(graph)
    points = None
    if graph.landmarks is not None:  # (imported here: a pose graph's run does without the module)
        from posegraph.solve.landmark_terms import point_variables

        points = point_variables(graph)
    pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held, graph.group.dim, points)
    solver = None
    measured = graph.num_edges + (graph.landmarks.num_measurements if graph.landmarks is not None else 0)
    if pattern.num_variables > 0 and measured > 0:
        solver = make_linear_solver(
            params.linear_solver, pattern, params.ordering, params.blas_threads, params.linear_tolerance,
            factor_needed=False,
        )  # fmt: skip
    edges = (np.array(graph.edge_from, copy=True), np.array(graph.edge_to, copy=True))
    return Analysis(*edges, held, pattern, solver, time.perf_counter() - start)


def optimize(
    graph: PoseGraph,
    initial=None,
    params: SolverParams | None = None,
    *,
    analysis: Analysis | None = None,
    hold: np.ndarray | None = None,
    initial_points: np.ndarray | None = None, hold_points: np.ndarray | None = None,
) -> OptimizeResult:
    """Minimise ``½ Σ eᵀ Ω e`` (or ``½ Σ ρ(eᵀΩe)`` with ``params.loss``) over the free poses.

    Parameters
    ----------
    graph : PoseGraph
        Its ``group`` gives the pose matrices ``(k, k)`` and the tangent dimension ``d``; its
        ``landmarks``, if any, are solved with the poses (``docs/landmarks.md``).
    initial : None, str or (n, k, k) array
        Starting poses: an array, or the name of an initialiser — ``"file"`` (the graph's own
        poses), ``"chordal"`` or ``"odometry"`` (:func:`posegraph.init.initialize`; a landmark graph whose
        own values fit its measurements starts there for ``"chordal"``: :mod:`posegraph.solve.file_start`).
        ``None`` means ``"chordal"``.
    params : SolverParams, optional
        Method, tolerances, damping, loss and linear solver (:class:`~posegraph.solve.params.SolverParams`).
    analysis : Analysis, optional
        The symbolic analysis of a graph with the same edges (:func:`analyze`), reused instead of
        made anew (its linear solver, not ``params.linear_solver``, then runs). ``ValueError``
        when its edges differ from ``graph``'s.
    hold : (n,) bool array, optional
        Vertices held at their initial pose besides those the analysis holds (their variables stay
        in the analysed system, decoupled: :class:`~posegraph.solve.sparsity.PinnedVariables`).
        With the edges of weight 0 that leave them unconstrained, this solves a subgraph's problem
        over the analysis of a larger edge set.
    initial_points, hold_points : (L, s) array, (L,) bool array, optional
        Starting landmark positions (None: the file's with ``initial="file"``, else each from its
        measurements given the starting poses, :func:`posegraph.init.landmarks.initialize_landmarks`),
        and landmarks held at their start as ``hold`` holds vertices.

    Returns an :class:`OptimizeResult`: final poses (held vertices unchanged) and landmark
    positions, costs, per-iteration records, termination reason and the linear solver that ran.
    """
    start = time.perf_counter()
    params = SolverParams() if params is None else params
    if analysis is not None and not analysis.matches(graph):
        raise ValueError("the analysis was made for other edges than the graph's")
    poses = _initial_poses(graph, initial)
    points = _initial_points(graph, initial, poses, initial_points)
    # (a given analysis or hold was made for the conventional gauge: solved in it)
    gauge = central_anchors(graph, poses) if analysis is None and hold is None and hold_points is None else None
    if gauge is None:
        return _optimize_from(graph, poses, points, params, analysis, hold, hold_points, start)
    if params.estimate_callback is not None:
        params = replace(params, estimate_callback=reported_moved_back(params.estimate_callback, graph, gauge[1], poses))
    result = _optimize_from(gauge[0], poses, points, params, None, None, None, start)
    moved, points = moved_back(graph, gauge[1], poses, result.poses, result.points)
    return replace(result, poses=moved, points=points)


def _optimize_from(graph: PoseGraph, poses, points, params: SolverParams, analysis, hold, hold_points, start: float) -> OptimizeResult:
    """The iterations of :func:`optimize` from ``poses``, ``points`` in ``graph``'s gauge."""
    run = _Run(graph, (poses, points), params, analysis, hold, hold_points)
    early = run.nothing_to_do()
    if early is not None:
        return run.result(early, [], start)
    records, termination = [], MAX_ITERATIONS
    for number in range(1, run.params.max_iterations + 1):
        system = run.linearize()
        outcome = _try_held_factorization(run, system) if run.held_lambda is not None else None
        if outcome is None:
            outcome = _trust_region_step(run, system)
        records.append(run.advance(number, outcome))
        termination = _termination(run, outcome, records[-1])
        if termination is not None:
            break
    return run.result(termination or MAX_ITERATIONS, records, start)


def _initial_poses(graph: PoseGraph, initial) -> np.ndarray:
    """The starting poses ``(n, k, k)``: given, the file's, or from an initialiser (checked finite)."""
    if initial is None:
        initial = "chordal"
    if isinstance(initial, str):
        if initial == "file":
            poses = graph.poses
        else:
            from posegraph.solve.file_start import start_poses

            poses = start_poses(graph, initial)
    else:
        poses = initial
    poses = np.array(poses, dtype=np.float64, copy=True)
    k = graph.group.matrix_size
    if poses.shape != (graph.num_vertices, k, k):
        raise ValueError(f"initial poses must have shape ({graph.num_vertices}, {k}, {k}), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise ValueError("initial poses contain NaN or infinite values")
    return poses


def _initial_points(graph: PoseGraph, initial, poses: np.ndarray, given) -> np.ndarray | None:
    """The starting landmark positions ``(L, s)`` (module :mod:`posegraph.model.landmarks`), None without landmarks."""
    if graph.landmarks is None:
        return None
    if given is None and isinstance(initial, str) and initial == "file":
        given = graph.landmarks.positions
    if given is None:
        from posegraph.init.landmarks import initialize_landmarks

        given, undetermined = initialize_landmarks(graph, poses)
        _warn_undetermined(graph, undetermined)
    points = np.array(given, dtype=np.float64, copy=True)
    if points.shape != graph.landmarks.positions.shape:
        raise ValueError(f"initial landmark positions must have shape {graph.landmarks.positions.shape}, got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("initial landmark positions contain NaN or infinite values")
    return points


def _warn_undetermined(graph: PoseGraph, undetermined: np.ndarray) -> None:
    """An :class:`~posegraph.errors.InputWarning` naming the landmarks its measurements do not determine."""
    if not undetermined.any():
        return
    import warnings

    from posegraph.errors import InputWarning

    ids = graph.landmarks.ids[undetermined]
    shown = ", ".join(str(i) for i in ids[:10].tolist()) + (f" and {ids.size - 10} more" if ids.size > 10 else "")
    where = f"{graph.source}: " if graph.source else ""
    warnings.warn(
        f"{where}{ids.size} landmark{'s' if ids.size > 1 else ''} not determined by {'their' if ids.size > 1 else 'its'} "
        f"measurements (e.g. a bearing seen from one pose, parallel rays): {shown}; started at a guess, "
        "held only by Levenberg-Marquardt's damping",
        InputWarning, stacklevel=3,
    )  # fmt: skip


@dataclass
class _Trial:
    """A step tried from the current poses, ``X ⊕ scale·δ``, and how it was judged."""

    lambda_: float
    """λ of the factorisation it was solved with (0 for Gauss-Newton)."""
    step: np.ndarray | None = None
    """``(dp,)`` solved step δ, or None when the factorisation failed."""
    slope: float = float("nan")
    """``gᵀδ``, the directional derivative ``φ'(0)`` of ``φ(t) = F(X ⊕ t·δ)``."""
    predicted: float = float("nan")
    """Model decrease ``L(0) − L(δ)`` of the full step."""
    damping_term: float = 0.0
    """``λ δᵀDδ`` (for the model decrease of a shortened step)."""
    poses: np.ndarray | None = None
    """Poses at the trial (None: no usable step)."""
    points: np.ndarray | None = None
    """Landmark positions at the trial (None for a pose graph)."""
    evaluation: Evaluation | None = None
    """The cost there."""
    gain: float = float("nan")
    """Gain ratio at the scale taken."""
    scale: float = float("nan")
    """Fraction of δ taken (1 for a full step; NaN for a rejected one)."""
    accepted: bool = False

    @property
    def norm(self) -> float:
        """Euclidean norm of δ (0 without a step)."""
        if self.step is None:
            return 0.0
        return float(np.sqrt(np.einsum("i,i->", self.step, self.step)))


@dataclass
class _Outcome:
    """What one iteration did: the last trial (accepted or not), attempts, and a stop if any."""

    trial: _Trial
    attempts: int = 0
    """Factorisations in this iteration (0 when the held one served)."""
    stop: str | None = None
    """A termination reason found during the iteration."""
    hold: bool = False
    """Whether the factorisation behind the accepted step may serve the next iteration."""


class _Run:
    """The state of one :func:`optimize` call: the problem, the current poses and cost, λ, the clock."""

    def __init__(self, graph: PoseGraph, start: tuple, params: SolverParams, analysis: Analysis | None, hold=None,
                 hold_points=None):
        setup_start = time.perf_counter()
        self.graph, self.params = graph, params
        self.poses, self.points = start
        analysis = analyze(graph, params) if analysis is None else analysis
        self.free = ~analysis.held
        self.pattern: HessianPattern = analysis.pattern
        if hold is None and hold_points is not None:
            hold = np.zeros(graph.num_vertices, dtype=bool)
        self.pinned = None if hold is None else PinnedVariables.of(self.pattern, hold, hold_points)
        self.objective = Objective(graph, params.loss)
        self.evaluation = self.objective.evaluate(self.poses, self.points)
        self.initial_cost = self.evaluation.cost
        if not np.isfinite(self.initial_cost):
            raise ValueError("the cost at the initial poses is not finite")
        self.solver = analysis.solver
        self.seconds_setup = time.perf_counter() - setup_start
        self.damping = Damping(params)
        self.clock = PhaseClock()
        self.held_lambda: float | None = None  # λ of the held factorisation, while it may serve
        self.last_decrease = np.inf
        self.cost_before = self.initial_cost

    @property
    def cost(self) -> float:
        """The cost at the current poses."""
        return self.evaluation.cost

    def nothing_to_do(self) -> str | None:
        """The reason to stop before the first iteration, if any."""
        if self.solver is None:
            return CONVERGED_NOTHING
        if self.cost <= self.params.cost_tolerance:
            return CONVERGED_COST
        return None

    def linearize(self) -> "_System":
        """The normal equations at the current poses (gradient now, H on first use)."""
        if self.held_lambda is None:
            self.solver.release()  # what it made for the last H is not needed while the next is built
        self.solver.linearized_at(self.poses, self.free, self.graph.group)
        with self.clock.phase("linearize"):
            blocks = self.objective.linearize(self.poses, self.evaluation)
        with self.clock.phase("assemble"):
            gradient = gradient_values(self.pattern, blocks.gradient)
            if blocks.priors is not None:
                add_prior_gradient(self.pattern, gradient, blocks.priors)
            if blocks.landmarks is not None:
                from posegraph.solve.landmark_terms import add_landmark_gradient

                add_landmark_gradient(self.pattern, gradient, blocks.landmarks)
            if self.pinned is not None:
                self.pinned.zero_gradient(gradient)
        return _System(self, blocks, gradient)

    def retract(self, step: np.ndarray) -> tuple:
        """``(poses, points)`` moved by the step ``δ`` ``(D,)``: ``X_k · Exp(δ_k)`` for the free vertices,
        ``p_l + δ_l`` for the free landmarks; held ones unchanged."""
        out = self.poses.copy()
        steps = step[: self.pattern.pose_dimension].reshape(-1, self.pattern.block_size)
        out[self.free] = self.poses[self.free] @ self.graph.group.exp(steps)
        if self.points is None:
            return out, None
        from posegraph.solve.landmark_terms import retract_points

        return out, retract_points(self.pattern, self.points, step)

    def evaluate_step(self, trial: _Trial) -> None:
        """Poses, cost and gain ratio of the full step ``X ⊕ δ``."""
        trial.poses, trial.points = self.retract(trial.step)
        trial.evaluation = self.objective.evaluate(trial.poses, trial.points)
        new_cost = trial.evaluation.cost
        trial.gain = (self.cost - new_cost) / trial.predicted if np.isfinite(new_cost) else -np.inf

    def advance(self, number: int, outcome: _Outcome) -> IterationRecord:
        """Move to an accepted step, keep or drop the held factorisation, and record the iteration."""
        trial, decrease = outcome.trial, 0.0
        if trial.accepted:
            decrease = self.cost - trial.evaluation.cost
            self.last_decrease, self.cost_before = decrease, self.cost
            self.poses, self.points, self.evaluation = trial.poses, trial.points, trial.evaluation
        self.held_lambda = trial.lambda_ if outcome.hold else None
        return IterationRecord(
            iteration=number,
            cost=self.cost,
            cost_decrease=decrease,
            lambda_=trial.lambda_ if self.damping.active else 0.0,
            step_norm=trial.norm,
            gain_ratio=trial.gain,
            accepted=trial.accepted,
            attempts=outcome.attempts,
            step_scale=trial.scale,
            **self.clock.lap(),
        )

    def result(self, termination: str, records: list, start: float) -> OptimizeResult:
        """The outcome, with the current poses and cost; ``start`` is when :func:`optimize` began."""
        return OptimizeResult(
            poses=self.poses,
            points=self.points,
            initial_cost=self.initial_cost,
            final_cost=self.cost,
            iterations=len(records),
            termination=termination,
            converged=termination.startswith("converged"),
            linear_solver="none" if self.solver is None else self.solver.name,
            method=self.params.method,
            records=records,
            seconds_setup=self.seconds_setup,
            seconds_total=time.perf_counter() - start,
            final_residuals=self.evaluation.residuals,
        )


class _System:
    """The normal equations of one linearisation: gradient ``g`` ``(dp,)`` and, on first use, H."""

    def __init__(self, run: _Run, blocks, gradient: np.ndarray):
        self.run, self.blocks, self.gradient = run, blocks, gradient

    @cached_property
    def hessian(self) -> np.ndarray:
        """CSC ``data`` of the lower triangle of H (:mod:`posegraph.solve.sparsity`)."""
        with self.run.clock.phase("assemble"):  # the Hessian blocks made and added a slice of edges at a time
            data = hessian_values(self.run.pattern, self.blocks.hessian_slice)
            if self.blocks.priors is not None:
                add_prior_hessian(self.run.pattern, data, self.blocks.priors)
            if self.blocks.landmarks is not None:
                from posegraph.solve.landmark_terms import add_landmark_hessian

                add_landmark_hessian(self.run.pattern, data, self.blocks.landmarks)
        # Assembled: H and g alone are used from here on. The edge blocks (Jacobian factors, adjoints,
        # per-edge gradients: ~600 bytes an SE(3) edge) go before the factorisation needs the memory.
        self.blocks = None
        return data if self.run.pinned is None else self.run.pinned.decouple(data)


def _trust_region_step(run: _Run, system: _System) -> _Outcome:
    """Damp, factorise, solve and judge; on rejection grow λ and refactorise the same H.

    Gauss-Newton makes one attempt (every rejection there is a stop). LM stops with
    ``"lambda exceeded bound"`` when λ would pass ``lambda_max``.
    """
    attempts = 0
    while True:
        attempts += 1
        trial = _solve_damped(run, system)
        with run.clock.phase("solve"):
            stop = _judge(run, trial)
        if trial.accepted or stop is not None:
            hold = trial.accepted and trial.scale == 1.0 and run.params.reuse_factorization and run.solver.holds_factorization
            return _Outcome(trial, attempts, stop, hold and _in_newton_region(trial.gain))
        if not run.damping.grow():
            return _Outcome(trial, attempts, LAMBDA_EXCEEDED)


def _solve_damped(run: _Run, system: _System) -> _Trial:
    """Factorise ``H + λD``, solve ``(H + λD) δ = −g`` and evaluate the full step when it is usable.

    The step is unusable (``trial.poses`` None) when the factorisation fails, δ is not finite or
    the model predicts no decrease.
    """
    trial = _Trial(run.damping.lam)
    data = system.hessian
    with run.clock.phase("factorize"):
        shift = run.damping.shift(data, run.pattern.diagonal)
        try:
            run.solver.factorize(data, shift)
        except NotPositiveDefiniteError:
            return trial
    with run.clock.phase("solve"):
        try:
            trial.step = step = run.solver.solve(-system.gradient)
        except NotPositiveDefiniteError:  # an iterative solver finds it only here
            return trial
        # (einsum, not a BLAS dot: numpy's BLAS threads would then spin against CHOLMOD's)
        trial.slope = float(np.einsum("i,i->", system.gradient, step))  # φ'(0) = gᵀδ
        trial.damping_term = run.damping.term(step)
        trial.predicted = model_decrease(1.0, trial.slope, trial.damping_term)
        if np.all(np.isfinite(step)) and trial.predicted > 0:
            run.evaluate_step(trial)
    return trial


def _judge(run: _Run, trial: _Trial) -> str | None:
    """Accept the trial (possibly shortened by the line search) or not; returns a stop, if any.

    Acceptance: LM, gain ratio above ``min_gain_ratio``; GN, the Armijo condition (with the line
    search) or no increase (gtsam's, without it). A failed full step is shortened by
    :func:`_shorten` when ``line_search`` is on. A rejection at round-off level (model and cost
    both agree nothing measurable is left) is convergence; other rejections stop Gauss-Newton.
    """
    params, lm = run.params, run.damping.active
    if trial.poses is None:
        if np.isfinite(trial.predicted) and abs(trial.predicted) <= 1e-300:
            return CONVERGED_PREDICTED  # zero gradient: nothing left to decrease
        return None if lm else NOT_POSITIVE_DEFINITE
    decrease = run.cost - trial.evaluation.cost
    if lm:
        accepted = trial.gain > params.min_gain_ratio
    elif params.line_search:
        accepted = trial.evaluation.cost <= run.cost + params.sufficient_decrease * trial.slope  # Armijo
    else:
        accepted = decrease >= 0  # plain Gauss-Newton (gtsam's): any step that does not increase F
    trial.scale = 1.0
    if not accepted and params.line_search:
        accepted = _shorten(run, trial)
    if accepted:
        trial.accepted = True
        run.damping.shrink(trial.gain)
        return None
    trial.scale = float("nan")
    if negligible(trial.predicted, run.cost, params) and negligible(abs(decrease), run.cost, params):
        return CONVERGED_PREDICTED  # at round-off level: nothing measurable left
    return None if lm else NO_DECREASE


def _shorten(run: _Run, trial: _Trial) -> bool:
    """Armijo line search along the failed full step (:func:`~posegraph.solve.trust_region.backtrack`).

    On success the trial holds the shortened step's poses, cost, scale ``t`` and gain ratio (over
    the model decrease at ``t``).
    """
    def cost_at(t):
        poses, points = run.retract(t * trial.step)
        evaluation = run.objective.evaluate(poses, points)
        return evaluation.cost, (poses, points, evaluation)

    found = backtrack(cost_at, run.cost, trial.slope, trial.evaluation.cost, run.params)
    if found is None:
        return False
    trial.scale, new_cost, (trial.poses, trial.points, trial.evaluation) = found
    trial.gain = (run.cost - new_cost) / model_decrease(trial.scale, trial.slope, trial.damping_term)
    return True


def _termination(run: _Run, outcome: _Outcome, record: IterationRecord) -> str | None:
    """Why to stop after this iteration, if at all: a stop found in it, the callback, the cost or
    its tolerance, or gtsam's decrease test on an accepted step.

    A small actual decrease alone can mislead: a shortened step, or a full step the model
    over-promised (gain well below 1), leaves up to its predicted decrease on the table, which must
    be small too. At a full step with gain ≈ 1 (every standard file) the two agree.
    """
    stop = outcome.stop
    if run.params.estimate_callback is not None:
        run.params.estimate_callback(record, run.poses, run.points)
    if run.params.callback is not None:
        try:
            if run.params.callback(record) is True:
                stop = stop or CALLBACK
        except StopIteration:
            stop = stop or CALLBACK
    if stop is not None or not outcome.trial.accepted:
        return stop
    if not np.isfinite(run.cost):
        return NON_FINITE
    if run.cost <= run.params.cost_tolerance:
        return CONVERGED_COST
    verdict = converged(max(record.cost_decrease, outcome.trial.predicted), run.cost_before, run.params)
    if verdict is not None and not run.solver.confirm_convergence():
        return None  # the step was solved loosely (pcg's forcing): the next one is solved fully first
    return verdict


# Held factorisation: Newton decrement and chord steps
# ----------------------------------------------------

CHORD_CONTRACTION = 0.1
"""A step from the previous factorisation is taken when its predicted decrease is at most this
fraction of the last actual decrease (or within the convergence tolerances): the chord iteration
then still converges at least this fast, so it cannot crawl where a new factorisation would leap.
Measured effect: ``docs/solver.md`` (``reuse_factorization``)."""

CHORD_AGREEMENT = 0.9
"""A step from the previous factorisation ``M`` is taken only if its model decrease under the new
H is at least this fraction of ``−½gᵀδ``, its value were H equal to M (see :func:`_chord_step_decrease`)."""

CHORD_MIN_GAIN = 0.9
"""The previous factorisation is tried only after a full step whose gain ratio was at least this
(and at most its inverse): the quadratic model was accurate there, i.e. the run is in Newton's
region, where H changes little from one iterate to the next."""

DECREMENT_MARGIN = 100.0
"""The run stops without a new factorisation when the Newton decrement under the held one,
``½ gᵀM⁻¹g``, is this many times below the convergence tolerances (and M was barely damped)."""

DECREMENT_MAX_LAMBDA = 1e-6
"""The held factorisation's λ up to which ``M = H_old + λD`` stands for ``H_old`` in that test."""


def _try_held_factorization(run: _Run, system: _System) -> _Outcome | None:
    """Use the factorisation ``M`` the solver still holds, before factorising the new H.

    Its Newton decrement ``½gᵀM⁻¹g`` may show the optimum reached (then the run stops without
    assembling H: :func:`_decrement_negligible`); else its chord step ``δ = −M⁻¹g`` is taken if H
    agrees with M along it and it promises a fast enough decrease (:func:`_chord_step_decrease`)
    and the cost confirms it (gain ratio above ``min_gain_ratio``). None: factorise as usual.
    """
    with run.clock.phase("solve"):
        step, slope = _chord_step(run.solver, system.gradient)
        if run.params.decrement_stop and _decrement_negligible(-0.5 * slope, run.cost, run.held_lambda, run.params):
            return _last_chord_step(run, step, slope)
    data = system.hessian
    if step is None:
        return None
    with run.clock.phase("solve"):
        predicted = _chord_step_decrease(run.pattern, data, step, slope, run.cost, run.params, run.last_decrease)
        if predicted is None:
            return None
        trial = _Trial(run.held_lambda, step, slope, predicted)
        run.evaluate_step(trial)
        if not trial.gain > run.params.min_gain_ratio:
            return None
    trial.accepted, trial.scale = True, 1.0
    return _Outcome(trial, attempts=0, hold=_in_newton_region(trial.gain))


def _last_chord_step(run: _Run, step: np.ndarray, slope: float) -> _Outcome:
    """Stop at a negligible Newton decrement, after taking the chord step if the cost confirms it.

    The decrement says no measurable *cost* is left, but along the flat directions of the cost the
    poses may still be a whole step away: sphere2500 from the chordal start stopped 1.6e-7 above
    the optimum with poses 1.6e-3 from it (``docs/solver.md``). The chord step ``δ = −M⁻¹g`` is
    already solved, so one cost evaluation tells whether M's model ``½gᵀM⁻¹g`` still holds along
    it: if the actual decrease is within :data:`CHORD_MIN_GAIN` of it the step is taken (no H is
    ever assembled for it); else (H has moved away from M along δ) the run stops where it is.
    """
    trial = _Trial(run.held_lambda, step, slope, predicted=-0.5 * slope)
    run.evaluate_step(trial)
    if not _in_newton_region(trial.gain):
        return _Outcome(_Trial(run.damping.lam), stop=CONVERGED_DECREMENT)
    trial.accepted, trial.scale = True, 1.0
    return _Outcome(trial, stop=CONVERGED_DECREMENT)


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
    if converged(predicted, cost_now, params) is None and predicted > CHORD_CONTRACTION * last_decrease:
        return None
    return predicted


def _decrement_negligible(decrement: float, cost_now: float, held_lambda: float, params: SolverParams) -> bool:
    """Whether ``decrement = ½ gᵀM⁻¹g`` (M the held factorisation) shows the optimum already reached.

    ``½ gᵀH⁻¹g`` is the decrease a Newton step would still promise; with M the (barely damped) H of
    a nearby iterate it differs by the spread of the eigenvalues of ``M⁻¹H``, so the test leaves a
    factor :data:`DECREMENT_MARGIN` for it.
    """
    if not (np.isfinite(decrement) and decrement >= 0 and held_lambda <= DECREMENT_MAX_LAMBDA):
        return False
    return converged(DECREMENT_MARGIN * decrement, cost_now, params) is not None
