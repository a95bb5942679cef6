"""Robust estimation: M-estimator losses and graduated non-convexity (GNC).

* :mod:`posegraph.robust.losses` — Huber, Cauchy, Geman-McClure, Tukey, DCS and truncated least
  squares as functions ρ(s) of the squared whitened residual ``s = eᵀΩe`` (cost ``½ Σ ρ(s)``),
  with their IRLS weights ρ'(s) and second derivatives ρ''(s).
* :mod:`posegraph.robust.gnc` — the GNC outer loop (Yang, Antonante, Tzoumas & Carlone, RA-L 2020)
  over any weighted least-squares solver, as gtsam's ``GncOptimizer``.
* :mod:`posegraph.robust.measurements` — what GNC weighs: the edges, then the priors; their squared
  residuals, dimensions, known inliers, and the graph weighted.
* :mod:`posegraph.robust.trust` — which trusted odometry edges the rest of the graph contradicts.
* :mod:`posegraph.robust.starts` — starts that outliers do not corrupt (robust chordal).
* :mod:`posegraph.robust.active` — weighted solves that keep one symbolic analysis while edges
  drop out (weight 0).
* :mod:`posegraph.robust.pipeline` — :func:`optimize_robust`: robust chordal start, then truncated
  least squares over Levenberg-Marquardt.

Order of imports, bottom up: losses, gnc, trust, measurements → active → starts → pipeline
(no module imports one after it). None imports scipy at import time (the χ² quantile is computed on first use).
"""

from posegraph.robust.losses import LOSS_NAMES, RobustLoss, make_loss

__all__ = ["LOSS_NAMES", "RobustLoss", "make_loss"]


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
