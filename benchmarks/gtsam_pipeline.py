"""gtsam's side of the benchmark as one process: read, initialise, optimise, write.

    python benchmarks/gtsam_pipeline.py IN.g2o -o OUT.g2o --report REPORT.json [--method lm|gn] [--init chordal|file]

What a gtsam user writes (gtsam's ``Pose3SLAMExample_initializePose3Chordal.py``):
``readG2o(path, is3D=True)``; a tight prior on the first pose (its file value, or the identity
when the file has no vertices) to fix the gauge, as our solver holds that vertex constant;
``InitializePose3.initialize`` (chordal relaxation + one Gauss-Newton refinement); gtsam's
``LevenbergMarquardtOptimizer`` or ``GaussNewtonOptimizer`` with default parameters; ``writeG2o``.

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
    graph, initial = gtsam.readG2o(args.input, True)
    seconds["read"] = time.perf_counter() - t

    _phase = "initialize"
    t = time.perf_counter()
    keys = sorted(graph.keyVector())
    anchor = min(initial.keys()) if initial.size() else keys[0]
    anchor_pose = initial.atPose3(anchor) if initial.exists(anchor) else gtsam.Pose3()
    with_prior = gtsam.NonlinearFactorGraph(graph)
    with_prior.add(gtsam.PriorFactorPose3(anchor, anchor_pose, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    if args.init == "chordal":
        start = gtsam.InitializePose3.initialize(with_prior)
    else:
        start = initial
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
        "vertices": len(keys),
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
