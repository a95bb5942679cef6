"""The solver's speed, phase by phase, side by side with gtsam's Levenberg-Marquardt.

    python benchmarks/bench_solver.py                 # torus3D and sphere2500 from ../shared/datasets
    python benchmarks/bench_solver.py --repeat 7 --datasets torus3D

Three tables (figures recorded in docs/solver.md):

1. Linearisation + assembly: residuals, Jacobians and per-edge H/g blocks for every edge, then the
   scatter into the sparse lower triangle of H — best and median of ``--repeat`` runs.
2. Linear backends: symbolic analysis once, then the numeric factorisation of the damped H of the
   file's poses — CHOLMOD with each ordering, and the scipy fallback.
3. Whole optimisations, ours (LM, default parameters) and gtsam's LM (default parameters, a prior of
   σ = 1e-6 on the first pose as the gauge), alternating so both see the same machine load: final
   cost, iterations, seconds per iteration. torus3D runs from the file's poses capped at
   ``--torus-iterations`` for both (gtsam stalls there for 100 iterations), and from our chordal
   initialisation; sphere2500 from the file's poses.

Timings on a shared machine are noisy: compare the ratios within one run, not across runs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from posegraph.io.g2o import read_g2o  # noqa: E402
from posegraph.solve import SolverParams, optimize  # noqa: E402
from posegraph.solve.linear import CholmodSolver, ScipySolver, cholmod_available  # noqa: E402
from posegraph.solve.linearize import linearize  # noqa: E402
from posegraph.solve.optimizer import held_vertices  # noqa: E402
from posegraph.solve.sparsity import analyze_pattern, gradient_values, hessian_values  # noqa: E402

DATASETS = ROOT.parent / "shared" / "datasets"


def timed(function, repeat):
    """(best, median) seconds of ``repeat`` calls."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times), statistics.median(times)


def linearize_table(graphs, repeat):
    print("\n## Linearisation + assembly (ms: best / median)\n")
    print("| dataset | edges | linearise | assemble | total |")
    print("|---|---:|---:|---:|---:|")
    for name, graph in graphs.items():
        pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held_vertices(graph))
        information = np.ascontiguousarray(graph.information)
        blocks = linearize(graph.poses, graph, information)
        lin = timed(lambda: linearize(graph.poses, graph, information), repeat)
        asm = timed(lambda: (hessian_values(pattern, blocks.hessian), gradient_values(pattern, blocks.gradient)), repeat)

        def both():
            b = linearize(graph.poses, graph, information)
            hessian_values(pattern, b.hessian)
            gradient_values(pattern, b.gradient)

        tot = timed(both, repeat)
        cell = lambda t: f"{1e3 * t[0]:.1f} / {1e3 * t[1]:.1f}"  # noqa: E731
        print(f"| {name} | {graph.num_edges} | {cell(lin)} | {cell(asm)} | {cell(tot)} |")


def backend_table(graphs, repeat):
    print("\n## Linear backends: analysis once, numeric factorisation per iteration (s: best / median)\n")
    print("| dataset | backend | analysis | factorisation | solve |")
    print("|---|---|---:|---:|---:|")
    for name, graph in graphs.items():
        pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held_vertices(graph))
        blocks = linearize(graph.poses, graph)
        data = hessian_values(pattern, blocks.hessian)
        data[pattern.diagonal] *= 1.0 + 1e-5  # LM's Marquardt damping at the initial λ
        rhs = -gradient_values(pattern, blocks.gradient)
        makers = []
        if cholmod_available():
            for ordering in ("amd", "metis", "nesdis"):
                makers.append((f"cholmod {ordering}", lambda o=ordering: CholmodSolver(pattern, o)))
        makers.append(("scipy SuperLU", lambda: ScipySolver(pattern)))
        for label, make in makers:
            start = time.perf_counter()
            try:
                solver = make()
            except Exception as err:  # e.g. CHOLMOD built without METIS
                print(f"| {name} | {label} | unavailable: {err} | | |")
                continue
            analysis = time.perf_counter() - start
            fact = timed(lambda: solver.factorize(data), repeat)
            solve = timed(lambda: solver.solve(rhs), repeat)
            print(f"| {name} | {label} | {analysis:.3f} | {fact[0]:.3f} / {fact[1]:.3f} | {solve[0]:.4f} / {solve[1]:.4f} |")


def run_gtsam(path, initial_poses, graph, max_iterations):
    import gtsam

    factors, values = gtsam.readG2o(str(path), True)
    if initial_poses is not None:
        values = gtsam.Values()
        for key, pose in zip(graph.ids.tolist(), initial_poses):
            values.insert(int(key), gtsam.Pose3(pose))
    first = min(values.keys())
    anchored = gtsam.NonlinearFactorGraph(factors)
    anchored.add(gtsam.PriorFactorPose3(first, values.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    optimizer = gtsam.LevenbergMarquardtOptimizer(anchored, values, params)
    start = time.perf_counter()
    result = optimizer.optimize()
    seconds = time.perf_counter() - start
    return factors.error(result), optimizer.iterations(), seconds


def solver_table(names, repeat, torus_iterations, with_gtsam):
    print("\n## Whole optimisations: ours (LM) vs gtsam LM, same start (median over rounds)\n")
    print("| dataset | start | solver | final cost | iterations | s total | s / iteration |")
    print("|---|---|---|---:|---:|---:|---:|")
    runs = []
    for name in names:
        path = DATASETS / f"{name}.g2o"
        graph = read_g2o(path)
        if name == "torus3D":
            runs.append((name, path, graph, "file", None, torus_iterations))
            from posegraph.init import initialize

            runs.append((name, path, graph, "chordal", initialize(graph, "chordal"), 100))
        else:
            runs.append((name, path, graph, "file", None, 100))
    for name, path, graph, start_name, start_poses, max_iterations in runs:
        ours, theirs = [], []
        for _ in range(repeat):
            result = optimize(
                graph,
                initial="file" if start_poses is None else start_poses,
                params=SolverParams(max_iterations=max_iterations),
            )
            ours.append((result.final_cost, result.iterations, result.seconds_total, result))
            if with_gtsam:
                theirs.append(run_gtsam(path, start_poses, graph, max_iterations))
        cost, its, secs, result = sorted(ours, key=lambda r: r[2])[len(ours) // 2]
        phases = (
            f"lin {result.seconds_linearize / its:.3f}, asm {result.seconds_assemble / its:.3f}, "
            f"fact {result.seconds_factorize / its:.3f}, solve+eval {result.seconds_solve / its:.3f}"
        )
        print(f"| {name} | {start_name} | posegraph ({result.linear_solver}) | {cost:.10g} | {its} | {secs:.2f} | {secs / its:.3f} ({phases}) |")
        if theirs:
            cost, its, secs = sorted(theirs, key=lambda r: r[2])[len(theirs) // 2]
            print(f"| {name} | {start_name} | gtsam LM | {cost:.10g} | {its} | {secs:.2f} | {secs / max(its, 1):.3f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", nargs="+", default=["torus3D", "sphere2500"])
    parser.add_argument("--repeat", type=int, default=5, help="timed repetitions (tables 1-2) and rounds (table 3)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of whole optimisations (table 3)")
    parser.add_argument("--torus-iterations", type=int, default=30)
    parser.add_argument("--no-gtsam", action="store_true")
    parser.add_argument("--skip", nargs="*", default=[], choices=["linearize", "backends", "solver"])
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    graphs = {name: read_g2o(DATASETS / f"{name}.g2o") for name in args.datasets}
    with_gtsam = not args.no_gtsam
    if with_gtsam:
        try:
            import gtsam  # noqa: F401
        except ImportError:
            with_gtsam = False
    if "linearize" not in args.skip:
        linearize_table(graphs, args.repeat)
    if "backends" not in args.skip:
        backend_table(graphs, args.repeat)
    if "solver" not in args.skip:
        solver_table(args.datasets, args.rounds, args.torus_iterations, with_gtsam)
    return 0


if __name__ == "__main__":
    sys.exit(main())
