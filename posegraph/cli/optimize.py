"""``posegraph optimize``: read, initialise, optimise, then write the result, report and figure together."""

from __future__ import annotations

import os

import numpy as np

from posegraph.cli.common import (
    EXIT_NOT_CONVERGED, EXIT_OK, Status, Ticker, Timer, check_distinct, check_output, fmt_cost, read_graph,
    repair_option, require_matplotlib, warn,
)
from posegraph.cli.robust import OUTLIER_WEIGHT, check_robust_options, final_weights, output_graph, outlier_line, robust_options, run_gnc
from posegraph.cli.solving import initial_poses, iteration_printer, solver_options, solver_params

NAME = "optimize"
HELP = "optimise a g2o pose graph and write the result"
DESCRIPTION = (
    "Optimise the vertex poses of a g2o file and write a g2o file with the same edges and FIX lines "
    "and the optimised vertices. Progress (one line per iteration: cost, decrease, LM lambda, "
    "seconds) goes to stderr; a summary to stdout. Exit status 1 (result still written) when the "
    "iteration cap ends the run before convergence."
)
EXAMPLES = """
  posegraph optimize tinyGrid3D.g2o -o tiny-opt.g2o
  posegraph optimize sphere2500.g2o -o out.g2o --report report.json --plot before-after.png
  posegraph optimize garage.g2o -o out.g2o --method gn --init odometry --max-iterations 20 --quiet
  posegraph optimize in.g2o -o in.g2o --force      (overwrite the input, atomically)
  posegraph optimize noisy.g2o -o out.g2o --robust gnc --drop-outliers --report report.json
  posegraph optimize in.g2o -o out.g2o --robust cauchy --robust-scale 3"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="input pose graph")
    p.add_argument("-o", "--output", metavar="OUT.g2o", required=True, help="output pose graph")
    repair_option(p)
    solver_options(p)
    robust_options(p)
    p.add_argument("--report", metavar="REPORT.json", help="write costs, iterations, timings and per-iteration "
                   "records as JSON")
    p.add_argument("--plot", metavar="FIG.png", help="draw the input and optimised trajectories (needs matplotlib)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but warnings and errors")
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")


def run(args) -> int:
    from posegraph.cli.startup import import_solver_modules

    status = Status(args.quiet)
    _check_outputs(args)
    import_solver_modules()  # first: it imports scipy.sparse its own way
    from posegraph.solve import optimize

    graph, start, file_cost, start_cost, seconds = _start(args, status)
    params = solver_params(args, callback=None if args.quiet else iteration_printer(status))
    robust = None
    with Timer() as t_opt:
        if args.robust == "gnc":
            robust = run_gnc(graph, start, solver_params(args), args, status)
            result = robust.result
        else:
            result = optimize(graph, initial=start, params=params)
    if start_cost is None:
        start_cost = result.initial_cost
    status(f"{result.method}: {result.termination} after {result.iterations} iterations ({t_opt.seconds:.3f} s)")
    seconds["optimise"] = t_opt.seconds
    weights = final_weights(graph, args, result, robust)
    _write_outputs(args, status, graph, result, params, file_cost, start_cost, seconds, weights)
    if not args.quiet:
        _print_summary(args, graph, result, file_cost, seconds)
        if weights is not None:
            print(outlier_line(graph, weights))
    if result.converged:
        return EXIT_OK
    warn(f"the solver stopped before converging ({result.termination}, {result.iterations} iterations); "
         f"the result was written to {args.output} anyway")
    return EXIT_NOT_CONVERGED


def _check_outputs(args) -> None:
    """Every output writable, none the input (unless ``--force``), no two the same; before any work."""
    check_robust_options(args)
    check_output(args.output, inputs=[args.input], allow_input=args.force, what="result")
    if args.report:
        check_output(args.report, inputs=[args.input], what="report")
    if args.plot:
        check_output(args.plot, inputs=[args.input], what="figure")
        require_matplotlib()
    check_distinct([args.output, args.report, args.plot])


def _start(args, status: Status):
    """Read and initialise: ``(graph, start poses, file cost, start cost or None, seconds per phase)``.

    The cost at the file's poses is printed and reported; with ``--quiet`` and no report nothing
    shows it, and it is NaN. With ``--quiet`` the start cost is None: the solver's own first
    evaluation (``result.initial_cost``) supplies it.
    """
    from posegraph.solve.residuals import cost

    graph, seconds_read = read_graph(args.input, status, repair_information=args.repair_information)
    file_cost = float(cost(graph)) if (not args.quiet or args.report) else float("nan")
    with Ticker(status, f"initialising ({args.init})"), Timer() as t_init:
        start = initial_poses(graph, args)
    start_cost = None
    if not args.quiet and start is not None:  # None: GNC's robust start, made by the optimiser
        start_cost = float(cost(graph, start)) if args.init != "file" else file_cost
        status(f"initialised ({args.init}): cost {fmt_cost(file_cost)} -> {fmt_cost(start_cost)} "
               f"({t_init.seconds:.3f} s)")
    return graph, start, file_cost, start_cost, {"read": seconds_read, "initialise": t_init.seconds}


def _write_outputs(args, status: Status, graph, result, params, file_cost, start_cost, seconds, weights=None) -> None:
    """The result, and the figure and report if asked, staged and renamed into place together."""
    from posegraph.atomic import StagedOutputs
    from posegraph.io.g2o import write_g2o

    with StagedOutputs() as outputs:
        with Ticker(status, f"writing {args.output}"), Timer() as t_write:
            write_g2o(outputs.stage(args.output), output_graph(graph, weights, args), result.poses)
        seconds["write"] = t_write.seconds
        if args.plot:
            from posegraph.plot import plot_trajectories

            with Ticker(status, f"drawing {args.plot}"), Timer() as t_plot:
                plot_trajectories(
                    outputs.stage(args.plot), [graph, graph],
                    [f"input ({os.path.basename(args.input)})", "optimised"],
                    [graph.poses, result.poses], title=os.path.basename(args.input),
                )
            seconds["plot"] = t_plot.seconds
        if args.report:
            from posegraph.atomic import write_json_atomic
            from posegraph.report import optimize_report

            report = optimize_report(
                args.input, args.output, graph, result, init=args.init, file_cost=file_cost,
                start_cost=start_cost, seconds=seconds, params=params,
            )
            if weights is not None:
                report["robust"] = args.robust
                report["outlier_edges"] = [int(k) for k in np.flatnonzero(weights < OUTLIER_WEIGHT)]
            write_json_atomic(outputs.stage(args.report), report)
        outputs.commit()


def _print_summary(args, graph, result, file_cost: float, seconds: dict) -> None:
    print(f"input:          {args.input} ({graph.num_vertices} vertices, {graph.num_edges} edges)")
    print(f"file cost:      {fmt_cost(file_cost)}")
    print(f"initial cost:   {fmt_cost(result.initial_cost)} (after {args.init} initialisation)")
    print(f"final cost:     {fmt_cost(result.final_cost)}")
    print(f"iterations:     {result.iterations}")
    print(f"termination:    {result.termination}")
    print(f"linear solver:  {result.linear_solver}")
    print("seconds:        " + ", ".join(f"{k} {v:.3f}" for k, v in seconds.items())
          + f", total {sum(seconds.values()):.3f}")
    print(f"output:         {args.output}" + "".join(f", {p}" for p in (args.report, args.plot) if p))
