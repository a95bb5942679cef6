"""gtsam's side of the benchmark as one process: read, initialise, optimise, write.

    python benchmarks/gtsam_pipeline.py IN.g2o -o OUT.g2o --report REPORT.json [--method lm|gn] [--init chordal|file]

What a gtsam user writes (gtsam's ``Pose3SLAMExample_initializePose3Chordal.py``):
``readG2o(path, is3D)``; a tight prior on the first pose (its file value, or the identity
when the file has no vertices) to fix the gauge, as our solver holds that vertex constant;
in 3D ``InitializePose3.initialize`` (chordal relaxation + one Gauss-Newton refinement), in 2D
``lago.initialize`` (gtsam's LAGO accepts only diagonal noise models, so it runs on a copy of the
graph whose noise keeps each edge's marginal sigmas; the optimiser then uses the full
information); gtsam's ``LevenbergMarquardtOptimizer`` or ``GaussNewtonOptimizer`` with default
parameters; ``writeG2o``. 2D or 3D is told by the file's first vertex or edge tag.

Costs are ``NonlinearFactorGraph.error`` of the graph as read, without the prior, so they compare
with ours. The report is JSON: ``initial_cost`` (at the initialisation), ``final_cost``,
``iterations``, ``vertices``, ``edges`` and ``seconds`` per phase (``import``, ``read``,
``initialize``, ``optimize``, ``write``), each measured with ``time.perf_counter`` inside this
process; the harness adds the whole-process wall time and peak memory.
"""

import time

_t0 = time.perf_counter()

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402

_phase = "start"  # the phase running, named in the one-line error message


def is_planar(path: str) -> bool:
    """Whether the g2o file's first vertex or edge line is 2D (``VERTEX_SE2``/``EDGE_SE2``)."""
    with open(path) as stream:
        for line in stream:
            tag = line.split(maxsplit=1)[0] if line.strip() else ""
            if tag.startswith(("VERTEX", "EDGE")):
                return tag in ("VERTEX_SE2", "EDGE_SE2")
    return False


def diagonal_copy(gtsam, graph):
    """``graph``'s between factors with diagonal noise of the same marginal sigmas (for LAGO)."""
    import numpy as np

    copy = gtsam.NonlinearFactorGraph()
    for index in range(graph.size()):
        factor = graph.at(index)
        if isinstance(factor, gtsam.BetweenFactorPose2):
            r = factor.noiseModel().R()
            sigmas = np.sqrt(np.diag(np.linalg.inv(r.T @ r)))
            keys = factor.keys()
            copy.add(gtsam.BetweenFactorPose2(keys[0], keys[1], factor.measured(), gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    return copy


def initialise(gtsam, graph, initial, planar: bool, init: str):
    """``(graph with the gauge prior, start values)``: the prior on the first pose, then chordal/LAGO or the file's values."""
    keys = sorted(graph.keyVector())
    anchor = min(initial.keys()) if initial.size() else keys[0]
    pose_type, prior_type, dim = (
        (gtsam.Pose2, gtsam.PriorFactorPose2, 3) if planar else (gtsam.Pose3, gtsam.PriorFactorPose3, 6)
    )
    at = initial.atPose2 if planar else initial.atPose3
    anchor_pose = at(anchor) if initial.exists(anchor) else pose_type()
    prior = prior_type(anchor, anchor_pose, gtsam.noiseModel.Isotropic.Sigma(dim, 1e-6))
    with_prior = gtsam.NonlinearFactorGraph(graph)
    with_prior.add(prior)
    if init == "file":
        return with_prior, initial
    if not planar:
        return with_prior, gtsam.InitializePose3.initialize(with_prior)
    lago_graph = diagonal_copy(gtsam, graph)
    lago_graph.add(prior)
    return with_prior, gtsam.lago.initialize(lago_graph)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input")
    parser.add_argument("-o", "--output", required=True)
    parser.add_argument("--report", required=True)
    parser.add_argument("--method", choices=("lm", "gn"), default="lm")
    parser.add_argument("--init", choices=("chordal", "file"), default="chordal")
    args = parser.parse_args(argv)
    seconds = {}

    global _phase
    _phase = "import"
    t = time.perf_counter()
    import gtsam

    seconds["import"] = time.perf_counter() - t

    _phase = "read"
    t = time.perf_counter()
    planar = is_planar(args.input)
    graph, initial = gtsam.readG2o(args.input, not planar)
    seconds["read"] = time.perf_counter() - t

    _phase = "initialize"
    t = time.perf_counter()
    with_prior, start = initialise(gtsam, graph, initial, planar, args.init)
    seconds["initialize"] = time.perf_counter() - t
    initial_cost = graph.error(start)

    _phase = "optimize"
    t = time.perf_counter()
    if args.method == "lm":
        optimizer = gtsam.LevenbergMarquardtOptimizer(with_prior, start, gtsam.LevenbergMarquardtParams())
    else:
        optimizer = gtsam.GaussNewtonOptimizer(with_prior, start, gtsam.GaussNewtonParams())
    result = optimizer.optimize()
    seconds["optimize"] = time.perf_counter() - t
    final_cost = graph.error(result)

    _phase = "write"
    t = time.perf_counter()
    gtsam.writeG2o(graph, result, args.output)
    seconds["write"] = time.perf_counter() - t

    report = {
        "tool": "gtsam",
        "method": args.method,
        "init": args.init,
        "vertices": len(graph.keyVector()),
        "edges": int(graph.size()),
        "initial_cost": initial_cost,
        "final_cost": final_cost,
        "iterations": int(optimizer.iterations()),
        "seconds": seconds,
        "in_process_seconds": time.perf_counter() - _t0,
    }
    with open(args.report, "w") as stream:
        json.dump(report, stream, indent=1)
    return 0


def _main() -> int:
    """``main`` with gtsam's exceptions reduced to one line on stderr (exit status 1)."""
    try:
        return main()
    except RuntimeError as error:  # gtsam raises RuntimeError with a multi-line explanation
        lines = [line.strip() for line in str(error).splitlines() if line.strip()]
        print(f"gtsam_pipeline: {_phase} failed: {' '.join(lines[:2])}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(_main())
