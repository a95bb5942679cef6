"""``posegraph optimize`` against gtsam's best cost on the same factors (issue #27: priors, TORO files).

    python benchmarks/verify_cost.py FILE [FILE …] [--json OUT.json] [-- OPTIMIZE OPTIONS]

For each file (the graphs of ``datasets/prior_graphs.py``, gtsam's ``w100_30.g2o``,
``w10000.graph``…): ``cli.py optimize FILE`` in a fresh process (its ``--report`` gives the final
cost), then gtsam's ``LevenbergMarquardtOptimizer`` on the same factors as posegraph read them —
``BetweenFactorPose3/2`` per edge and, per prior, ``PriorFactorPose3/2`` / ``GPSFactor`` /
``PoseTranslationPrior2D`` (:func:`posegraph.crosscheck.gtsam_bridge.graph_to_gtsam`); the gauge held by the
priors, or else by tight priors on posegraph's anchors (:func:`posegraph.crosscheck.gtsam_bridge.gauge_priors`,
left out of the cost) — from three starts (the file's poses, posegraph's chordal start, posegraph's
result), tolerances 1e-14; gtsam's best cost is the lowest. Printed per file: both costs and their
relative gap (the check: posegraph's cost is at most gtsam's best · (1 + 1e-6)) and, with priors,
the cost (priors included) of the poses optimised without them — what posegraph answered when it
skipped the prior lines.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import replace

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

TOLERANCE = 1e-6
"""posegraph's cost may exceed gtsam's best by at most this fraction."""


def posegraph_cost(path: str, options=()) -> tuple[float, float, dict]:
    """``(final cost, wall seconds, report)`` of ``cli.py optimize path [options]`` in a fresh process."""
    with tempfile.TemporaryDirectory() as folder:
        report = os.path.join(folder, "report.json")
        command = [sys.executable, os.path.join(ROOT, "cli.py"), "optimize", path, "-o",
                   os.path.join(folder, "out.g2o"), "--report", report, "--quiet", *options]
        start = time.perf_counter()
        subprocess.run(command, check=True)
        seconds = time.perf_counter() - start
        with open(report) as handle:
            data = json.load(handle)
    return float(data["final_cost"]), seconds, data


def gtsam_best_cost(graph, starts: dict) -> dict:
    """``{start name: gtsam's LM cost from it}`` on the graph's factors (priors included, no gauge prior)."""
    import gtsam

    from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam, poses_to_values

    from posegraph.crosscheck.gtsam_bridge import gauge_priors

    factors = graph_to_gtsam(graph)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    params.setMaxIterations(500)
    costs = {}
    for name, poses in starts.items():
        anchored = gtsam.NonlinearFactorGraph(factors)
        anchored.push_back(gauge_priors(graph, poses))  # none for a component the priors hold
        result = gtsam.LevenbergMarquardtOptimizer(anchored, poses_to_values(graph.ids, poses), params).optimize()
        costs[name] = float(factors.error(result))
    return costs


def gtsam_own_reading_cost(path: str, graph, start) -> float | None:
    """gtsam's LM cost on the factors ``gtsam.readG2o`` itself makes of ``path`` (from ``start``, the
    anchor held by a tight prior), or None when gtsam cannot read the file as it is (priors, which
    it skips; ``EQUIV`` merges; TORO's order, which it refuses)."""
    import gtsam

    from posegraph.crosscheck.gtsam_bridge import gauge_priors, poses_to_values

    if graph.priors is not None or graph.kept_lines:
        return None
    try:
        factors, _ = gtsam.readG2o(path, graph.group.name == "SE3")
    except RuntimeError:
        return None
    anchored = gtsam.NonlinearFactorGraph(factors)
    anchored.push_back(gauge_priors(graph, start))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    return float(factors.error(gtsam.LevenbergMarquardtOptimizer(anchored, poses_to_values(graph.ids, start), params).optimize()))


def verify(path: str, options=()) -> dict:
    """The figures of one file (module docstring)."""
    from posegraph.init import initialize
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.optimizer import optimize
    from posegraph.solve.residuals import cost

    ours, seconds, report = posegraph_cost(path, options)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the command above showed them
        graph = read_g2o(path, edge2_information=_option(options, "--edge2-information", "auto"))
    starts = {"file": graph.poses, "posegraph chordal": initialize(graph, "chordal"),
              "posegraph result": optimize(graph, "chordal").poses}
    theirs = gtsam_best_cost(graph, starts)
    best = min(theirs.values())
    row = {
        "file": os.path.basename(path), "vertices": graph.num_vertices, "edges": graph.num_edges,
        "pose_priors": graph.priors.num_pose if graph.priors else 0,
        "position_priors": graph.priors.num_position if graph.priors else 0,
        "posegraph_cost": ours, "posegraph_seconds": seconds, "iterations": report.get("iterations"),
        "gtsam_costs": theirs, "gtsam_best": best, "relative_gap": (ours - best) / best,
        "reached": ours <= best * (1 + TOLERANCE),
    }
    own = gtsam_own_reading_cost(path, graph, starts["posegraph result"])
    if own is not None:
        row["gtsam_own_reading"] = own
    if graph.priors is not None:  # the answer when the priors were skipped, scored with them
        row["cost_when_priors_skipped"] = cost(graph, optimize(replace(graph, priors=None), "chordal").poses)
    return row


def _option(options, name: str, default: str) -> str:
    """The value following ``name`` in ``options``, else ``default``."""
    options = list(options)
    return options[options.index(name) + 1] if name in options else default


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--json", help="write the figures here")
    argv = sys.argv[1:] if argv is None else list(argv)
    options = argv[argv.index("--") + 1:] if "--" in argv else []
    args = parser.parse_args(argv[: argv.index("--")] if "--" in argv else argv)
    rows = [verify(path, options) for path in args.files]
    for row in rows:
        skipped = row.get("cost_when_priors_skipped")
        print(f"{row['file']}: {row['vertices']} vertices, {row['edges']} edges, {row['pose_priors']} pose + "
              f"{row['position_priors']} position priors; posegraph {row['posegraph_cost']:.9g} "
              f"({row['iterations']} iterations, {row['posegraph_seconds']:.2f} s process), gtsam best "
              f"{row['gtsam_best']:.9g} (gap {row['relative_gap']:+.2e}: {'reached' if row['reached'] else 'NOT reached'})"
              + (f"; priors skipped: {skipped:.9g}" if skipped is not None else "")
              + (f"; gtsam's own reading: {row['gtsam_own_reading']:.9g}" if "gtsam_own_reading" in row else ""))
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(rows, handle, indent=2)
    return 0 if all(row["reached"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
