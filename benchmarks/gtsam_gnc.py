"""gtsam's side of the robust benchmark as one process: read, initialise, GNC, report.

    python benchmarks/gtsam_gnc.py IN.g2o --report REPORT.json

What a gtsam user writes for robust pose-graph optimisation (gtsam's ``GncOptimizer`` tests and
examples): ``readG2o(path, is3D=True)``; a tight prior on the first pose (its file value) to fix
the gauge; the start from ``InitializePose3.initialize`` (gtsam's chordal relaxation + one
Gauss-Newton refinement, the start of gtsam's own Pose3 SLAM examples; for a 2D file — first line
``VERTEX_SE2`` — ``readG2o(path, is3D=False)``, a ``PriorFactorPose2`` and ``lago.initialize``, gtsam's
planar start); ``GncLMOptimizer`` with
``GncLMParams()`` defaults — TLS, μ step 1.4, relative cost tolerance 1e-5, weights tolerance
1e-4, inlier thresholds at the χ² quantile 0.99 (gtsam's default for ``GncLMOptimizer``) — and
known inliers: the odometry edges (consecutive vertex ids, in either direction) and the prior.

When gtsam's initialiser fails (``InitializePose3`` raises "Indeterminate linear system" on some
synthetic spheres), GNC starts from the file's poses instead and the report says ``"start": "file"``.

The report is JSON: ``outlier_edges`` (0-based edge-line indices whose final weight is below
0.5), ``poses`` file written beside it is not produced; the final poses go to ``--poses`` as a
``.npy`` ``(n, 4, 4)`` in the order of the file's vertex ids, and ``seconds`` per phase plus
``total`` (from the process start, imports included).
"""

import time

_t0 = time.perf_counter()

import argparse  # noqa: E402
import json  # noqa: E402

import numpy as np  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description="gtsam GncLMOptimizer (TLS, defaults) on a g2o file")
    parser.add_argument("input")
    parser.add_argument("--report", required=True)
    parser.add_argument("--poses", required=True, help="final poses, .npy (n, 4, 4) by ascending vertex id")
    args = parser.parse_args()
    import gtsam

    seconds = {"import": time.perf_counter() - _t0}
    t = time.perf_counter()
    with open(args.input) as stream:
        planar = stream.readline().startswith("VERTEX_SE2")
    graph, initial = gtsam.readG2o(args.input, not planar)
    m = graph.size()
    known = [k for k in range(m) if abs(graph.at(k).keys()[0] - graph.at(k).keys()[1]) == 1]
    first = min(initial.keys())
    if planar:
        graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    else:
        graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    known.append(m)
    seconds["read"] = time.perf_counter() - t
    t = time.perf_counter()
    try:
        start, start_name = (gtsam.lago.initialize(graph) if planar else gtsam.InitializePose3.initialize(graph)), "gtsam"
    except RuntimeError:  # e.g. InitializePose3's "Indeterminate linear system" on some synthetic spheres
        start, start_name = initial, "file"
    seconds["initialize"] = time.perf_counter() - t
    t = time.perf_counter()
    params = gtsam.GncLMParams()
    params.setLossType(gtsam.GncLossType.TLS)
    params.setKnownInliers(known)
    optimizer = gtsam.GncLMOptimizer(graph, start, params)
    result = optimizer.optimize()
    seconds["optimize"] = time.perf_counter() - t
    weights = np.asarray(optimizer.getWeights())[:m]
    keys = sorted(result.keys())
    poses = np.stack([(result.atPose2(k) if planar else result.atPose3(k)).matrix() for k in keys])
    np.save(args.poses, poses)
    seconds["total"] = time.perf_counter() - _t0
    report = {"outlier_edges": np.flatnonzero(weights < 0.5).tolist(), "seconds": seconds, "edges": m, "start": start_name}
    with open(args.report, "w") as stream:
        json.dump(report, stream)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
