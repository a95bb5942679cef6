"""``posegraph compare``: this project's optimiser and gtsam's on one graph, side by side."""

from __future__ import annotations

from posegraph.cli.common import (
    reader_options,
    EXIT_NOT_CONVERGED, EXIT_OK, STDIO, Status, Timer, check_output, display_name, fmt_cost, non_negative_float,
    read_graph, repair_option,
)
from posegraph.cli.solving import check_linear_solver, initial_poses, iteration_printer, solver_options, solver_params

COMPARE_COST_TOLERANCE = 1e-6
"""Default for ``compare --cost-tolerance``: relative difference of the final costs, against
max(1, |gtsam's final cost|). With the solver's default tolerances both optimisers stop within
~1e-9 relative of the same optimum on the standard datasets; 1e-6 leaves room for gtsam stopping
one iteration earlier without hiding a different local minimum."""

NAME = "compare"
HELP = "optimise with posegraph and gtsam, side by side"
DESCRIPTION = (
    "Run this project's optimiser and gtsam's (same start, same method and tolerances) on one "
    "graph in one process, and print start and final costs, iterations, seconds per phase and the "
    "largest rotation and translation difference between the two solutions. Exit status 0 when "
    f"the final costs agree within --cost-tolerance (relative, default {COMPARE_COST_TOLERANCE:g}), "
    "1 otherwise. Needs gtsam (pip install \"posegraph[gtsam]\")."
)
EXAMPLES = """
  posegraph compare tinyGrid3D.g2o
  posegraph compare sphere2500.g2o --method gn --report compare.json
  posegraph compare garage.g2o --init chordal --gtsam-start own    (gtsam's own InitializePose3)
  posegraph compare intel.g2o --gtsam-start own                      (2D: Pose2 factors, gtsam's LAGO)"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="input pose graph (- for standard input)")
    repair_option(p)
    solver_options(p)
    p.add_argument("--gtsam-start", choices=("same", "own"), default="same",
                   help="start gtsam from posegraph's initial poses (default), or let it start on its own: "
                        "InitializePose3 (LAGO for a 2D graph) for --init chordal, the file's poses for --init file (gtsam has no "
                        "odometry initialiser: --init odometry always shares the start)")
    p.add_argument("--cost-tolerance", type=non_negative_float, default=COMPARE_COST_TOLERANCE, metavar="TOL",
                   help="largest relative difference of the final costs counted as agreement")
    p.add_argument("--report", metavar="REPORT.json", help="write the comparison as JSON")


def run(args) -> int:
    from posegraph.crosscheck.gtsam_bridge import require_gtsam

    require_gtsam()
    if args.report:
        check_output(args.report, inputs=[args.input], what="report")
    from posegraph.cli.startup import import_solver_modules
    from posegraph.solve.residuals import cost

    status = Status(args.quiet)
    import_solver_modules()
    ours = _run_ours(args, status)
    theirs, gtsam_init = _run_gtsam(args, status, ours)
    comparison = _compare(ours["result"].poses, theirs.poses, ours["result"].final_cost, theirs.final_cost)
    agree = comparison["final_cost_relative_difference"] <= args.cost_tolerance
    ours["start_cost"] = float(cost(ours["graph"], ours["start"]))
    _print_table(args, ours, theirs, gtsam_init, comparison, agree)
    if args.report:
        _write_report(args, ours, theirs, gtsam_init, comparison, agree)
    return EXIT_OK if agree else EXIT_NOT_CONVERGED


def _run_ours(args, status: Status) -> dict:
    """Read, initialise and optimise: the graph, start, parameters, result and seconds per phase."""
    from posegraph.solve import optimize

    graph, seconds_read = read_graph(args.input, status, repair_information=args.repair_information,
                                     uses_file_poses=args.init == "file", **reader_options(args))
    check_linear_solver(graph, args.linear_solver, args.input)
    if graph.group.residual_log is not None:  # g2o's Sim(3) error: compare on gtsam's, the exact log's
        from dataclasses import replace

        graph = replace(graph, group=replace(graph.group, residual_log=None))
        status("Sim(3): both sides minimise the exact log's cost (gtsam's), not g2o's first-order EdgeSim3 error")
    with Timer() as t_init:
        start = initial_poses(graph, args)
    params = solver_params(args, callback=None if args.quiet else iteration_printer(status, args.max_iterations))
    status(f"posegraph: {params.method}, start {args.init}")
    with Timer() as t_opt:
        result = optimize(graph, initial=start, params=params)
    seconds = {"read": seconds_read, "initialise": t_init.seconds, "optimise": t_opt.seconds}
    return {"graph": graph, "start": start, "params": params, "result": result, "seconds": seconds}


def _run_gtsam(args, status: Status, ours: dict):
    """gtsam's run (:func:`posegraph.crosscheck.gtsam_bridge.run_gtsam`) and how it started: "given" or ``--init``."""
    from posegraph.crosscheck.gtsam_bridge import run_gtsam

    params, graph = ours["params"], ours["graph"]
    if graph.landmarks is not None:
        return _run_gtsam_landmarks(status, ours), "given"
    if args.gtsam_start == "same" or args.init == "odometry":
        gtsam_init, gtsam_initial = "given", ours["start"]
    else:
        gtsam_init, gtsam_initial = args.init, None
    status(f"gtsam: {params.method}, start {'same as posegraph' if gtsam_init == 'given' else args.init}")
    # With repaired information (or a graph from standard input) gtsam gets our model, not the file.
    theirs = run_gtsam(
        graph if args.repair_information or args.input == STDIO else args.input,
        graph=graph, init=gtsam_init, initial=gtsam_initial,
        method=params.method,
        max_iterations=params.max_iterations, relative_tolerance=params.relative_tolerance,
        absolute_tolerance=params.absolute_tolerance,
    )
    return theirs, gtsam_init


def _run_gtsam_landmarks(status: Status, ours: dict):
    """gtsam on a landmark graph (:func:`posegraph.crosscheck.gtsam_landmarks.run_gtsam_landmarks`: its
    ``BearingRangeFactor2D``, ``BearingFactor2D``, ``PriorFactorPoint2/3`` and a ``CustomFactor`` for
    positions), always from posegraph's start (the poses and the landmarks they give)."""
    from posegraph.crosscheck.gtsam_landmarks import python_factor_note, run_gtsam_landmarks
    from posegraph.init.landmarks import initialize_landmarks

    params, graph = ours["params"], ours["graph"]
    status(f"gtsam: {params.method}, start same as posegraph (landmark graphs: gtsam has no initialiser for them)")
    status(python_factor_note(graph) or "gtsam: every landmark measurement as gtsam's own factor")
    return run_gtsam_landmarks(
        graph, ours["start"], initialize_landmarks(graph, ours["start"])[0], method=params.method,
        max_iterations=params.max_iterations, relative_tolerance=params.relative_tolerance,
        absolute_tolerance=params.absolute_tolerance,
    )


def _compare(our_poses, their_poses, our_cost: float, their_cost: float) -> dict:
    """Largest rotation (degrees) and translation differences of two ``(n, k, k)`` solutions (SE(3) or
    SE(2)), and ``|our_cost − their_cost| / max(1, |their_cost|)``."""
    import numpy as np

    from posegraph.analysis.evaluate import rotation_angle

    r = our_poses.shape[-1] - 1
    rot = np.degrees(rotation_angle(np.swapaxes(our_poses[:, :r, :r], -1, -2) @ their_poses[:, :r, :r]))
    trans = np.linalg.norm(our_poses[:, :r, r] - their_poses[:, :r, r], axis=-1)
    return {
        "final_cost_relative_difference": abs(our_cost - their_cost) / max(1.0, abs(their_cost)),
        "max_rotation_difference_deg": float(rot.max()) if rot.size else 0.0,
        "max_translation_difference": float(trans.max()) if trans.size else 0.0,
    }


def _phases(args, ours: dict, theirs, gtsam_init: str) -> dict:
    """Seconds per phase, labelled by what each tool did: ``{label: (ours, theirs)}``, None where a
    tool had no such phase. Reading a file and converting posegraph's graph, initialising and
    converting posegraph's start are different work, so they are different rows."""
    seconds = ours["seconds"]
    gtsam_built = args.repair_information or args.input == STDIO  # gtsam got our graph, not the file
    gtsam_given = gtsam_init == "given"  # gtsam got our start, converted to Values
    phases = {
        "seconds read file": (seconds["read"], None if gtsam_built else theirs.seconds_read),
        "seconds convert graph": (None, theirs.seconds_read if gtsam_built else None),
        f"seconds initialise ({args.init})": (
            seconds["initialise"], None if gtsam_given else theirs.seconds_initialise),
        "seconds convert start": (None, theirs.seconds_initialise if gtsam_given else None),
        "seconds optimise": (seconds["optimise"], theirs.seconds_optimise),
    }
    phases = {k: v for k, v in phases.items() if v != (None, None)}
    phases["seconds total"] = tuple(sum(v[side] or 0.0 for v in phases.values()) for side in (0, 1))
    return phases


def _rows(args, ours: dict, theirs, gtsam_init: str) -> tuple[dict, dict]:
    """The table's two columns, as text ("–" where a tool had no such phase)."""
    result = ours["result"]
    ours_row = {"start cost": fmt_cost(ours["start_cost"]), "final cost": fmt_cost(result.final_cost),
                "iterations": str(result.iterations), "converged": "yes" if result.converged else "no"}
    theirs_row = {"start cost": fmt_cost(theirs.initial_cost), "final cost": fmt_cost(theirs.final_cost),
                  "iterations": str(theirs.iterations), "converged": "yes" if theirs.converged else "no"}
    for label, (mine, other) in _phases(args, ours, theirs, gtsam_init).items():
        ours_row[label] = "–" if mine is None else f"{mine:.4f}"
        theirs_row[label] = "–" if other is None else f"{other:.4f}"
    return ours_row, theirs_row


def _print_table(args, ours: dict, theirs, gtsam_init: str, comparison: dict, agree: bool) -> None:
    ours_row, theirs_row = _rows(args, ours, theirs, gtsam_init)
    graph, method = ours["graph"], ours["params"].method
    header = ("", "posegraph", f"gtsam {theirs.version}".strip())
    width = max(len(k) for k in ours_row) + 2
    col = max(14, *(len(v) for v in ours_row.values())) + 2
    print(f"{display_name(args.input)}: {graph.num_vertices} vertices, {graph.num_edges} edges; {method.upper()}, "
          f"start {args.init}" + (" (gtsam from the same poses)" if gtsam_init == "given" else " (each its own)"))
    print(f"{header[0]:<{width}}{header[1]:<{col}}{header[2]}")
    for key in ours_row:
        print(f"{key:<{width}}{ours_row[key]:<{col}}{theirs_row[key]}")
    print(f"final cost relative difference: {comparison['final_cost_relative_difference']:.3e} "
          f"(tolerance {args.cost_tolerance:g}): " + ("agree" if agree else "DISAGREE"))
    if not agree and graph.group.name == "SIM3" and ours["result"].final_cost < theirs.final_cost:
        print("  (Sim(3): gtsam's BetweenFactorSimilarity3 uses an identity Logmap derivative, so its LM stops "
              "above the optimum it shares with posegraph; docs/sim3.md)")
    print(f"largest rotation difference:    {comparison['max_rotation_difference_deg']:.3e} deg")
    print(f"largest translation difference: {comparison['max_translation_difference']:.3e}")


def _write_report(args, ours: dict, theirs, gtsam_init: str, comparison: dict, agree: bool) -> None:
    from posegraph.io.atomic import write_json_atomic

    params, result = ours["params"], ours["result"]
    phases = _phases(args, ours, theirs, gtsam_init)
    seconds = [{_phase_key(k): v[side] for k, v in phases.items() if v[side] is not None} for side in (0, 1)]
    write_json_atomic(args.report, {
        "input": display_name(args.input), "method": params.method, "init": args.init, "gtsam_start": gtsam_init,
        "relative_tolerance": params.relative_tolerance, "absolute_tolerance": params.absolute_tolerance,
        "max_iterations": params.max_iterations,
        "posegraph": {"start_cost": ours["start_cost"], "final_cost": result.final_cost,
                      "iterations": result.iterations, "converged": result.converged,
                      "termination": result.termination, "linear_solver": result.linear_solver,
                      "seconds": seconds[0]},
        "gtsam": {"version": theirs.version, "start_cost": theirs.initial_cost, "final_cost": theirs.final_cost,
                  "iterations": theirs.iterations, "converged": theirs.converged, "seconds": seconds[1]},
        "final_cost_relative_difference": comparison["final_cost_relative_difference"],
        "cost_tolerance": args.cost_tolerance, "agree": agree,
        "max_rotation_difference_deg": comparison["max_rotation_difference_deg"],
        "max_translation_difference": comparison["max_translation_difference"],
    })


def _phase_key(label: str) -> str:
    """``"seconds initialise (chordal)"`` → ``"initialise"``: the report's key of a phase row."""
    return label.removeprefix("seconds ").split(" (")[0].replace(" ", "_")
