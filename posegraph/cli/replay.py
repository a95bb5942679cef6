"""``posegraph replay``: a g2o file fed to the incremental optimiser as a SLAM front end would feed it."""

from __future__ import annotations

import os
import sys

from posegraph.cli.common import (
    EXIT_NOT_CONVERGED, EXIT_OK, STDIO, Status, Timer, UsageError, check_distinct, check_figure, check_output,
    display_name, fmt_cost, positive_int, print_all, read_graph, repair_option, stage_or_print,
)
from posegraph.cli.rerun_output import check_rerun_options, open_recording, replay_recorder, rerun_options

NAME = "replay"
HELP = "replay a g2o file pose by pose through the incremental optimiser"
DESCRIPTION = (
    "Feed the vertices of a g2o file in id order to the incremental optimiser (docs/incremental.md), each "
    "with every edge to a vertex already in (and its priors, FIX), K new vertices per update; print a "
    "progress line, the per-update time statistics (mean, median, p99, max) and the final cost against a "
    "batch solve of the same graph. Options that apply: --robust LOSS (every solve, the incremental ones "
    "too), --linear-solver and --method (the solves handed to the batch solver: drastic or failed updates, the final "
    "comparison). Exit status 1 when the final cost exceeds the batch optimum by more than max(1e-6, --tolerance) relative."
)
EXAMPLES = """
  posegraph replay intel.g2o
  posegraph replay manhattan.g2o --batch-size 10 --report replay.json --plot replay.png -o manhattan-opt.g2o
  posegraph replay garage.g2o --tolerance 1e-3 --check-every 100      (speed setting, excess measured every 100 poses)"""

ROBUST_LOSSES = ("none", "huber", "cauchy", "geman-mcclure", "tukey", "dcs")


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="input pose graph")
    p.add_argument("-o", "--output", metavar="OUT.g2o", help="write the final estimate (as optimize writes; - for stdout)")
    p.add_argument("--batch-size", type=positive_int, default=1, metavar="K", help="new vertices per update (default 1)")
    p.add_argument("--report", metavar="R.json", help="optimize's report fields for the final estimate, plus the "
                   "per-update statistics (- for standard output)")
    p.add_argument("--plot", metavar="F.png", help="update time and cost excess against the number of poses (matplotlib)")
    # the default is the optimiser's (posegraph.incremental.optimizer.DEFAULT_TOLERANCE, equal to this
    # text: tests/cli); not imported here, since help must come without numpy
    p.add_argument("--tolerance", type=float, default=None, metavar="TOL",
                   help="relative cost excess bounded after each update (default 1e-7; 1e-3 trades accuracy for speed)")
    p.add_argument("--verify", action="store_true", help="check every update with a warm batch solve (exact, slow)")
    p.add_argument("--check-every", type=positive_int, default=None, metavar="N",
                   help="compare with a batch solve of the prefix every N poses (for the plot and report)")
    p.add_argument("--method", choices=("lm", "gn"), default="lm", help="method of the batch solves (default lm)")
    p.add_argument("--linear-solver", choices=("auto", "cholmod", "scipy", "pcg"), default="auto",
                   help="sparse solver of the batch solves")
    p.add_argument("--robust", choices=ROBUST_LOSSES, default="none", help="robust loss on every edge (no gnc here)")
    p.add_argument("--robust-scale", type=float, default=None, metavar="C", help="the loss's scale")
    repair_option(p)
    rerun_options(p)


def _check(args) -> None:
    if args.tolerance is not None and not args.tolerance > 0:
        raise UsageError("--tolerance must be positive")
    if args.output:
        check_output(args.output, inputs=[args.input], what="result", stdout=True)
    if args.report:
        check_output(args.report, inputs=[args.input], what="report", stdout=True)
    if args.plot:
        check_figure(args.plot, inputs=[args.input])
    if args.output == STDIO and args.report == STDIO:
        raise UsageError("the result and the report cannot both go to standard output (-)")
    check_rerun_options(args)
    check_distinct([p for p in (args.output, args.report, args.plot, args.rerun) if p and p != STDIO])


def _optimizer(args, graph):
    from posegraph.incremental import IncrementalOptimizer
    from posegraph.solve import SolverParams

    loss = None
    if args.robust != "none":
        from posegraph.robust import make_loss

        loss = make_loss(args.robust.replace("-", "_"), args.robust_scale, dimension=graph.group.dim)
    params = SolverParams(method=args.method, linear_solver=args.linear_solver, loss=loss)
    tolerance = {} if args.tolerance is None else {"tolerance": args.tolerance}
    return IncrementalOptimizer(graph.group, **tolerance, params=params, verify=args.verify), params


def _progress(status: Status, total: int):
    step = max(total // 20, 1)

    def show(result, number) -> None:
        poses = int(result.poses_after[-1])
        if poses % step == 0 or poses == total:
            seconds = result.seconds
            status(f"replay: {poses}/{total} poses, {number} updates, {seconds.sum():.2f} s, "
                   f"last {1e3 * seconds[-1]:.2f} ms, cost {fmt_cost(result.optimizer.cost())}")
    return show


def run(args) -> int:
    _check(args)
    with open_recording(args, "posegraph replay") as recording:
        return _run(args, recording)


def _run(args, recording) -> int:
    from posegraph.cli.startup import import_solver_modules

    status = Status(args.quiet)
    import_solver_modules()
    from posegraph.cli.solving import check_linear_solver
    from posegraph.incremental.replay import cost_excess, replay, time_statistics

    graph, seconds_read = read_graph(args.input, status, repair_information=args.repair_information,
                                     uses_file_poses=False)  # each vertex is placed by its first edge
    check_linear_solver(graph, args.linear_solver, args.input)
    opt, params = _optimizer(args, graph)
    recorder = replay_recorder(recording, graph, args.batch_size)
    with Timer() as t:
        result = replay(graph, args.batch_size, optimizer=opt, check_every=args.check_every,
                        progress=_chain(None if args.quiet else _progress(status, graph.num_vertices), recorder))
    stats = time_statistics(result.seconds)
    with Timer() as t_batch:
        poses, ours, best, excess = result.checks[-1] if result.checks else cost_excess(opt)
    seconds = {"read": seconds_read, "replay": t.seconds, "batch_check": t_batch.seconds}
    if not args.quiet:
        ms = {k: 1e3 * stats[k] for k in ("mean", "median", "p99", "max")}
        print(f"{stats['updates']} updates in {stats['total']:.3f} s: per update mean {ms['mean']:.3f} ms, "
              f"median {ms['median']:.3f} ms, p99 {ms['p99']:.3f} ms, max {ms['max']:.3f} ms",
              file=sys.stdout if args.output != STDIO else sys.stderr)
        print(f"final cost {fmt_cost(ours)}, batch solve {fmt_cost(best)}: excess {excess:.3g} relative",
              file=sys.stdout if args.output != STDIO else sys.stderr)
    if recorder is not None:
        recorder.finish(result, (ours, best, excess), stats, title=f"posegraph replay {os.path.basename(display_name(args.input))}")
    _write(args, status, graph, opt, params, result, stats, (ours, best, excess), seconds, recording)
    drawn = _draw(args, status, result) if args.plot else True
    return EXIT_OK if excess <= max(1e-6, opt.tolerance) and drawn else EXIT_NOT_CONVERGED


def _final_result(opt, ours: float):
    """The final estimate as an :class:`~posegraph.solve.result.OptimizeResult` (for optimize's report)."""
    from posegraph.solve.result import OptimizeResult

    return OptimizeResult(poses=opt.poses, initial_cost=ours, final_cost=ours, iterations=0,
                          termination="converged: incremental", converged=True, linear_solver="incremental",
                          method="incremental")


def _chain(*hooks):
    """One progress hook calling each of ``hooks`` that is not None (None if none is)."""
    hooks = [h for h in hooks if h is not None]
    if len(hooks) < 2:
        return hooks[0] if hooks else None
    return lambda result, number: [hook(result, number) for hook in hooks] and None


def _write(args, status, graph, opt, params, result, stats, costs, seconds, recording=None) -> None:
    """``-o`` and ``--report``, staged and renamed into place together (as optimize does)."""
    from posegraph.io.atomic import StagedOutputs, json_text
    from posegraph.io.g2o import format_g2o, write_g2o
    from posegraph.solve.residuals import cost

    ours, best, excess = costs
    final = _final_result(opt, ours)
    file_cost = float(cost(graph)) if args.report else float("nan")  # at the file's poses and landmarks
    graph = _estimated_graph(graph, opt)
    printed = []
    with StagedOutputs() as outputs:
        if args.output == STDIO:
            printed.append(format_g2o(graph, _in_file_order(graph, opt)))
        elif args.output:
            with outputs.writing(args.output) as tmp:
                write_g2o(tmp, graph, _in_file_order(graph, opt))
        if args.report:
            report = _report(args, graph, opt, params, result, stats, costs, seconds, final, file_cost)
            stage_or_print(outputs, args.report, json_text(report), printed)
        if recording is not None:
            recording.stage_into(outputs)
        outputs.commit()
    print_all(printed)


def _in_file_order(graph, opt):
    """The estimate in the file's vertex order (the optimiser holds them in id order)."""
    index = {v: k for k, v in enumerate(opt.ids.tolist())}
    return opt.poses[[index[v] for v in graph.ids.tolist()]]


def _estimated_graph(graph, opt):
    """``graph`` with its landmarks where the optimiser left them (file order); a pose graph as it is."""
    if graph.landmarks is None:
        return graph
    index = {v: k for k, v in enumerate(opt.landmark_ids.tolist())}
    return graph.with_points(opt.landmark_positions[[index[v] for v in graph.landmarks.ids.tolist()]])


def _report(args, graph, opt, params, result, stats, costs, seconds, final, file_cost: float) -> dict:
    from posegraph.analysis.report import optimize_report

    from dataclasses import replace

    points = None if graph.landmarks is None else graph.landmarks.positions
    final = replace(final, poses=_in_file_order(graph, opt), points=points)
    report = optimize_report(display_name(args.input), args.output or "", graph, final, init="incremental",
                             file_cost=file_cost, seconds=seconds, params=params)
    ours, best, excess = costs
    report["incremental"] = {
        "batch_size": args.batch_size, "tolerance": opt.tolerance, "verify": args.verify,
        "update_seconds": stats, "batch_cost": best, "relative_excess": excess,
        "checks": [{"poses": c[0], "cost": c[1], "batch_cost": c[2], "relative_excess": c[3]} for c in result.checks],
        "kinds": {k: result.kinds.count(k) for k in sorted(set(result.kinds))},
    }
    return report


def _draw(args, status, result) -> bool:
    try:
        from posegraph.incremental.figure import replay_figure

        replay_figure(args.plot, result)
        return True
    except ImportError as exc:
        status(f"warning: no figure drawn ({exc})")
        return False
