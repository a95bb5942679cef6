"""``optimize``'s robust options: ``--robust``, ``--robust-scale``, ``--known-inliers``, ``--drop-outliers``,
``--reanalyse-fraction``.

``--robust NAME`` with an M-estimator (``huber``, ``cauchy``, ``geman-mcclure``, ``tukey``,
``dcs``, ``tls``) gives the solver that loss (:func:`posegraph.robust.make_loss`, scale
``--robust-scale`` or the loss's default); ``--robust gnc`` runs
:func:`posegraph.robust.optimize_robust` (GNC-TLS from the robust chordal start with
``--init chordal``, the default; from the ``--init odometry`` / ``file`` poses otherwise).
An edge whose final weight is below 0.5 is judged an outlier.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from posegraph.cli.common import positive_float, unit_fraction


ROBUST_CHOICES = ("none", "huber", "cauchy", "geman-mcclure", "tukey", "dcs", "tls", "gnc")
"""``--robust`` values: no loss, the six M-estimators, or graduated non-convexity."""

OUTLIER_WEIGHT = 0.5
"""An edge whose final weight (ρ'(s), or GNC's weight) is below this is reported as an outlier."""


def robust_options(p: argparse.ArgumentParser) -> None:
    """Add the five robust options to ``p``."""
    p.add_argument("--robust", choices=ROBUST_CHOICES, default="none", metavar="{" + ",".join(ROBUST_CHOICES) + "}",
                   help="robust loss on every edge, or gnc: graduated non-convexity with truncated least squares "
                        "from a start that wrong loop closures do not corrupt (default none: least squares)")
    p.add_argument("--robust-scale", type=positive_float, default=None, metavar="C",
                   help="the loss's scale in units of the whitened residual norm (default: the loss's own; "
                        "gnc: the inlier threshold, default sqrt of the chi2 0.99 quantile, 4.10 in 3D)")
    p.add_argument("--known-inliers", choices=("odometry", "none"), default="odometry",
                   help="gnc: edges trusted, never rejected (default odometry: one edge per pair of consecutive "
                        "vertex ids; where parallel edges join a pair, the one the other edges agree with); a trusted "
                        "edge that fails the inlier test at the result is released and GNC runs again, with a warning")
    p.add_argument("--strict-known-inliers", action="store_true",
                   help="gnc: never release a known inlier; only warn about those that fail the inlier test")
    p.add_argument("--drop-outliers", action="store_true",
                   help="write OUT without the edges judged outliers (final weight below 0.5)")
    p.add_argument("--reanalyse-fraction", type=unit_fraction, default=None, metavar="F",
                   help="gnc: analyse the sparsity anew when the edges of nonzero weight fall below F times the "
                        "analysed ones (default 0: analyse once, unless an edge outside them comes back; 0.98 was 1.4-3.5x "
                        "faster on the benchmarks; 1: on every change)")


def check_robust_options(args) -> None:
    """Usage errors (exit 2) before any work."""
    from posegraph.cli.common import UsageError

    if args.drop_outliers and args.robust == "none":
        raise UsageError("--drop-outliers needs a robust loss (--robust NAME)")
    if args.robust_scale is not None and args.robust == "none":
        raise UsageError("--robust-scale needs a robust loss (--robust NAME)")
    if args.reanalyse_fraction is not None and args.robust != "gnc":
        raise UsageError("--reanalyse-fraction needs --robust gnc")
    if args.strict_known_inliers and args.robust != "gnc":
        raise UsageError("--strict-known-inliers needs --robust gnc")
    if args.drop_outliers and "-" not in (args.input, args.output) and os.path.exists(args.output) and os.path.samefile(args.output, args.input):
        raise UsageError(f"--drop-outliers never overwrites the input {args.input}: choose another OUT")


def robust_loss(args):
    """The loss of ``--robust`` for :class:`~posegraph.solve.SolverParams`; None for ``none`` and ``gnc``."""
    if getattr(args, "robust", "none") in ("none", "gnc"):
        return None
    from posegraph.robust import make_loss

    return make_loss(args.robust.replace("-", "_"), args.robust_scale)


def run_gnc(graph, start, params, args, status):
    """:func:`posegraph.robust.optimize_robust` as ``--robust gnc`` asks; progress per outer iteration."""
    from posegraph.robust.gnc import GncParams
    from posegraph.robust.pipeline import optimize_robust

    gnc = GncParams() if args.robust_scale is None else GncParams(inlier_threshold=args.robust_scale**2)

    def progress(record) -> None:
        stage = "tls" if math.isinf(record.mu) else "gnc"
        status(f"  {stage} {record.iteration:3d}  mu {record.mu:.3g}  inliers {record.inliers}  cost {record.cost:.10e}")

    fraction = {} if args.reanalyse_fraction is None else {"reanalyse_fraction": args.reanalyse_fraction}
    return optimize_robust(graph, start, params, gnc=gnc, known_inliers=args.known_inliers, progress=progress,
                           strict_known_inliers=args.strict_known_inliers, **fraction)  # fmt: skip


def final_weights(graph, args, result, robust):
    """``(m,)`` final edge weights (GNC's, or ρ'(s) at the result), None without ``--robust``."""
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    if robust is not None:
        return robust.weights
    loss = robust_loss(args)
    if loss is None:
        return None
    from posegraph.robust.measurements import squared_residuals

    return np.asarray(loss.weight(squared_residuals(graph, result.poses)), dtype=np.float64)


def final_prior_weights(graph, args, result, robust):
    """``(u,)`` final weights of the priors (GNC's, or ρ'(s) at the result), None without ``--robust`` or priors."""
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    if graph.priors is None or not len(graph.priors) or args.robust == "none":
        return None
    if robust is not None:
        return robust.prior_weights
    from posegraph.robust.measurements import measurement_residuals

    return np.asarray(robust_loss(args).weight(measurement_residuals(graph, result.poses)[graph.num_edges:]))


def final_landmark_weights(graph, args, result, robust):
    """``(q,)`` final weights of the landmark measurements (GNC's, or ρ'(s) at the result), None without
    ``--robust`` or landmarks."""
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    if graph.landmarks is None or not graph.landmarks.num_measurements or args.robust == "none":
        return None
    if robust is not None:
        return robust.landmark_weights
    from posegraph.solve.landmark_terms import landmark_errors

    return np.asarray(robust_loss(args).weight(landmark_errors(graph, result.poses, result.points).squared))


def robust_summary(graph, weights, args, prior_weights=None, landmark_weights=None) -> None:
    """Print the outlier line of the summary, if robust: after the others, on the same stream
    (stderr when standard output carries the result or the report)."""
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    if weights is not None:
        out = sys.stderr if "-" in (args.output, args.report) else sys.stdout
        line = outlier_line(graph, weights)
        if prior_weights is not None:
            line += f"; {int(np.count_nonzero(prior_weights < OUTLIER_WEIGHT))} of {len(prior_weights)} priors"
        if landmark_weights is not None:
            line += (f"; {int(np.count_nonzero(landmark_weights < OUTLIER_WEIGHT))} of {len(landmark_weights)} "
                     "landmark measurements")
        print(line, file=out, flush=True)


def robust_report(report: dict, args, weights, known=None, prior_weights=None, graph=None, landmark_weights=None) -> dict:
    """``report`` with ``robust`` (the ``--robust`` name) and ``outlier_edges`` (0-based edge-line
    indices with final weight below 0.5) when robust, ``outlier_priors`` (the same of the priors) with
    priors, and ``known_inliers`` (GNC's, from
    :func:`known_inlier_facts`) when given; unchanged otherwise."""
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    if weights is not None:
        report["robust"] = args.robust
        report["outlier_edges"] = [int(k) for k in np.flatnonzero(weights < OUTLIER_WEIGHT)]
    if prior_weights is not None:  # priors (pose priors first, then position priors) judged outliers
        report["outlier_priors"] = [int(k) for k in np.flatnonzero(prior_weights < OUTLIER_WEIGHT)]
    if known is not None:
        report["known_inliers"] = dict(known, mode=args.known_inliers, strict=bool(args.strict_known_inliers))
    if landmark_weights is not None:
        report["outlier_landmark_measurements"] = _landmark_outlier_rows(graph, landmark_weights)
    return report


def _landmark_outlier_rows(graph, weights) -> list:
    """Per landmark measurement of weight below 0.5: ``{"tag", "line", "pose_id", "landmark_id"}`` (pose_id
    None for a point prior)."""
    from posegraph.robust.pipeline import landmark_outliers

    families = graph.landmarks.observations
    return [{"tag": families[o.family].tag, "line": o.line, "pose_id": None if o.pose < 0 else int(graph.ids[o.pose]),
             "landmark_id": int(graph.landmarks.ids[o.landmark])} for o in landmark_outliers(graph, weights)]


def known_inlier_facts(graph, robust) -> dict | None:
    """What GNC's trusted edges look like at its result (None without GNC): ``count``,
    ``chi2_per_dof`` (:func:`~posegraph.robust.trust.known_chi2_per_dof`), and ``released`` and
    ``suspicious`` (:class:`~posegraph.robust.pipeline.RobustResult`'s, 0-based edge-line indices)."""
    if robust is None:
        return None
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    from posegraph.robust.measurements import squared_residuals
    from posegraph.robust.trust import known_chi2_per_dof

    ratio = known_chi2_per_dof(squared_residuals(graph, robust.poses), robust.known, graph.group.dim)
    return {"count": int(np.count_nonzero(robust.known)), "chi2_per_dof": ratio,
            "released": [int(k) for k in robust.released], "suspicious": [int(k) for k in robust.suspicious]}


def warn_about_known_inliers(graph, known: dict | None) -> None:
    """Warnings naming the known inliers GNC released, or (strict, or still failing) kept though they
    fail the inlier test, and one when their χ² per dof is far above 1."""
    from posegraph.cli.common import warn
    from posegraph.analysis.report import CHI2_PER_DOF_WARNING

    if known is None:
        return
    if known["released"]:
        warn(f"{_edges_text(graph, known['released'])} trusted as known inliers failed the inlier test at the result "
             "and were released: GNC ran again judging them like loop closures (--strict-known-inliers keeps them)")
    if known["suspicious"]:
        warn(f"{_edges_text(graph, known['suspicious'])} trusted as known inliers fail the inlier test at the result: "
             "wrong odometry? the answer bends to fit them")
    if known["chi2_per_dof"] > CHI2_PER_DOF_WARNING:
        warn(f"the known inliers' χ² per dof is {known['chi2_per_dof']:.3g}, far above the ≈1 their information "
             f"matrices predict (> {CHI2_PER_DOF_WARNING:g}): some trusted edge is wrong or overconfident")


def _edges_text(graph, edges: list, shown: int = 5) -> str:
    """``"3 edges (lines 12, 40, 77)"``: how many, and the file lines of the first ``shown``."""
    lines = graph.edge_lines
    where = ", ".join(str(int(lines[k])) if lines is not None else f"edge {k}" for k in edges[:shown])
    more = f", … {len(edges) - shown} more" if len(edges) > shown else ""
    return f"{len(edges)} edge{'s' if len(edges) != 1 else ''} (line{'s' if len(edges) != 1 else ''} {where}{more})"


def outlier_line(graph, weights) -> str:
    """The summary line: how many loop closures (and odometry edges, if any) were judged outliers."""
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    outlier = weights < OUTLIER_WEIGHT
    odometry = graph.odometry_mask()
    loops = int(np.count_nonzero(outlier & ~odometry))
    line = f"outliers:       {loops} of {int(np.count_nonzero(~odometry))} loop closures (final weight < {OUTLIER_WEIGHT})"
    rejected_odometry = int(np.count_nonzero(outlier & odometry))
    return line + (f", and {rejected_odometry} odometry edges" if rejected_odometry else "")


def output_graph(graph, weights, *, drop: bool, prior_weights=None, landmark_weights=None):
    """``graph`` without the edges (and priors, ``prior_weights`` ``(u,)``, and landmark measurements,
    ``landmark_weights`` ``(q,)``) judged outliers when ``drop`` and robust, else ``graph``."""
    import numpy as np  # here, not at import: --help and the parser must not load numpy

    if not drop or weights is None:
        return graph
    from posegraph.robust.active import edge_subgraph
    from posegraph.robust.measurements import landmark_subset, weighted_priors

    kept = edge_subgraph(graph, np.flatnonzero(weights >= OUTLIER_WEIGHT))
    if landmark_weights is not None and np.any(landmark_weights < OUTLIER_WEIGHT):
        kept = landmark_subset(kept, landmark_weights >= OUTLIER_WEIGHT)
    if prior_weights is None or np.all(prior_weights >= OUTLIER_WEIGHT):
        return kept
    return weighted_priors(kept, (prior_weights >= OUTLIER_WEIGHT).astype(np.float64))
