"""Figures of docs/solver.md, "Ill-conditioned graphs": GN and LM on the synthetic hard graphs.

    python -m tests.solve.ill_conditioned_table            # default parameters (line search on)
    python -m tests.solve.ill_conditioned_table --plain    # line_search=False: gtsam's step rules

Prints one markdown row per graph and start: the optimum (gtsam LM at tolerance 1e-14 started from
our LM solution, edges' cost only; our LM's cost without gtsam) and, for LM and GN, the final cost's
relative gap to it, or the termination reason and cost when the run did not converge, and the
iterations. A few seconds; not a test (the assertions are in test_ill_conditioned.py).
"""

from __future__ import annotations

import sys

from posegraph.init import chordal_initialization
from posegraph.solve import SolverParams, optimize
from tests.init import synthetic

GRAPHS = [
    ("hard 21", lambda: synthetic.hard_graph(21)),
    ("hard 22", lambda: synthetic.hard_graph(22)),
    ("hard 23", lambda: synthetic.hard_graph(23)),
    ("hard 24", lambda: synthetic.hard_graph(24)),
    ("roll-blind 31", lambda: synthetic.roll_blind_odometry_graph(31)),
    ("roll-blind 32", lambda: synthetic.roll_blind_odometry_graph(32)),
]


def gtsam_optimum(graph, start):
    """gtsam LM from ``start`` at tolerance 1e-14, or None without gtsam."""
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return None
    from posegraph.crosscheck.gtsam_bridge import gtsam_reference_cost

    return gtsam_reference_cost(graph, start, max_iterations=300)


def cell(result, optimum):
    if result.converged:
        return f"{(result.final_cost - optimum) / optimum:+.1e}, {result.iterations} it"
    return f"{result.termination}, {result.iterations} it ({result.final_cost:.6g})"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra = {"line_search": False} if "--plain" in argv else {}
    print("| graph | optimum | start | LM | GN |")
    print("|---|---:|---|---|---|")
    for name, build in GRAPHS:
        graph, truth = build()
        starts = {"chordal": chordal_initialization(graph), "truth": synthetic.expected_poses(graph, truth)}
        runs = {
            (start, method): optimize(
                graph, initial=poses, params=SolverParams(method=method, max_iterations=300, **extra)
            )
            for start, poses in starts.items()
            for method in ("lm", "gn")
        }
        reference = optimize(graph, initial=starts["chordal"], params=SolverParams(max_iterations=300))
        optimum = gtsam_optimum(graph, reference.poses) or reference.final_cost
        for k, start in enumerate(starts):
            label = f"{name} | {optimum:.10g}" if k == 0 else " | "
            print(f"| {label} | {start} | {cell(runs[start, 'lm'], optimum)} | {cell(runs[start, 'gn'], optimum)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
