"""Graduated non-convexity (GNC) over any weighted least-squares solver.

Yang, Antonante, Tzoumas & Carlone, "Graduated Non-Convexity for Robust Spatial Perception: From
Non-Minimal Solvers to Global Outlier Rejection", RA-L 2020 (arXiv:1909.08605), as gtsam's
``GncOptimizer`` implements it. Units: ``s_k = e_kᵀΩ_k e_k`` is edge ``k``'s squared whitened
residual and ``c̄²_k`` its inlier threshold on ``s`` (default the χ² quantile at probability 0.99
for the edge's dimension: 16.81 for SE(3)). gtsam works with the factor error ``s/2`` and
``barcSq = c̄²/2``; every formula below is homogeneous of degree 0 in ``(s, c̄²)``, so the two agree.

The algorithm (:func:`run_gnc`)::

    w = 1;  x = solve(x₀, w)                        least squares with every edge (or given w)
    μ = initial_mu(s(x₀))                           Remark 5 (gtsam evaluates it at x₀)
    repeat:
        w = weights(s(x), μ), known inliers 1       eq. (14) TLS / eq. (12) Geman-McClure
        x = solve(x or x₀, w)                       warm start, or gtsam's restart from x₀
        stop if w is binary and as at the last iteration (TLS), the weighted cost ½ Σ w s
        stalled, or μ reached 1 (GM)
        μ = update_mu(μ)                            TLS: μ·step (→ ∞);  GM: max(1, μ/step)

Surrogates (paper eqs. 12 and 14) with ``c̄²`` the threshold:

* TLS: ``w = 1`` if ``s ≤ μ/(μ+1) c̄²``; ``0`` if ``s ≥ (μ+1)/μ c̄²``; else
  ``√(c̄² μ(μ+1)/s) − μ``. Small μ is convex (ℓ1-like, ``w ≈ √(c̄² μ / s)``); μ → ∞ is TLS.
  ``μ₀ = min_k c̄²/(2 s_k − c̄²)`` over edges with ``2 s_k > c̄²`` (at least 1e-6); none means every
  residual is small and GNC stops at once.
* Geman-McClure: ``w = (μ c̄² / (μ c̄² + s))²``; large μ is nearly convex, μ = 1 is GM with scale
  ``c̄``. ``μ₀ = max_k 2 s_k / c̄²``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from posegraph.robust.losses import chi2_quantile

__all__ = [
    "GNC_LOSSES",
    "GncParams",
    "GncIteration",
    "GncResult",
    "inlier_thresholds",
    "initial_mu",
    "update_mu",
    "gnc_weights",
    "weights_are_binary",
    "run_gnc",
]

GNC_LOSSES = ("tls", "gm")
"""Surrogates :func:`run_gnc` accepts: truncated least squares and Geman-McClure."""

MIN_INITIAL_MU = 1e-6
"""Lower bound of TLS' initial μ (gtsam's): a huge residual would otherwise give μ₀ ≈ 0, a
surrogate so flat that the first weights are all ≈ 1 and the schedule needs ~40 more steps."""


@dataclass(frozen=True)
class GncParams:
    """Parameters of :func:`run_gnc`; the defaults are gtsam's ``GncParams``."""

    loss: str = "tls"
    """Surrogate: ``"tls"`` (truncated least squares) or ``"gm"`` (Geman-McClure)."""
    mu_step: float = 1.4
    """Factor by which μ grows (TLS) or shrinks (GM) per outer iteration (> 1)."""
    max_iterations: int = 100
    """Most outer iterations (weight updates followed by a weighted solve)."""
    relative_cost_tolerance: float = 1e-5
    """Stop when ``|cost − previous| / max(previous, 1e-7)`` of ``½ Σ w s`` falls below this."""
    weights_tolerance: float = 1e-4
    """TLS stops when every weight is within this of 0 or 1."""
    inlier_probability: float = 0.99
    """The inlier threshold ``c̄²`` is the χ² quantile at this probability for the edge's dimension."""
    inlier_threshold: float | None = None
    """``c̄²`` in units of ``s = eᵀΩe``, overriding ``inlier_probability`` when set."""
    warm_start: bool = True
    """Start each weighted solve from the last solution; False restarts from ``x₀`` as gtsam does."""

    def __post_init__(self) -> None:
        if self.loss not in GNC_LOSSES:
            raise ValueError(f"GNC loss must be one of {', '.join(GNC_LOSSES)}, got {self.loss!r}")
        if not self.mu_step > 1.0:
            raise ValueError(f"mu_step must be > 1, got {self.mu_step!r}")
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 1:
            raise ValueError(f"max_iterations must be an integer >= 1, got {self.max_iterations!r}")
        if not 0.0 < self.inlier_probability < 1.0:
            raise ValueError(f"inlier_probability must be in (0, 1), got {self.inlier_probability!r}")
        if self.inlier_threshold is not None and not self.inlier_threshold > 0:
            raise ValueError(f"inlier_threshold must be > 0, got {self.inlier_threshold!r}")


@dataclass(frozen=True)
class GncIteration:
    """One outer iteration, as passed to the progress callback."""

    iteration: int
    """0-based outer iteration."""
    mu: float
    """μ the weights were computed with."""
    inliers: int
    """Edges with weight > 0.5."""
    cost: float
    """``½ Σ w s`` after the weighted solve."""


@dataclass
class GncResult:
    """Outcome of :func:`run_gnc`."""

    poses: object
    """The last weighted solve's solution (whatever ``solve_weighted`` returns)."""
    weights: np.ndarray
    """``(m,)`` final weights in [0, 1] (TLS: binary when ``reason == "weights"``)."""
    iterations: int
    """Outer iterations run (0 when GNC had nothing to do)."""
    mu: float
    """The last μ."""
    reason: str
    """Why it stopped: ``"weights"``, ``"cost"``, ``"mu"``, ``"max_iterations"``, ``"no_large_residual"``
    (TLS: every residual below the threshold at the start) or ``"all_known"`` (every edge a known inlier)."""
    history: list = field(default_factory=list)
    """:class:`GncIteration` per outer iteration."""

    @property
    def inliers(self) -> np.ndarray:
        """``(m,)`` bool, weight > 0.5."""
        return self.weights > 0.5


def inlier_thresholds(dimension, count: int, params: GncParams) -> np.ndarray:
    """``(count,)`` thresholds ``c̄²`` on ``s``: ``params.inlier_threshold`` or the χ² quantile at
    ``params.inlier_probability`` for ``dimension`` (an int or ``(count,)`` ints)."""
    if params.inlier_threshold is not None:
        return np.full(count, float(params.inlier_threshold))
    dims = np.broadcast_to(np.asarray(dimension, dtype=np.int64), (count,))
    table = {int(d): chi2_quantile(params.inlier_probability, int(d)) for d in np.unique(dims)}
    return np.array([table[int(d)] for d in dims]) if count else np.zeros(0)


def initial_mu(s: np.ndarray, thresholds: np.ndarray, loss: str) -> float:
    """μ₀ of Remark 5 from squared residuals ``s`` ``(m,)``; ≤ 0 when TLS has nothing to reject."""
    if loss == "gm":
        return float(np.max(2.0 * s / thresholds, initial=0.0))
    excess = 2.0 * s - thresholds
    large = excess > 0
    if not np.any(large):
        return -1.0
    return max(float(np.min(thresholds[large] / excess[large])), MIN_INITIAL_MU)


def update_mu(mu: float, params: GncParams) -> float:
    """TLS: ``μ · step`` (towards TLS as μ → ∞); GM: ``max(1, μ / step)`` (GM itself at μ = 1)."""
    return mu * params.mu_step if params.loss == "tls" else max(1.0, mu / params.mu_step)


def gnc_weights(s: np.ndarray, thresholds: np.ndarray, mu: float, loss: str) -> np.ndarray:
    """Weights ``(m,)`` minimising the surrogate for fixed residuals (paper eqs. 12 and 14)."""
    s = np.asarray(s, dtype=np.float64)
    if loss == "gm":
        scaled = mu * thresholds
        return (scaled / (scaled + s)) ** 2
    lower = mu / (mu + 1.0) * thresholds
    upper = (mu + 1.0) / mu * thresholds
    safe = np.where(s > 0, s, 1.0)  # s ≤ lower there: the branch below is not taken
    between = np.clip(np.sqrt(thresholds * mu * (mu + 1.0) / safe) - mu, 0.0, 1.0)
    return np.where(s >= upper, 0.0, np.where(s <= lower, 1.0, between))


def weights_are_binary(weights: np.ndarray, tolerance: float) -> bool:
    """Every weight within ``tolerance`` of 0 or 1."""
    return bool(np.all(np.abs(weights - np.round(weights)) <= tolerance))


def _stopped(params: GncParams, mu: float, weights: np.ndarray, last: np.ndarray, cost: float, previous: float) -> str | None:
    if abs(cost - previous) / max(previous, 1e-7) < params.relative_cost_tolerance:
        return "cost"
    # gtsam stops as soon as the weights are binary. With residuals of 1e8 at the first solve
    # (random outliers across the map) and μ₀ = 1e-6 every first weight is below 1e-4, inliers'
    # too: "binary" all zero. So binary weights stop the loop only when they also rounded the
    # same way at the previous iteration.
    if (
        params.loss == "tls"
        and weights_are_binary(weights, params.weights_tolerance)
        and np.array_equal(np.round(weights), np.round(last))
    ):
        return "weights"
    if params.loss == "gm" and abs(mu - 1.0) < 1e-9:
        return "mu"
    return None


def run_gnc(
    squared_residuals: Callable[[object], np.ndarray],
    solve_weighted: Callable[[object, np.ndarray], object],
    poses0,
    known_inliers: np.ndarray | None = None,
    params: GncParams | None = None,
    *,
    dimension=6,
    initial_weights: np.ndarray | None = None,
    progress: Callable[[GncIteration], None] | None = None,
    start_solved: bool = False,
) -> GncResult:
    """Graduated non-convexity (module docstring) over a weighted least-squares solver.

    ``squared_residuals(poses) -> s (m,)`` gives ``eᵀΩe`` per edge; ``solve_weighted(start,
    weights) -> poses`` minimises ``½ Σ w_k s_k`` from ``start`` (the solver's own business: it may
    keep its symbolic analysis between calls). ``known_inliers`` ``(m,)`` bool edges stay at
    weight 1 (e.g. odometry). ``dimension`` (int or ``(m,)``) sets the χ² thresholds.
    ``initial_weights`` ``(m,)`` weigh the first solve instead of all ones (gtsam's
    ``setWeights``), e.g. the weights of a robust start. ``progress`` is called after each outer
    iteration with a :class:`GncIteration`. ``start_solved``: ``poses0`` already minimises the
    first weighted problem (e.g. the chordal start of the graph with every edge), so that solve
    is skipped.
    """
    params = GncParams() if params is None else params
    s0 = np.asarray(squared_residuals(poses0), dtype=np.float64)
    m = len(s0)
    known = np.zeros(m, bool) if known_inliers is None else np.asarray(known_inliers, dtype=bool)
    if known.shape != (m,):
        raise ValueError(f"known_inliers must be a ({m},) bool mask, got shape {known.shape}")
    thresholds = inlier_thresholds(dimension, m, params)

    weights = np.ones(m) if initial_weights is None else np.where(known, 1.0, np.asarray(initial_weights, dtype=np.float64))
    if weights.shape != (m,):
        raise ValueError(f"initial_weights must have shape ({m},), got {weights.shape}")
    poses = poses0 if start_solved else solve_weighted(poses0, weights)
    mu = initial_mu(s0, thresholds, params.loss)
    previous = 0.5 * float(np.dot(weights, squared_residuals(poses)))
    if np.all(known):
        return GncResult(poses, weights, 0, mu, "all_known")
    if mu <= 0:
        return GncResult(poses, weights, 0, mu, "no_large_residual")

    history, reason = [], "max_iterations"
    for iteration in range(params.max_iterations):
        last = weights if iteration else np.full(m, 0.5)  # nothing to agree with at the first
        weights = np.where(known, 1.0, gnc_weights(squared_residuals(poses), thresholds, mu, params.loss))
        poses = solve_weighted(poses if params.warm_start else poses0, weights)
        cost = 0.5 * float(np.dot(weights, squared_residuals(poses)))
        record = GncIteration(iteration, mu, int(np.count_nonzero(weights > 0.5)), cost)
        history.append(record)
        if progress is not None:
            progress(record)
        stop = _stopped(params, mu, weights, last, cost, previous)
        if stop is not None:
            reason = stop
            break
        mu = update_mu(mu, params)
        previous = cost
    return GncResult(poses, weights, len(history), mu, reason, history)
