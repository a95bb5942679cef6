"""The solver's speed, phase by phase, side by side with gtsam's Levenberg-Marquardt.

    python benchmarks/bench_solver.py                 # torus3D and sphere2500 from ../shared/datasets
    python benchmarks/bench_solver.py --repeat 7 --datasets torus3D

Three tables (figures recorded in docs/solver.md):

1. Linearisation + assembly: residuals, Jacobians and per-edge H/g blocks for every edge, then the
   scatter into the sparse lower triangle of H — best and median of ``--repeat`` runs.
2. Linear backends: symbolic analysis once, then the numeric factorisation of the damped H of the
   file's poses — CHOLMOD with each ordering, and the scipy fallback.
3. Whole optimisations, ours (LM, default parameters) and gtsam's LM (default parameters, a prior of
   σ = 1e-6 on the first pose as the gauge), alternating round by round so both see the same machine
   load: final cost, iterations, wall and CPU seconds per iteration, and the median per-round ratio.
   torus3D runs from the file's poses capped at ``--torus-iterations`` for both (both stall there
   for 100 iterations) and from our chordal initialisation; sphere2500 from the file's poses.

4. Final costs on the standard files from the file's poses: gtsam LM at its default tolerances
   (1e-5) and at 1e-12, our LM and GN at their defaults (``--skip costs`` to leave it out).

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
from posegraph.model.graph import held_vertices  # noqa: E402
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
        hessian_blocks = blocks.hessian_blocks
        # linearize computes the Hessian blocks on first use: time them with it, as the solver does
        lin = timed(lambda: linearize(graph.poses, graph, information).hessian_blocks, repeat)
        asm = timed(lambda: (hessian_values(pattern, hessian_blocks), gradient_values(pattern, blocks.gradient)), repeat)

        def both():
            b = linearize(graph.poses, graph, information)
            hessian_values(pattern, b.hessian_blocks)
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
        data = hessian_values(pattern, blocks.hessian_blocks)
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


def run_gtsam(path, initial_poses, graph, max_iterations, tolerance=None):
    """gtsam LM from the file's values (or ``initial_poses``): (final cost, iterations, wall s, CPU s)."""
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
    if tolerance is not None:
        params.setRelativeErrorTol(tolerance)
        params.setAbsoluteErrorTol(tolerance)
    start, cpu = time.perf_counter(), time.process_time()
    optimizer = gtsam.LevenbergMarquardtOptimizer(anchored, values, params)
    result = optimizer.optimize()
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    return factors.error(result), optimizer.iterations(), seconds, cpu


def run_ours(graph, start_poses, max_iterations):
    """Our LM (defaults): (final cost, iterations, wall s, CPU s, result). Wall and CPU include setup."""
    cpu = time.process_time()
    result = optimize(
        graph,
        initial="file" if start_poses is None else start_poses,
        params=SolverParams(max_iterations=max_iterations),
    )
    return result.final_cost, result.iterations, result.seconds_total, time.process_time() - cpu, result


def solver_table(names, rounds, torus_iterations, with_gtsam):
    print("\n## Whole optimisations: ours (LM) vs gtsam LM, same start, alternating rounds\n")
    print("Seconds per iteration: wall clock of the whole optimiser call (ours includes the sparsity")
    print("analysis and symbolic factorisation) over its iterations, as best / median of the rounds;")
    print("ratio: ours / gtsam of those (below 1: ours is faster).\n")
    print("| dataset | start | solver | final cost | iterations | s / iteration (best / median) | ratio (best / median) |")
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
        for _ in range(rounds):
            ours.append(run_ours(graph, start_poses, max_iterations))
            if with_gtsam:
                theirs.append(run_gtsam(path, start_poses, graph, max_iterations))
        per_it = lambda rows: [r[2] / max(r[1], 1) for r in rows]  # noqa: E731
        ours_best, ours_med = min(per_it(ours)), statistics.median(per_it(ours))
        result = min(ours, key=lambda r: r[2] / r[1])[4]  # the best round's phase split
        its = result.iterations
        phases = (
            f"lin {result.seconds_linearize / its:.3f}, asm {result.seconds_assemble / its:.3f}, "
            f"fact {result.seconds_factorize / its:.3f}, solve+eval {result.seconds_solve / its:.3f}"
        )
        ratio = ""
        if theirs:
            their_best, their_med = min(per_it(theirs)), statistics.median(per_it(theirs))
            ratio = f"{ours_best / their_best:.2f} / {ours_med / their_med:.2f}"
        print(
            f"| {name} | {start_name} | posegraph ({result.linear_solver}) | {result.final_cost:.10g} | {its} | "
            f"{ours_best:.3f} / {ours_med:.3f} ({phases}) | {ratio} |"
        )
        if theirs:
            cost, its = theirs[-1][0], theirs[-1][1]
            print(f"| {name} | {start_name} | gtsam LM | {cost:.10g} | {its} | {their_best:.3f} / {their_med:.3f} | |")


COST_FILES = ["tinyGrid3D", "smallGrid3D", "parking-garage", "sphere2500", "pose3example"]


def cost_table(with_gtsam):
    print("\n## Final costs from the file's poses\n")
    header = "| dataset | gtsam LM (tol 1e-5) | gtsam LM (tol 1e-12) | ours LM | ours GN | rel. gap LM vs gtsam 1e-12 |"
    print(header)
    print("|---|---:|---:|---:|---:|---:|")
    for name in COST_FILES:
        if name == "pose3example":
            if not with_gtsam:
                continue
            import gtsam

            path = Path(gtsam.findExampleDataFile("pose3example.txt"))
        else:
            path = DATASETS / f"{name}.g2o"
        graph = read_g2o(path)
        lm = optimize(graph, initial="file", params=SolverParams(method="lm"))
        gn = optimize(graph, initial="file", params=SolverParams(method="gn"))
        default = tight = float("nan")
        if with_gtsam:
            default = run_gtsam(path, None, graph, 100)
            tight = run_gtsam(path, None, graph, 100, tolerance=1e-12)
        gap = (lm.final_cost - tight[0]) / tight[0] if with_gtsam else float("nan")
        g = lambda r: f"{r[0]:.12g} ({r[1]} it)" if with_gtsam else "–"  # noqa: E731
        print(
            f"| {name} | {g(default)} | {g(tight)} | {lm.final_cost:.12g} ({lm.iterations} it) | "
            f"{gn.final_cost:.12g} ({gn.iterations} it) | {gap:.1e} |"
        )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", nargs="+", default=["torus3D", "sphere2500"])
    parser.add_argument("--repeat", type=int, default=7, help="timed repetitions (tables 1-2)")
    parser.add_argument("--rounds", type=int, default=7, help="alternating rounds of whole optimisations (table 3)")
    parser.add_argument("--torus-iterations", type=int, default=15, help="iteration cap for torus3D from the file")
    parser.add_argument("--no-gtsam", action="store_true")
    parser.add_argument("--skip", nargs="*", default=[], choices=["linearize", "backends", "solver", "costs"])
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
    if "costs" not in args.skip:
        cost_table(with_gtsam)
    return 0


if __name__ == "__main__":
    sys.exit(main())
