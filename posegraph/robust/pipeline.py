"""Robust pose-graph optimisation with graduated non-convexity: :func:`optimize_robust`.

The pipeline (``docs/robust.md`` measures it and the alternatives):

1. **Start** — by default the robust chordal start
   (:func:`posegraph.robust.starts.robust_chordal_start`): GNC whose weighted solve is the chordal
   initialisation of the weighted graph, so neither the start nor its inlier decisions trust the
   loop closures. Its inlier threshold is :data:`START_THRESHOLD_FACTOR` × ``c̄²``: loose, because
   the relaxation's residuals are inflated, and still far below a wrong loop closure's. With ``initial`` given (poses or an initialiser's name) the start is instead GNC
   over Levenberg-Marquardt from those poses, as gtsam's ``GncOptimizer`` runs it.
2. **Truncated least squares at μ → ∞** (:func:`tls_alternation`): LM on the edges judged inliers,
   then every edge is judged again at the solution — an inlier when its squared whitened residual
   ``s = eᵀΩe`` is at most the threshold ``c̄²`` (GNC's: the χ² quantile at 0.99), or when it is a
   known inlier — until the inlier set repeats. Each round lowers the TLS cost ``½ Σ min(s, c̄²)``
   (alternating minimisation over the poses and the binary weights), so it ends; it rejects the
   outliers the loose start let in and keeps the inliers.

3. **Trust, checked** (:mod:`posegraph.robust.trust`): the known inliers keep weight 1 throughout,
   but by default (``known_inliers="odometry"``) a pair of consecutive vertices joined by parallel
   edges has none of them trusted until GNC has kept one (where it kept none, the one that fits
   best is trusted); and at the result every known inlier whose ``s`` exceeds the family-wise
   threshold (:func:`doubt_thresholds`: right edges in the χ² tail above ``c̄²`` are not doubted),
   or that every edge spanning it contradicts, is doubted: steps 1 and 2 run again without trusting
   it, and the doubted edges are released when that answer fits the graph better (a lower
   truncated cost ``½ Σ min(s, c̄²)``), unless ``strict_known_inliers``. One wrong trusted edge
   would otherwise bend the answer while passing every other test; random wrong loop closures
   that happen to span the last stretch of a trajectory doubt a right one, and lose.
4. **Re-admission trials** (:func:`_readmit`): the rejected, untrusted measurements in order of
   ``s / c̄²`` at the answer, level ``2^k`` after level, are fitted again with the inliers and the
   TLS rounds rerun from there; a trial is kept when it lowers the TLS objective and the first that
   does not ends them. The TLS rounds judge a rejected edge at a solution fitted without it: right
   edges the start rejected together bend that solution away from all of them (the bundled
   example: 90 of 308 loop closures, ATE 0.74 m against 0.095 m), and only a joint fit brings them
   back. Wrong edges raise the objective at the trial's first LM step.

No outer iteration re-reads or re-analyses the graph, and each warm-starts from the last. The
symbolic analyses are shared by all solves (:class:`posegraph.robust.active.ActiveEdgeSolves`):
one made for an edge set serves every later set of edges with nonzero weight inside it, the
dropped edges at weight 0. By default (``reanalyse_fraction=0``) that is one analysis of the
chordal system (over every edge) and one of the Levenberg-Marquardt system (over the start's
inliers), a new one only if the TLS rounds readmit an edge outside it, and one per re-admission
trial (a graph whose rejected edges are all wrong: one). ``reanalyse_fraction=0.98``
analyses anew when fewer than 98 % of the analysed edges are still weighted: the outliers' fill
then costs more than an analysis, and the whole run took 0.3–0.7 × as long (``docs/robust.md``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.robust.active import DEFAULT_REANALYSE_FRACTION, ActiveEdgeSolves
from posegraph.robust.gnc import GncIteration, GncParams, GncResult, inlier_thresholds, run_gnc
from posegraph.robust.measurements import (
    Estimate, estimate_of, known_inlier_mask, measurement_dimensions, measurement_residuals, num_measurements, num_priors,
)
from posegraph.robust.starts import robust_chordal_start
from posegraph.robust.trust import (
    contradicted_odometry, best_edges_of_unkept_pairs, known_inliers_above, parallel_odometry_mask, truncated_cost,
)

__all__ = ["RobustResult", "LandmarkOutlier", "known_inlier_mask", "landmark_outliers", "optimize_robust", "tls_alternation", "doubt_thresholds"]

START_THRESHOLD_FACTOR = 2.0
"""The robust chordal start judges inliers against ``START_THRESHOLD_FACTOR · c̄²``: the chordal
relaxation's residuals are inflated where it bends the graph (at c̄² it rejected 61 inliers of
torus3D and 17 of smallGrid3D with 20 % outliers, which the TLS rounds then could not readmit:
without them their residuals stay at 2–2.5 c̄²), while random outliers' are 1e3 c̄² and more. Too
loose a start lets in outliers that bend the graph enough to pass the TLS rounds' test at c̄²
(parking-garage, whose information is ~1e4 times weaker than its residuals: 4 c̄² let 2 of
2,308 through at 50 %). Measured with 20 % outliers on smallGrid3D and torus3D and 50 % on
parking-garage, exact outlier sets at 2, not at 1 or 4 (``docs/robust.md``)."""

MAX_TLS_ROUNDS = 20
"""Cap on the rounds of :func:`tls_alternation` (each lowers the TLS cost, so it ends; seen: 1–3)."""


MAX_RELEASE_ROUNDS = 3
"""Most re-runs after releasing known inliers that failed the check (:mod:`posegraph.robust.trust`);
one suffices when a single wrong edge was trusted (a released edge is rejected, and the rest fit)."""

READMISSION_PROBE_ITERATIONS = 1
"""LM iterations over the inliers and the candidates, from the robust answer, after which a
re-admission trial (:func:`_readmission_trial`) goes on only if the TLS objective has dropped. One:
from a nearby answer one step lands in the least-squares basin of a consistent set (the bundled
example, every rejected edge readmitted: objective 1,347.7 → 935.0 after one, 932.7 at convergence),
while wrong edges raise the objective ninefold at once (every edge readmitted on sphere2500 + 20 %:
4,795 → 42,414; parking-garage + 10 %: 3,884 → 30,874), so a failed trial costs one iteration
(``docs/robust.md``, "Clean graphs")."""

MAX_READMISSION_TRIALS = 64
"""Cap on the re-admission trials (:func:`_readmit`; levels ``2^k c̄²``, so 64 covers any finite residual)."""


@dataclass
class RobustResult:
    """Outcome of :func:`optimize_robust`."""

    poses: np.ndarray
    """``(n, 4, 4)`` optimised poses."""
    weights: np.ndarray
    """``(m,)`` final weight of every edge (TLS: 0 or 1), in the graph's edge order."""
    result: object
    """:class:`~posegraph.solve.OptimizeResult` of the last least-squares solve (over the inliers:
    its ``final_cost`` is ``½ Σ w eᵀΩe``)."""
    start: GncResult
    """The GNC run that made the start and the first inlier guess (of the last run, if released)."""
    history: list = field(default_factory=list)
    """:class:`~posegraph.robust.gnc.GncIteration` per outer iteration, GNC's then the TLS rounds' (μ = ∞)."""
    seconds_start: float = 0.0
    """Seconds in step 1 (the start), summed over runs."""
    seconds_total: float = 0.0
    analyses: int = 0
    """Symbolic analyses made (chordal and solver; :class:`~posegraph.robust.active.ActiveEdgeSolves`)."""
    known: np.ndarray | None = None
    """``(m,)`` bool: the edges trusted (kept at weight 1) in the end."""
    released: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """``(k,)`` 0-based indices of known inliers released because their residual failed the inlier
    test at a result (:func:`~posegraph.robust.trust.known_inliers_above`); GNC then ran again."""
    suspicious: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """``(k,)`` indices of trusted edges kept though doubted: those a run without trusting them
    rejected (``strict_known_inliers``), and those still above the family-wise doubt threshold
    (:func:`doubt_thresholds`) at the result."""
    prior_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """``(u,)`` final weight of every prior (pose priors, then position priors): GNC judges them like
    the edges, never trusting them; a wrong GNSS fix ends at weight 0 like a wrong loop closure."""
    points: np.ndarray | None = None
    """``(L, s)`` optimised landmark positions, None for a pose graph."""
    landmark_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """``(q,)`` final weight of every landmark measurement (families in order, point priors included):
    GNC judges them like the loop closures, never trusting them; a wrong data association ends at 0."""
    landmark_outliers: list = field(default_factory=list)
    """:class:`LandmarkOutlier` per landmark measurement of final weight below 0.5, in family order."""
    readmitted: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """``(k,)`` 0-based indices of the edges the start and the TLS rounds had rejected and the
    re-admission trial (:func:`_readmission_trial`) readmitted: consistent with the least-squares
    solution of every edge, which fits the graph better by the TLS objective."""

    @property
    def outlier_edges(self) -> np.ndarray:
        """``(k,)`` 0-based indices, in edge order, of the edges with final weight below 0.5."""
        return np.flatnonzero(self.weights < 0.5)

    @property
    def final_cost(self) -> float:
        """``½ Σ w eᵀΩe`` at the result."""
        return self.result.final_cost

    def summary(self) -> str:
        """Two lines: what GNC did, and the outliers found."""
        landmarks = f", {len(self.landmark_outliers)} of {len(self.landmark_weights)} landmark measurements" if self.points is not None else ""
        return (
            f"GNC: {self.start.iterations} outer iterations ({self.start.reason}), then {len(self.history) - len(self.start.history)} "
            f"TLS rounds, {self.analyses} symbolic analyses; final cost {self.final_cost:.6g} ({self.seconds_total:.3f} s)\n"
            f"outliers: {len(self.outlier_edges)} of {len(self.weights)} edges{landmarks}"
        )


@dataclass(frozen=True)
class LandmarkOutlier:
    """A landmark measurement GNC rejected (final weight below 0.5)."""

    family: int
    """Index of its family in ``graph.landmarks.observations``."""
    index: int
    """Its row in that family."""
    kind: str
    """The family's kind (``"position"``, ``"bearing"``, ``"bearing_range"``, ``"prior"``)."""
    pose: int
    """Index of the observing pose (−1 for a point prior)."""
    landmark: int
    """Index of the landmark it was associated with."""
    line: int | None
    """Its 1-based line in the file, None when not read from one."""


def landmark_outliers(graph: PoseGraph, weights: np.ndarray) -> list:
    """:class:`LandmarkOutlier` per landmark measurement of ``weights`` ``(q,)`` below 0.5 (families in order)."""
    found, start = [], 0
    for number, family in enumerate(() if graph.landmarks is None else graph.landmarks.observations):
        for row in np.flatnonzero(np.asarray(weights[start : start + family.count]) < 0.5).tolist():
            line = None if family.lines is None else int(family.lines[row])
            found.append(LandmarkOutlier(number, row, family.kind, int(family.pose[row]), int(family.landmark[row]), line))
        start += family.count
    return found


@dataclass
class _Run:
    """One GNC run from a start to the end of the TLS rounds, with the edges it trusted."""

    start: GncResult
    weights: np.ndarray
    result: object
    known: np.ndarray
    seconds_start: float


def optimize_robust(
    graph: PoseGraph,
    initial=None,
    params=None,
    *,
    gnc: GncParams | None = None,
    known_inliers="odometry",
    progress=None,
    reanalyse_fraction: float = DEFAULT_REANALYSE_FRACTION,
    strict_known_inliers: bool = False,
) -> RobustResult:
    """Optimise ``graph`` robustly to wrong loop closures by GNC (module docstring).

    ``initial``: None for the robust chordal start, else poses ``(n, 4, 4)`` or ``"chordal"``,
    ``"odometry"``, ``"file"`` for GNC over LM from them. ``params``: the least-squares solves'
    :class:`~posegraph.solve.SolverParams` (``loss`` must be None; ``callback`` gets each LM
    iteration of every solve). ``gnc``: :class:`~posegraph.robust.gnc.GncParams` (surrogate
    ``"tls"`` or ``"gm"``, μ schedule, inlier threshold). ``known_inliers``: ``"odometry"``
    (default: one edge per pair of consecutive vertex ids, :meth:`PoseGraph.odometry_mask`; the
    pairs joined by parallel edges trusted only as :mod:`posegraph.robust.trust` says), ``"none"``
    or a ``(m,)`` bool mask; these keep weight 1. At the result, known inliers whose residual fails
    the inlier test are released and GNC runs again without them, unless ``strict_known_inliers``
    (then they are only reported, in ``suspicious``). ``progress`` gets a
    :class:`~posegraph.robust.gnc.GncIteration` per outer iteration. ``reanalyse_fraction``: when
    the solves analyse their edge set anew (:class:`~posegraph.robust.active.ActiveEdgeSolves`).
    """
    begin = time.perf_counter()
    gnc = GncParams() if gnc is None else gnc
    m = graph.num_edges
    known = _with_priors(graph, known_inlier_mask(graph, known_inliers))  # priors are never trusted: GNC weighs them
    by_odometry = known_inliers is None or (isinstance(known_inliers, str) and known_inliers == "odometry")
    parallel = _with_priors(graph, parallel_odometry_mask(graph) if by_odometry else np.zeros(m, dtype=bool))
    solves = ActiveEdgeSolves(graph, params, reanalyse_fraction=reanalyse_fraction)
    thresholds = inlier_thresholds(measurement_dimensions(graph), len(known), gnc)
    history: list = []
    run = _gnc_run(graph, initial, known & ~parallel, gnc, solves, thresholds, history, progress)
    run = _trust_unkept_pairs(graph, run, parallel, solves, thresholds, history, progress)
    runs = [run]

    def rerun(known):
        runs.append(_gnc_run(graph, initial, known, gnc, solves, thresholds, history, progress))
        return runs[-1]

    doubt = doubt_thresholds(graph, run.known, gnc)
    run, released, suspicious = _release_doubtful(graph, run, rerun, thresholds, doubt, strict_known_inliers)
    rejected = run.weights < 0.5
    if gnc.loss == "tls":
        run = _readmit(graph, run, solves, thresholds, history, progress)
    mu = m + num_priors(graph)
    return RobustResult(
        run.result.poses, run.weights[:m], run.result, run.start, history, sum(r.seconds_start for r in runs),
        time.perf_counter() - begin, solves.analyses, run.known[:m], np.flatnonzero(released[:m]),
        np.flatnonzero(suspicious[:m]), run.weights[m:mu], run.result.points, run.weights[mu:],
        landmark_outliers(graph, run.weights[mu:]), np.flatnonzero((rejected & (run.weights >= 0.5))[:m]),
    )  # fmt: skip


def _trust_unkept_pairs(graph, run: _Run, parallel: np.ndarray, solves, thresholds, history: list, progress) -> _Run:
    """``run``, or where GNC kept no edge of an ambiguous pair (``parallel`` ``(m + u + q,)`` bool,
    :func:`~posegraph.robust.trust.parallel_odometry_mask`), TLS rounds from it trusting the edge of
    each such pair that fits best (:func:`~posegraph.robust.trust.best_edges_of_unkept_pairs`)."""
    m = graph.num_edges
    s = measurement_residuals(graph, estimate_of(graph, run.result))[:m]
    fallback = _with_priors(graph, best_edges_of_unkept_pairs(graph, parallel[:m], run.weights[:m] >= 0.5, s))
    return _trust_more(graph, run, fallback, solves, thresholds, history, progress) if fallback.any() else run


def doubt_thresholds(graph: PoseGraph, known: np.ndarray, gnc: GncParams) -> np.ndarray:
    """``(m + u + q,)`` thresholds on ``s`` above which a trusted measurement (``known`` ``(m + u + q,)``
    bool) is doubted by its residual: the χ² quantile at ``1 − (1 − p)/N`` for its dimension, ``p``
    GNC's inlier probability and ``N`` the number of trusted measurements (Bonferroni). On a graph whose
    trusted edges are all right, the chance that any of them is doubted is then at most ``1 − p``
    (1 %), where the per-edge test at ``c̄²`` doubts ~1 % of them (torus, 2,496 poses: 4 right odometry
    edges released and rejected). An explicit ``gnc.inlier_threshold`` is used as it is."""
    count = max(int(np.count_nonzero(known)), 1)
    family = replace(gnc, inlier_probability=1.0 - (1.0 - gnc.inlier_probability) / count)
    return inlier_thresholds(measurement_dimensions(graph), len(known), family)


def _readmit(graph, run: _Run, solves, thresholds, history: list, progress) -> _Run:
    """``run`` after re-admission trials (:func:`_readmission_trial`) of its rejected, untrusted
    measurements in order of their ``s / c̄²`` at its result: those at most ``2^k`` for ``k = 1, 2, …``
    (levels no rejected measurement falls in are skipped), each trial from the answer of the last
    accepted one, until one fails or none is left.

    Why: the TLS rounds judge each rejected edge at a solution fitted without it and without every
    other rejected edge. Right edges rejected together (the chordal start misjudged a region) bend
    the solution away from all of them, and no round readmits any: on the bundled example 90 right
    loop closures stay rejected at s = 1.1–30 c̄², all below c̄² at the least-squares solution. Fitted
    together they agree with the rest, and the TLS objective says so. The levels readmit the
    edges nearest to consistent first, so that wrong edges (s ~ 1e5 c̄² and more) come last and end
    the trials; the first trial on a graph whose rejected edges are all wrong is its last."""
    level = 0
    for _ in range(MAX_READMISSION_TRIALS):
        rejected = (run.weights < 0.5) & ~run.known
        if not rejected.any():
            break
        ratio = measurement_residuals(graph, estimate_of(graph, run.result)) / thresholds
        level = max(level + 1, int(np.ceil(np.log2(max(float(np.min(ratio[rejected])), 2.0)))))
        trial = _readmission_trial(graph, run, rejected & (ratio <= 2.0**level), solves, thresholds, history, progress)
        if trial is None:
            break
        run = trial
    return run


def _readmission_trial(graph, run: _Run, candidates: np.ndarray, solves, thresholds, history: list, progress) -> _Run | None:
    """The answer with ``candidates`` ``(m + u + q,)`` bool readmitted, or None when it does not lower
    the TLS objective (:func:`_tls_objective`): :data:`READMISSION_PROBE_ITERATIONS` LM iterations
    over ``run``'s inliers and the candidates from ``run``'s result — the trial ends there unless the
    objective has dropped —, then TLS rounds (:func:`tls_alternation`) from that point, every
    measurement judged again; each round lowers the objective further."""
    objective = _tls_objective(graph, run.known, thresholds)
    state = estimate_of(graph, run.result)
    weights = ((run.weights >= 0.5) | candidates).astype(np.float64)
    probe = estimate_of(graph, solves.least_squares(state, weights, max_iterations=READMISSION_PROBE_ITERATIONS))
    if not objective(probe) < objective(state):
        return None
    judged = _inlier_test(graph, run.known, thresholds)
    weights, result = tls_alternation(solves, probe, judged(probe), judged, history, progress)
    if not objective(estimate_of(graph, result)) < objective(state):  # not reached: each round lowers it
        return None
    return _Run(run.start, weights, result, run.known, run.seconds_start)


def _tls_objective(graph, known: np.ndarray, thresholds):
    """``state -> ½ Σ_known s + ½ Σ_other min(s, c̄²)``: the objective the TLS rounds lower, with the
    trusted measurements ``known`` ``(m + u + q,)`` bool counted in full."""

    def objective(state) -> float:
        s = measurement_residuals(graph, state)
        return 0.5 * float(np.sum(np.where(known, s, np.minimum(s, thresholds))))

    return objective


def _with_priors(graph, mask: np.ndarray) -> np.ndarray:
    """``(m,)`` bool over the edges extended with False for the graph's priors and landmark
    measurements: ``(m + u + q,)``."""
    return np.r_[mask, np.zeros(num_measurements(graph) - graph.num_edges, dtype=bool)]


def _release_doubtful(graph, run: _Run, rerun, thresholds, doubt, strict: bool):
    """Check ``run``'s trusted edges (:func:`_doubtful`, against ``doubt``: :func:`doubt_thresholds`); release the doubtful ones when a run without
    trusting them (``rerun(known) -> _Run``) fits the graph better: a lower truncated cost
    (:func:`~posegraph.robust.trust.truncated_cost`, every edge judged alike) by more than half the
    least threshold, at most :data:`MAX_RELEASE_ROUNDS` times. ``strict``: never release; the edges
    the better run rejected are named instead. Returns ``(run, released (m,) bool, suspicious (m,)
    bool)``; suspicious also holds the trusted edges still above ``doubt`` at the end. The final check
    is family-wise, as the doubt is: at the per-edge ``c̄²`` about 1 % of right odometry edges would be
    named (4 of 2,496 on a clean torus), a warning every large clean graph would give."""
    released = np.zeros(len(run.known), dtype=bool)
    suspicious = np.zeros(len(run.known), dtype=bool)
    for _ in range(MAX_RELEASE_ROUNDS):
        doubtful = _doubtful(graph, run, doubt)
        if not doubtful.any():
            break
        trial = rerun(run.known & ~doubtful)
        fits = truncated_cost(measurement_residuals(graph, estimate_of(graph, trial.result)), thresholds)
        if fits >= truncated_cost(measurement_residuals(graph, estimate_of(graph, run.result)), thresholds) - 0.5 * float(np.min(thresholds)):
            break  # trusting them fits the graph as well: the edges spanning them were wrong, not they
        if strict:
            suspicious |= doubtful & (trial.weights < 0.5)
            break
        released |= doubtful
        run = trial
    suspicious |= known_inliers_above(measurement_residuals(graph, estimate_of(graph, run.result)), run.known, doubt)
    return run, released, suspicious


def _gnc_run(graph, initial, known, gnc: GncParams, solves, thresholds, history: list, progress) -> _Run:
    """The start (step 1), then the TLS rounds at μ → ∞ (step 2), trusting ``known`` ``(m,)`` bool."""
    begin = time.perf_counter()
    if initial is None:
        loose = replace(gnc, inlier_threshold=START_THRESHOLD_FACTOR * inlier_thresholds(graph.group.dim, 1, gnc)[0])
        if graph.landmarks is None:
            start = robust_chordal_start(graph, known, loose, solves=solves, progress=progress)
        else:
            start = _landmark_start(graph, known, gnc, loose, solves, progress)
    else:
        start = _gnc_over_least_squares(graph, initial, known, gnc, solves, progress)
    seconds_start = time.perf_counter() - begin
    history.extend(start.history)
    if gnc.loss == "tls":
        judged = _inlier_test(graph, known, thresholds)
        weights, result = tls_alternation(solves, start.poses, start.inliers | known, judged, history, progress)
    else:  # Geman-McClure: its weights are not binary; one solve with them
        weights = np.where(known, 1.0, start.weights)
        result = solves.least_squares(start.poses, weights)
    return _Run(start, weights, result, known, seconds_start)


def _doubtful(graph, run: _Run, thresholds) -> np.ndarray:
    """``(m,)`` bool: ``run``'s trusted edges whose ``s`` exceeds ``thresholds`` (the doubt thresholds)
    at its result, or that every edge spanning them contradicts (:mod:`posegraph.robust.trust`)."""
    above = known_inliers_above(measurement_residuals(graph, estimate_of(graph, run.result)), run.known, thresholds)
    m = graph.num_edges
    return above | _with_priors(graph, contradicted_odometry(graph, run.known[:m], run.weights[:m] >= 0.5))


def _trust_more(graph, run: _Run, more: np.ndarray, solves, thresholds, history: list, progress) -> _Run:
    """TLS rounds from ``run``'s result, trusting ``more`` ``(m,)`` bool edges besides its known ones."""
    known = run.known | more
    inliers = (run.weights >= 0.5) | known
    weights, result = tls_alternation(solves, estimate_of(graph, run.result), inliers, _inlier_test(graph, known, thresholds),
                                      history, progress)  # fmt: skip
    return _Run(run.start, weights, result, known, run.seconds_start)


def _inlier_test(graph, known: np.ndarray, thresholds):
    """``poses -> (m,) bool``: an edge is an inlier when trusted or ``s = eᵀΩe ≤ c̄²`` at ``poses``."""

    def judged(poses):
        return known | (measurement_residuals(graph, poses) <= thresholds)

    return judged


def tls_alternation(solves: ActiveEdgeSolves, poses, inliers, judged, history: list, progress=None):
    """Alternate LM over ``inliers`` ``(m,)`` bool and ``inliers = judged(poses)`` until the set
    repeats (at most :data:`MAX_TLS_ROUNDS`). Appends a :class:`GncIteration` (μ = ∞) per round to
    ``history``. Returns ``(weights (m,) of 0/1, the last OptimizeResult)``."""
    for _ in range(MAX_TLS_ROUNDS):
        weights = inliers.astype(np.float64)
        result = solves.least_squares(poses, weights)
        poses = estimate_of(solves.graph, result)
        record = GncIteration(len(history), float("inf"), int(np.count_nonzero(inliers)), result.final_cost)
        history.append(record)
        if progress is not None:
            progress(record)
        judged_now = judged(poses)
        if np.array_equal(judged_now, inliers):
            break
        inliers = judged_now
    return weights, result


def _gnc_over_least_squares(graph, initial, known, gnc: GncParams, solves: ActiveEdgeSolves, progress) -> GncResult:
    """GNC whose weighted solve is LM from the last solution (gtsam's ``GncLMOptimizer``, warm-started).
    A landmark graph starts from the landmark positions :func:`~posegraph.solve.optimize` would (the
    file's with ``initial="file"``, else each landmark from its measurements given the poses)."""
    from posegraph.solve.optimizer import _initial_points, _initial_poses

    poses = _initial_poses(graph, initial)
    start = poses if graph.landmarks is None else Estimate(poses, _initial_points(graph, initial, poses, None))
    return _run_gnc_least_squares(graph, start, known, gnc, solves, progress)


def _run_gnc_least_squares(graph, start, known, gnc: GncParams, solves, progress, initial_weights=None) -> GncResult:
    """:func:`run_gnc` over LM solves of ``graph`` from the state ``start`` (poses or an Estimate)."""
    return run_gnc(
        lambda state: measurement_residuals(graph, state),
        lambda state, w: estimate_of(graph, solves.least_squares(state, w)),
        start,
        known,
        gnc,
        dimension=measurement_dimensions(graph),
        initial_weights=initial_weights,
        progress=progress,
    )


def _landmark_start(graph, known, gnc: GncParams, loose: GncParams, solves: ActiveEdgeSolves, progress) -> GncResult:
    """The start of a landmark graph: the robust chordal start of its pose part (edges and priors,
    :meth:`ActiveEdgeSolves.pose_part`), each landmark placed from its measurements given those poses
    (:func:`posegraph.init.landmarks.initialize_landmarks`: least squares, wrong associations included),
    then GNC over LM on the whole graph from there, the edges and priors first weighted as the chordal
    GNC left them and every landmark measurement at 1. Its ``history`` and ``iterations`` hold both GNC runs'."""
    from posegraph.init.landmarks import initialize_landmarks

    mu = graph.num_edges + num_priors(graph)
    poses = robust_chordal_start(solves.pose_part().graph, known[:mu], loose, solves=solves.pose_part(), progress=progress)
    points, _ = initialize_landmarks(graph, poses.poses)
    weights = np.r_[poses.weights, np.ones(len(known) - mu)]
    result = _run_gnc_least_squares(graph, Estimate(poses.poses, points), known, gnc, solves, progress, weights)
    return replace(result, iterations=poses.iterations + result.iterations, history=poses.history + result.history)
