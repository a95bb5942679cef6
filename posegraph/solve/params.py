"""Solver parameters: one dataclass with a docstring per field.

The names and meanings follow gtsam's ``NonlinearOptimizerParams`` and
``LevenbergMarquardtParams`` where they exist; the defaults differ where
gtsam's would stop short of the optimum (see ``docs/solver.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

__all__ = ["SolverParams"]

_METHODS = ("lm", "gn")
_LINEAR_SOLVERS = ("auto", "cholmod", "scipy", "pcg")
_LAMBDA_UPDATES = ("nielsen", "fixed")


@dataclass
class SolverParams:
    """Parameters of :func:`posegraph.solve.optimize`.

    Convergence is gtsam's test, ``Δ = cost_before − cost_after`` after an
    accepted step: converged when ``Δ <= absolute_tolerance`` or
    ``Δ / cost_before <= relative_tolerance``; in addition when the cost itself
    is at most ``cost_tolerance`` or when the linear model predicts a decrease
    smaller than those tolerances (then no step can do measurably better).
    """

    method: str = "lm"
    """``"lm"`` (Levenberg-Marquardt, the robust default) or ``"gn"`` (plain Gauss-Newton steps)."""

    max_iterations: int = 100
    """Maximum number of outer iterations (relinearisations), as gtsam's ``maxIterations``.
    LM retries of one iteration with a larger λ do not count as iterations."""

    relative_tolerance: float = 1e-7
    """Stop when an accepted step decreases the cost by at most this fraction of it (gtsam's
    ``relativeErrorTol``, there 1e-5). Tighter than gtsam's because 1e-5 can stop short: on
    pose3example.txt gtsam ends 2.5e-6 above the optimum. At 1e-7 every standard file ends within
    2.1e-8 of the optimum (most within 3e-10) — a 50× margin on the 1e-6 goal — for at most one
    iteration more than 1e-6 would take (table in ``docs/solver.md``)."""

    absolute_tolerance: float = 1e-12
    """Stop when an accepted step decreases the cost by at most this much (gtsam's
    ``absoluteErrorTol``, there 1e-5)."""

    cost_tolerance: float = 0.0
    """Stop when the cost is at most this (gtsam's ``errorTol``)."""

    initial_lambda: float = 1e-12
    """LM: initial damping λ (gtsam's ``lambdaInitial``, there 1e-5). Small, i.e. LM starts as
    Gauss-Newton and damps only after a step has failed (which the line search first tries to
    shorten): even a relative ``λ·diag(H)`` of 1e-5 slows the weakly determined directions of
    ill-conditioned graphs. From the chordal start, 1e-12 instead of 1e-5 took parking-garage from
    7 factorisations to 3, sphere2500 from 4 to 3, synthetic hard graphs 21 and 24 from 12 and 11
    to 4 and 5, roll-blind 32 from 95 to 71, and never more; from the file's poses parking-garage
    from 7 to 4 and otherwise the same, except roll-blind 32 from the ground truth (32 to 42). Every
    run ends at the same optimum (within 2e-8). Pass 1e-5 for gtsam's behaviour."""

    lambda_factor: float = 10.0
    """LM with ``lambda_update="fixed"``: λ is multiplied by it after a rejected step and divided by it
    after an accepted one (gtsam's ``lambdaFactor``). With ``"nielsen"`` it is unused."""

    lambda_min: float = 1e-12
    """LM: lower bound of λ (gtsam's ``lambdaLowerBound`` is 0; a positive floor keeps the damped
    system positive definite when H is singular to round-off)."""

    lambda_max: float = 1e10
    """LM: when a rejected step would push λ above this, stop with ``"lambda exceeded bound"``
    (gtsam's ``lambdaUpperBound``, there 1e5 with λ·I damping)."""

    lambda_update: str = "fixed"
    """LM: how λ follows the gain ratio ρ = actual / predicted decrease. ``"nielsen"``
    (Nielsen 1999; Madsen, Nielsen & Tingleff, *Methods for non-linear least squares problems*, 2004):
    accepted → λ·max(1/3, 1 − (2ρ − 1)³), rejected → λ·ν with ν doubling on each consecutive
    rejection. ``"fixed"``: gtsam's default, ÷/× ``lambda_factor``."""

    min_gain_ratio: float = 1e-3
    """LM: a step is accepted when ρ exceeds this (gtsam's ``minModelFidelity``, same default)."""

    line_search: bool = True
    """Backtrack along a step the quadratic model over-promised instead of discarding it: when the full
    step δ fails (LM: gain ratio ≤ ``min_gain_ratio``; GN: no sufficient decrease), try ``X ⊕ t·δ`` with
    ``t`` from quadratic interpolation of ``φ(t) = F(X ⊕ t·δ)`` through ``φ(0)``, ``φ'(0) = gᵀδ`` and
    the last trial, kept in ``[0.1, 0.5]`` of the previous ``t``, until the sufficient-decrease
    (Armijo) condition ``φ(t) ≤ φ(0) + sufficient_decrease · t · φ'(0)`` holds (then, if the first
    ``t`` was clamped, two log-scale bisections towards the failed ``t`` while φ keeps falling), or
    ``t`` falls below ``line_search_min_step``. An accepted shortened step counts as a successful LM
    step (λ shrinks). Each trial costs one evaluation of the residuals, no factorisation. Without
    it (gtsam's behaviour) Gauss-Newton stops at the first step that raises the cost and LM raises
    λ, which on graphs whose information spans many orders of magnitude damps the weakly determined
    directions to a crawl (``docs/solver.md``, "Ill-conditioned graphs"). On the standard files no
    step fails, so it never runs there."""

    line_search_min_step: float = 1e-3
    """Smallest fraction ``t`` of a step the line search tries before giving up on the step (then LM
    raises λ, GN stops). Far from the optimum of the roll-blind synthetic graph the accepted ``t`` are
    0.02–0.1 for dozens of iterations, so the floor sits an order of magnitude below those."""

    sufficient_decrease: float = 1e-4
    """Armijo constant ``c₁`` of the line search, and of Gauss-Newton's full-step test when
    ``line_search`` is on (without it GN accepts any step that does not raise the cost)."""

    reuse_factorization: bool = True
    """Chord steps: after a full step whose gain ratio was within 10% of 1, first solve the next
    linearisation's system with the factorisation that step came from (H has barely changed in
    Newton's region). The step is taken — its record has ``attempts == 0`` — only if H agrees with
    that factorisation along it, its predicted decrease is at most a tenth of the last decrease
    (or already within the tolerances) and its gain ratio exceeds ``min_gain_ratio``; otherwise
    the system is factorised as usual, after one triangular solve spent in vain (see
    :mod:`posegraph.solve.optimizer`). From the chordal start sphere2500, torus3D and
    parking-garage take 2 factorisations instead of 4, the other shared files 1–3 fewer or the
    same, at the same iterations and final costs within 2e-10 relative (``docs/solver.md``)."""

    decrement_stop: bool = True
    """With ``reuse_factorization``: stop when the Newton decrement under the held factorisation,
    ``½gᵀM⁻¹g``, is 100 times below the tolerances (M barely damped), after taking its chord step
    if the cost confirms M's model along it; the last iteration then assembles no H and factorises
    nothing. Off, such an iteration tests the chord step against the new H and factorises if it is
    stale. Measured from the chordal start (``benchmarks/solver_heuristics.py``): it saves one
    factorisation on parking-garage (2 instead of 3), where it stops 2e-10 relative above the
    optimum with poses 4e-3 from it; elsewhere it changes nothing (``docs/solver.md``)."""

    diagonal_damping: bool = True
    """LM: damp with λ·diag(H) (Marquardt, scale invariant; diagonal clamped to
    [``min_diagonal``, ``max_diagonal``] as gtsam does) if True, else with λ·I (gtsam's default,
    ``diagonalDamping=false``)."""

    min_diagonal: float = 1e-6
    """LM with ``diagonal_damping``: lower clamp of diag(H) in the damping term (gtsam's ``minDiagonal``)."""

    max_diagonal: float = 1e32
    """LM with ``diagonal_damping``: upper clamp of diag(H) in the damping term (gtsam's ``maxDiagonal``)."""

    linear_solver: str = "auto"
    """Sparse solver for the normal equations (:func:`posegraph.solve.linear.make_linear_solver`):
    ``"cholmod"`` (CHOLMOD's supernodal Cholesky from the cvxopt wheel, :mod:`posegraph.linalg.cholmod`;
    symbolic analysis once per graph), ``"scipy"`` (SuperLU without pivoting in symmetric mode;
    needs only scipy), ``"pcg"`` (no factorisation: conjugate gradients preconditioned by
    aggregation multigrid, pyamg; memory linear in the graph, for graphs whose factor
    would not fit: :mod:`posegraph.linalg.multigrid`), or ``"auto"`` (CHOLMOD when cvxopt imports, else
    scipy). Figures in ``docs/cholesky.md`` and ``docs/benchmarks.md`` ("Memory per pose")."""

    linear_tolerance: float = 1e-8
    """``"pcg"``: the tightest relative residual ‖b − Ax‖/‖b‖ CG is asked for (:data:`posegraph.linalg.multigrid.DEFAULT_TOLERANCE`);
    looser while LM is far from converged (Eisenstat–Walker forcing, :class:`posegraph.solve.linear.MultigridSolver`).
    Ignored by the direct solvers."""

    ordering: str = "auto"
    """Fill-reducing ordering for ``"cholmod"`` (:data:`posegraph.linalg.cholmod.ORDERINGS`): ``"amd"``
    or ``"nesdis"`` (= ``"metis"``: METIS nested dissection through pymetis), both of the vertex
    graph; ``"natural"``; ``"default"`` (CHOLMOD's own AMD of the scalar pattern); or ``"auto"``:
    AMD below 10,000 free vertices, nested dissection from there on (measured fastest on pose
    graphs: :data:`posegraph.linalg.cholmod.NESTED_DISSECTION_VERTICES`, ``docs/cholesky.md``). Ignored
    by ``"scipy"``."""

    blas_threads: Optional[int] = 1
    """Threads of the OpenBLAS cvxopt bundles under CHOLMOD during its factorisations and solves,
    restored afterwards (:mod:`posegraph.linalg.native_threads`, through threadpoolctl). cvxopt's CHOLMOD
    has no OpenMP, and the Linux x86_64 wheel's OpenBLAS is single-threaded, so there this changes
    nothing; it caps a threaded build (other platforms' wheels). None leaves the BLAS as it is.
    Measured on the system OpenBLAS of an earlier backend, 2-core machine: one thread factorised
    torus3D in 0.071 s against 0.089 s with the defaults when the machine was idle, and 0.069 s
    against 0.18 s while other jobs ran; raise it on a big, idle machine with large graphs."""

    loss: Optional[Any] = None
    """A robust loss of each edge's squared norm ``s = eᵀΩe`` (:class:`posegraph.solve.objective.Loss`:
    ``rho(s)`` and ``weight(s) = ρ'(s)``, batched over edges): the solver then minimises ``½ Σ ρ(s)``,
    linearised by IRLS (per-edge weights ``ρ'(s)`` on the gradient and H blocks). None (the
    default) is least squares, ``½ Σ s``, with exactly the arithmetic of no weights at all."""

    callback: Optional[Callable[..., None]] = None
    """Called with each :class:`~posegraph.solve.result.IterationRecord` as it is made (e.g. to print
    progress). Returning ``True`` (or raising ``StopIteration``) stops the solver with reason ``"callback"``."""

    estimate_callback: Optional[Callable[..., None]] = None
    """Called after each iteration, before :attr:`callback`, with ``(record, poses, points)``: its
    :class:`~posegraph.solve.result.IterationRecord`, the ``(n, k, k)`` poses and the ``(L, s)`` landmark
    positions (None without landmarks) the iteration ends at — the solver's own arrays, never changed in
    place afterwards (a later iteration makes new ones), to be read, not written (e.g. to record the
    estimate's path: :mod:`posegraph.analysis.rerun_log`). Its return value is ignored."""

    def __post_init__(self) -> None:
        if self.method not in _METHODS:
            raise ValueError(f"method must be one of {_METHODS}, got {self.method!r}")
        if self.linear_solver not in _LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be one of {_LINEAR_SOLVERS}, got {self.linear_solver!r}")
        if self.lambda_update not in _LAMBDA_UPDATES:
            raise ValueError(f"lambda_update must be one of {_LAMBDA_UPDATES}, got {self.lambda_update!r}")
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 0:
            raise ValueError(f"max_iterations must be a non-negative integer, got {self.max_iterations!r}")
        for name in ("relative_tolerance", "absolute_tolerance", "cost_tolerance", "lambda_min", "min_diagonal"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0 < self.linear_tolerance < 1:
            raise ValueError(f"linear_tolerance must be in (0, 1), got {self.linear_tolerance!r}")
        for name in ("initial_lambda", "lambda_max", "max_diagonal"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not self.lambda_factor > 1:
            raise ValueError(f"lambda_factor must be > 1, got {self.lambda_factor!r}")
        if not self.lambda_min <= self.initial_lambda <= self.lambda_max:
            raise ValueError("need lambda_min <= initial_lambda <= lambda_max")
        if self.blas_threads is not None and (int(self.blas_threads) != self.blas_threads or self.blas_threads < 1):
            raise ValueError(f"blas_threads must be a positive integer or None, got {self.blas_threads!r}")
        if not 0 < self.line_search_min_step < 1:
            raise ValueError(f"line_search_min_step must be in (0, 1), got {self.line_search_min_step!r}")
        if not 0 < self.sufficient_decrease < 0.5:
            raise ValueError(f"sufficient_decrease must be in (0, 0.5), got {self.sufficient_decrease!r}")
        if self.loss is not None and not (callable(getattr(self.loss, "rho", None)) and callable(getattr(self.loss, "weight", None))):
            raise ValueError("loss must have methods rho(s) and weight(s), or be None")
        if self.callback is not None and not callable(self.callback):
            raise ValueError("callback must be callable or None")
        if self.estimate_callback is not None and not callable(self.estimate_callback):
            raise ValueError("estimate_callback must be callable or None")
