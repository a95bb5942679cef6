"""Graphs with priors: ``posegraph optimize`` against gtsam's best cost on the same factors (issue #27).

    python benchmarks/verify_priors.py FILE.g2o [FILE.g2o …] [--json OUT.json]

For each file (e.g. those of ``datasets/prior_graphs.py``): ``cli.py optimize FILE`` in a fresh
process (its ``--report`` gives the final cost and the wall time), then gtsam's
``LevenbergMarquardtOptimizer`` on the same factors — ``BetweenFactorPose3/2`` per edge and, per
prior, ``PriorFactorPose3/2`` / ``GPSFactor`` / ``PoseTranslationPrior2D``
(:func:`posegraph.gtsam_bridge.graph_to_gtsam`), no gauge prior: the priors hold the gauge — from
three starts (the file's poses, posegraph's chordal start, posegraph's result), tolerances 1e-14;
gtsam's best cost is the lowest. Printed per file: both costs and their relative gap (the check:
posegraph's cost is at most gtsam's best · (1 + 1e-6)), and the cost with the priors of the poses
optimised without them (what posegraph answered when it skipped the prior lines).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

TOLERANCE = 1e-6
"""posegraph's cost may exceed gtsam's best by at most this fraction."""


def posegraph_cost(path: str) -> tuple[float, float, dict]:
    """``(final cost, wall seconds, report)`` of ``cli.py optimize path`` in a fresh process."""
    with tempfile.TemporaryDirectory() as folder:
        report = os.path.join(folder, "report.json")
        command = [sys.executable, os.path.join(ROOT, "cli.py"), "optimize", path, "-o",
                   os.path.join(folder, "out.g2o"), "--report", report, "--quiet"]
        start = time.perf_counter()
        subprocess.run(command, check=True)
        seconds = time.perf_counter() - start
        with open(report) as handle:
            data = json.load(handle)
    return float(data["final_cost"]), seconds, data


def gtsam_best_cost(graph, starts: dict) -> dict:
    """``{start name: gtsam's LM cost from it}`` on the graph's factors (priors included, no gauge prior)."""
    import gtsam

    from posegraph.gtsam_bridge import graph_to_gtsam, poses_to_values

    factors = graph_to_gtsam(graph)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    params.setMaxIterations(500)
    costs = {}
    for name, poses in starts.items():
        result = gtsam.LevenbergMarquardtOptimizer(factors, poses_to_values(graph.ids, poses), params).optimize()
        costs[name] = float(factors.error(result))
    return costs


def verify(path: str) -> dict:
    """The figures of one file (module docstring)."""
    from posegraph.init import initialize
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.optimizer import optimize
    from posegraph.solve.residuals import cost

    ours, seconds, report = posegraph_cost(path)
    graph = read_g2o(path)
    without = optimize(replace(graph, priors=None), "chordal").poses  # the answer when the priors were skipped
    starts = {"file": graph.poses, "posegraph chordal": initialize(graph, "chordal"),
              "posegraph result": optimize(graph, "chordal").poses}
    theirs = gtsam_best_cost(graph, starts)
    best = min(theirs.values())
    return {
        "file": os.path.basename(path), "vertices": graph.num_vertices, "edges": graph.num_edges,
        "pose_priors": graph.priors.num_pose, "position_priors": graph.priors.num_position,
        "posegraph_cost": ours, "posegraph_seconds": seconds, "iterations": report.get("iterations"),
        "gtsam_costs": theirs, "gtsam_best": best, "relative_gap": (ours - best) / best,
        "reached": ours <= best * (1 + TOLERANCE), "cost_when_priors_skipped": cost(graph, without),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args(argv)
    rows = [verify(path) for path in args.files]
    for row in rows:
        print(f"{row['file']}: {row['vertices']} vertices, {row['edges']} edges, {row['pose_priors']} pose + "
              f"{row['position_priors']} position priors; posegraph {row['posegraph_cost']:.9g} "
              f"({row['iterations']} iterations, {row['posegraph_seconds']:.2f} s process), gtsam best "
              f"{row['gtsam_best']:.9g} (gap {row['relative_gap']:+.2e}: {'reached' if row['reached'] else 'NOT reached'}); "
              f"priors skipped: {row['cost_when_priors_skipped']:.9g}")
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(rows, handle, indent=2)
    return 0 if all(row["reached"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
