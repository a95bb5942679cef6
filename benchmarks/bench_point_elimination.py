"""Point elimination on landmark graphs against today's CHOLMOD (AMD) path, side by side (issue 44).

    python -m benchmarks.bench_point_elimination [--data DIR] [--rounds N] [--files NAME ...] [--out FILE.json]

Per file: the start is made once (the solver's own: :func:`posegraph.solve.file_start.start_poses`, the
landmarks placed from it, the central pose held as :func:`posegraph.solve.optimizer.optimize` holds it);
then each variant's analysis (its linear solver built once: ordering, symbolic factorisation, gathers),
and ``--rounds`` rounds of LM from that start, the variants alternating (the order rotates each round).
Variants (:mod:`benchmarks.point_elimination`): ``amd`` (today's path: CHOLMOD, AMD of the variable
graph), ``points-first`` (CHOLMOD, every point eliminated first), ``schur`` (the explicit Schur
complement on the points) and, for comparison, no order imposed on the points but METIS's nested
dissection of the variable graph instead of AMD (``nesdis``; left out without pymetis). Reported per
variant: seconds to build its linear solver (the pattern's analysis, common to all, not counted), LM
seconds (median), in process seconds (read, start, the pattern's analysis, the solver built, LM; the
write, the same for all, left out), the summed factorise and solve phases, LM iterations and factorisations, the final
cost's relative difference from ``amd``'s, and the flops of one factorisation (CHOLMOD's supernodes;
``schur``: of ``S``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.point_elimination import PointsFirstCholmod, SchurComplementSolver, point_incidence

DATA = Path(__file__).resolve().parents[2] / "data-landmarks"
FILES = ("dlr.g2o", "victoriaPark-full.g2o.gz", "world-1000-dense-highnoise_default.g2o.gz", "world-2000-default.g2o.gz",
         "world-2000-full.g2o.gz", "world-2000-lownoise-default.g2o.gz", "world-2000-lownoise-full.g2o.gz")  # fmt: skip
VARIANTS = {"amd": None, "points-first": PointsFirstCholmod, "schur": SchurComplementSolver, "nesdis": "nesdis"}


def prepared(path: Path):
    """``(graph in the solver's gauge, start poses, start points)`` as :func:`optimize` makes them."""
    import posegraph
    from posegraph.init.landmarks import initialize_landmarks
    from posegraph.solve.file_start import start_poses
    from posegraph.solve.gauge import central_anchors

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tags posegraph does not read (g2o_frontend's feature lines)
        graph = posegraph.read_g2o(path)
    poses = start_poses(graph, "chordal")
    points, _ = initialize_landmarks(graph, poses)
    gauge = central_anchors(graph, poses)
    return (graph if gauge is None else gauge[0]), poses, points


def analyses(graph) -> dict:
    """Per variant ``(analysis, seconds to build its linear solver)``: today's :func:`analyze`, its
    solver replaced (the pattern's analysis, common to all, is not counted; no order remembered)."""
    from posegraph.linalg import cholmod as cholmod_library
    from posegraph.solve.linear import CholmodSolver
    from posegraph.solve.optimizer import analyze

    analysis = analyze(graph)
    out = {}
    for name, solver in VARIANTS.items():  # (the first, amd, is what analyze built: its pattern's time is left)
        if solver == "nesdis" and not cholmod_library.nested_dissection_available():
            continue
        cholmod_library._LAST_ORDERS.clear()
        start = time.perf_counter()
        if solver is None or isinstance(solver, str):
            made = CholmodSolver(analysis.pattern, solver or "amd")
        else:
            made = solver(analysis.pattern)
        out[name] = (replace(analysis, solver=made), time.perf_counter() - start)
    out["pattern_s"] = analysis.seconds - out["amd"][1]
    return out


def point_statistics(pattern) -> dict:
    """How the points sit in the graph and in AMD's order: poses seeing each point (median, largest),
    pose pairs the Schur complement couples through points (``Σ k(k−1)/2``), and the share of points among
    the first half of the variables AMD eliminates (their share of all variables, ``Q/p``, if AMD were
    blind to them; ``min(1, 2Q/p)`` if it eliminated them first)."""
    from posegraph.linalg import cholmod as cholmod_library

    _, point = point_incidence(pattern)
    seen = np.bincount(point, minlength=pattern.num_variables - pattern.num_pose_variables)
    order = cholmod_library.fill_reducing_order(pattern.block_indptr, pattern.block_indices, pattern.num_variables, "amd")
    half = order[: order.size // 2]
    return {
        "points": int(seen.size), "poses": int(pattern.num_pose_variables),
        "seen_median": float(np.median(seen)), "seen_max": int(seen.max(initial=0)),
        "pose_pairs": int((seen * (seen - 1) // 2).sum()),
        "points_in_amd_first_half": float(np.mean(half >= pattern.num_pose_variables)) if half.size else 0.0,
    }


def factor_flops(solver) -> float | None:
    """Flops of the solver's last CHOLMOD factorisation (``schur``: of ``S``)."""
    return solver._cholesky.factor_flops


def measure(path: Path, rounds: int) -> dict:
    """The figures of one file (module docstring)."""
    from posegraph.solve.optimizer import optimize

    prepared(path)  # discarded: the imports and the page cache, not the file's work
    start = time.perf_counter()
    graph, poses, points = prepared(path)
    common = time.perf_counter() - start  # read, start (and the gauge)
    made = analyses(graph)
    pattern_seconds = made.pop("pattern_s")
    names = list(made)
    runs = {name: [] for name in names}
    for number in range(rounds):
        for name in names[number % len(names):] + names[: number % len(names)]:
            result = optimize(graph, poses, analysis=made[name][0], initial_points=points)
            runs[name].append(result)
    reference = runs["amd"][0].final_cost
    rows = {}
    for name, results in runs.items():
        last = results[-1]
        rows[name] = {
            "solver_build_s": made[name][1],
            "lm_s": statistics.median(r.seconds_total for r in results),
            "in_process_s": common + pattern_seconds + made[name][1] + statistics.median(r.seconds_total for r in results),
            "factorize_s": statistics.median(sum(x.seconds_factorize for x in r.records) for r in results),
            "solve_s": statistics.median(sum(x.seconds_solve for x in r.records) for r in results),
            "iterations": last.iterations,
            "factorisations": sum(x.attempts for x in last.records),
            "cost_relative": abs(last.final_cost - reference) / abs(reference),
            "mflop": factor_flops(made[name][0].solver) / 1e6,
        }
    return {"variants": rows, "points": point_statistics(made["amd"][0].pattern)}


def table(figures: dict) -> str:
    """A markdown table of :func:`measure`'s figures, one row per file and variant."""
    lines = ["| file | variant | solver built s | LM s | in process s | factorise s | solve s | iterations (factorisations) | cost vs amd | Mflop / factorisation |",
             "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for file, entry in figures.items():
        for name, row in entry["variants"].items():
            lines.append(
                f"| {file} | {name} | {row['solver_build_s']:.3f} | {row['lm_s']:.3f} | {row['in_process_s']:.3f} | {row['factorize_s']:.3f} | "
                f"{row['solve_s']:.3f} | {row['iterations']} ({row['factorisations']}) | {row['cost_relative']:.1e} | {row['mflop']:.1f} |"
            )  # fmt: skip
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--files", nargs="*", default=list(FILES))
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    args = parser.parse_args(argv)
    figures = {}
    for name in args.files:
        path = args.data / name
        if not path.is_file():
            print(f"{name}: absent ({path}), skipped")
            continue
        figures[name] = measure(path, args.rounds)
        print(table({name: figures[name]}), "\n", figures[name]["points"], flush=True)
    print(table(figures))
    if args.out is not None:
        args.out.write_text(json.dumps(figures, indent=1) + "\n")


if __name__ == "__main__":
    main()
