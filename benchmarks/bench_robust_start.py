"""Starts for GNC on a graph with injected outliers: how far each is from the clean optimum.

    python -m benchmarks.bench_robust_start                          # sphere2500, 20 % outliers, seed 1
    python -m benchmarks.bench_robust_start path/to/graph.g2o --fraction 0.1 --seed 3

The clean graph is read, optimised (its optimum is the reference), and ``fraction`` × its loop
closures of random outliers are injected (:func:`datasets.synthetic.inject_outliers`). For each
start the table gives the time to make it, its cost on the *clean* graph (½ Σ eᵀΩe over the
original edges only) and its ATE (RMS translation and rotation error after rigid alignment)
against the clean optimum. The robust chordal start also reports the outliers it rejected, and
the last row is the whole pipeline it allows: robust chordal start, then one Levenberg-Marquardt
solve of the graph weighted by its weights. Figures are recorded in docs/robust.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "datasets"


def _row(name: str, seconds: float, poses, clean, reference, extra: str = "") -> str:
    from posegraph.analysis.evaluate import absolute_trajectory_error
    from posegraph.solve.residuals import cost

    translation, rotation, _ = absolute_trajectory_error(poses, reference)
    return (
        f"| {name} | {seconds:.2f} | {cost(clean, poses):.4g} | {np.sqrt(np.mean(translation**2)):.3g} "
        f"| {np.sqrt(np.mean(rotation**2)):.3g} | {extra} |"
    )


def _timed(make):
    start = time.perf_counter()
    value = make()
    return value, time.perf_counter() - start


def run(path: Path, fraction: float, seed: int, log=print) -> None:
    from datasets.synthetic import inject_outliers
    from posegraph.init import initialize
    from posegraph.io.g2o import read_g2o
    from posegraph.robust import starts
    from posegraph.robust.measurements import weighted_graph
    from posegraph.solve import optimize

    clean = read_g2o(path)
    reference = optimize(clean).poses
    graph, indices = inject_outliers(clean, fraction=fraction, seed=seed)
    outlier = np.zeros(graph.num_edges, bool)
    outlier[indices] = True
    log(f"{path.name}: {clean.num_vertices} poses, {clean.num_edges} edges + {len(indices)} outliers (seed {seed})\n")
    log("| start | time (s) | cost on the clean graph | ATE trans. RMS | ATE rot. RMS (deg) | outliers rejected |")
    log("|---|---|---|---|---|---|")
    log(_row("clean optimum (reference)", 0.0, reference, clean, reference))
    rows = [
        ("chordal, every edge", lambda: initialize(graph, "chordal")),
        ("odometry BFS tree, every edge", lambda: initialize(graph, "odometry")),
        ("odometry chain (known inliers)", lambda: starts.inlier_chain_start(graph)),
    ] + [
        (f"chordal, loop closures × {factor:g}", lambda factor=factor: starts.downweighted_chordal_start(graph, factor))
        for factor in (1e-1, 1e-2, 1e-3, 1e-6)
    ]
    for name, make in rows:
        poses, seconds = _timed(make)
        log(_row(name, seconds, poses, clean, reference))
    robust, seconds = _timed(lambda: starts.robust_chordal_start(graph))
    rejected = ~robust.inliers
    verdict = f"{rejected.sum()} ({np.count_nonzero(rejected & outlier)} true, {np.count_nonzero(rejected & ~outlier)} false); {robust.iterations} GNC iterations"
    log(_row("robust chordal (GNC-TLS over chordal)", seconds, robust.poses, clean, reference, verdict))
    final, more = _timed(lambda: optimize(weighted_graph(graph, np.round(robust.weights)), initial=robust.poses).poses)
    log(_row("robust chordal, then LM on the weighted graph", seconds + more, final, clean, reference, "same weights"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_robust_start", description=__doc__.split("\n\n")[0])
    parser.add_argument("file", nargs="?", type=Path, default=SHARED / "sphere2500.g2o", help="clean g2o graph (default sphere2500)")
    parser.add_argument("--fraction", type=float, default=0.2, help="outliers per loop closure (default 0.2)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the injected outliers (default 1)")
    args = parser.parse_args(argv)
    if not args.file.is_file():
        print(f"error: {args.file} does not exist", file=sys.stderr)
        return 1
    run(args.file, args.fraction, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
