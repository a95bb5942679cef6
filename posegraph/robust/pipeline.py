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

No outer iteration re-reads or re-analyses the graph, and each warm-starts from the last. The
symbolic analyses are shared by all solves (:class:`posegraph.robust.active.ActiveEdgeSolves`):
one made for an edge set serves every later set of edges with nonzero weight inside it, the
dropped edges at weight 0. By default (``reanalyse_fraction=0``) that is one analysis of the
chordal system (over every edge) and one of the Levenberg-Marquardt system (over the start's
inliers), a new one only if the TLS rounds readmit an edge outside it. ``reanalyse_fraction=0.98``
analyses anew when fewer than 98 % of the analysed edges are still weighted: the outliers' fill
then costs more than an analysis, and the whole run took 0.3–0.7 × as long (``docs/robust.md``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from posegraph.graph import PoseGraph
from posegraph.robust.active import DEFAULT_REANALYSE_FRACTION, ActiveEdgeSolves
from posegraph.robust.gnc import GncIteration, GncParams, GncResult, inlier_thresholds, run_gnc
from posegraph.robust.starts import known_inlier_mask, robust_chordal_start, squared_residuals

__all__ = ["RobustResult", "known_inlier_mask", "optimize_robust", "tls_alternation"]

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
    """The GNC run that made the start and the first inlier guess."""
    history: list = field(default_factory=list)
    """:class:`~posegraph.robust.gnc.GncIteration` per outer iteration, GNC's then the TLS rounds' (μ = ∞)."""
    seconds_start: float = 0.0
    """Seconds in step 1 (the start)."""
    seconds_total: float = 0.0
    analyses: int = 0
    """Symbolic analyses made (chordal and solver; :class:`~posegraph.robust.active.ActiveEdgeSolves`)."""

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
        return (
            f"GNC: {self.start.iterations} outer iterations ({self.start.reason}), then {len(self.history) - len(self.start.history)} "
            f"TLS rounds, {self.analyses} symbolic analyses; final cost {self.final_cost:.6g} ({self.seconds_total:.3f} s)\n"
            f"outliers: {len(self.outlier_edges)} of {len(self.weights)} edges"
        )


def optimize_robust(
    graph: PoseGraph,
    initial=None,
    params=None,
    *,
    gnc: GncParams | None = None,
    known_inliers="odometry",
    progress=None,
    reanalyse_fraction: float = DEFAULT_REANALYSE_FRACTION,
) -> RobustResult:
    """Optimise ``graph`` robustly to wrong loop closures by GNC (module docstring).

    ``initial``: None for the robust chordal start, else poses ``(n, 4, 4)`` or ``"chordal"``,
    ``"odometry"``, ``"file"`` for GNC over LM from them. ``params``: the least-squares solves'
    :class:`~posegraph.solve.SolverParams` (``loss`` must be None; ``callback`` gets each LM
    iteration of every solve). ``gnc``: :class:`~posegraph.robust.gnc.GncParams` (surrogate
    ``"tls"`` or ``"gm"``, μ schedule, inlier threshold). ``known_inliers``: ``"odometry"``
    (default: edges between consecutive vertex ids), ``"none"`` or a ``(m,)`` bool mask; these
    keep weight 1. ``progress`` gets a :class:`~posegraph.robust.gnc.GncIteration` per outer
    iteration. ``reanalyse_fraction``: when the solves analyse their edge set anew
    (:class:`~posegraph.robust.active.ActiveEdgeSolves`).
    """
    begin = time.perf_counter()
    gnc = GncParams() if gnc is None else gnc
    known = known_inlier_mask(graph, known_inliers)
    solves = ActiveEdgeSolves(graph, params, reanalyse_fraction=reanalyse_fraction)
    if initial is None:
        loose = replace(gnc, inlier_threshold=START_THRESHOLD_FACTOR * inlier_thresholds(graph.group.dim, 1, gnc)[0])
        start = robust_chordal_start(graph, known, loose, solves=solves, progress=progress)
    else:
        start = _gnc_over_least_squares(graph, initial, known, gnc, solves, progress)
    seconds_start = time.perf_counter() - begin
    thresholds = inlier_thresholds(graph.group.dim, graph.num_edges, gnc)
    history = list(start.history)

    def judged(poses):
        return known | (squared_residuals(graph, poses) <= thresholds)

    if gnc.loss == "tls":
        weights, result = tls_alternation(solves, start.poses, start.inliers | known, judged, history, progress)
    else:  # Geman-McClure: its weights are not binary; one solve with them
        weights = np.where(known, 1.0, start.weights)
        result = solves.least_squares(start.poses, weights)
    seconds_total = time.perf_counter() - begin
    return RobustResult(result.poses, weights, result, start, history, seconds_start, seconds_total, solves.analyses)


def tls_alternation(solves: ActiveEdgeSolves, poses, inliers, judged, history: list, progress=None):
    """Alternate LM over ``inliers`` ``(m,)`` bool and ``inliers = judged(poses)`` until the set
    repeats (at most :data:`MAX_TLS_ROUNDS`). Appends a :class:`GncIteration` (μ = ∞) per round to
    ``history``. Returns ``(weights (m,) of 0/1, the last OptimizeResult)``."""
    for _ in range(MAX_TLS_ROUNDS):
        weights = inliers.astype(np.float64)
        result = solves.least_squares(poses, weights)
        poses = result.poses
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
    """GNC whose weighted solve is LM from the last solution (gtsam's ``GncLMOptimizer``, warm-started)."""
    from posegraph.solve.optimizer import _initial_poses

    return run_gnc(
        lambda poses: squared_residuals(graph, poses),
        lambda start, w: solves.least_squares(start, w).poses,
        _initial_poses(graph, initial),
        known,
        gnc,
        dimension=graph.group.dim,
        progress=progress,
    )
