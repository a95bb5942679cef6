"""``posegraph optimize``: read, initialise, optimise, then write the result, report and figure together."""

from __future__ import annotations

import os

import sys

from posegraph.cli.common import (
    reader_options,
    EXIT_NOT_CONVERGED, EXIT_OK, LARGE_GRAPH_POSES, STDIO, Status, Ticker, Timer, UsageError,
    check_distinct, check_figure, check_output, display_name, fmt_cost, graph_size, non_negative_int, read_graph, repair_option,
    interrupted_status, quiet_option, warn,
)
from posegraph.cli.robust import (
    check_robust_options, final_landmark_weights, final_prior_weights, final_weights, known_inlier_facts, output_graph, robust_options, robust_report,
    robust_summary, run_gnc, warn_about_known_inliers,
)
from posegraph.cli.rerun_output import (
    check_rerun_options, open_recording, optimize_recorder, record_optimize_result, rerun_options, with_recorder,
)
from posegraph.cli.solving import initial_poses, iteration_printer, solver_options, solver_params, stop_reason

NAME = "optimize"
HELP = "optimise a g2o pose graph and write the result"
DESCRIPTION = (
    "Optimise the vertex poses of a g2o file and write a g2o file with the same edges and FIX lines "
    "and the optimised vertices. Progress (one line per iteration: cost, decrease, LM lambda, "
    "seconds) goes to stderr; a summary to stdout: the cost (1/2 chi2, as gtsam's error), chi2 "
    "(as g2o prints it) and chi2/dof, with a warning naming the suspicious loop closures when the edges, "
    "judged against each other, say the map is broken (not after --robust; --no-map-check skips it), "
    "and one naming the worst edges when chi2/dof is far above 1. IN or OUT may be - (standard input / "
    "output). Exit status 1 (result still written) when the iteration cap ends the run before convergence or the figure could not be drawn."
)
EXAMPLES = """
  posegraph optimize tinyGrid3D.g2o -o tiny-opt.g2o
  posegraph optimize sphere2500.g2o -o out.g2o --report report.json --plot before-after.png
  posegraph optimize sphere2500.g2o -o out.g2o --covariances cov.npz   (then: posegraph plot out.g2o -o fig.png --covariances cov.npz)
  posegraph optimize garage.g2o -o out.g2o --method gn --init odometry --max-iterations 20 --quiet
  posegraph optimize -i 20 -o out.g2o in.g2o --fix 0 --stats     (g2o's habits: -i, fix by id)
  cat in.g2o | posegraph optimize - -o - --quiet > out.g2o
  posegraph optimize in.g2o -o in.g2o --force      (overwrite the input, atomically)
  posegraph optimize noisy.g2o -o out.g2o --robust gnc --drop-outliers --report report.json
  posegraph optimize in.g2o -o out.g2o --robust cauchy --robust-scale 3"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="input pose graph (- for standard input)")
    p.add_argument("-o", "--output", metavar="OUT.g2o", required=True,
                   help="output pose graph (- for standard output; the summary then goes to stderr)")
    file_options(p)
    p.add_argument("--report", metavar="REPORT.json", help="write costs, chi2, iterations, timings and "
                   "per-iteration records as JSON (- for standard output)")
    p.add_argument("--plot", metavar="FIG.png", help="draw the input and optimised trajectories (needs matplotlib); "
                   "drawn after OUT is written, a failure is a warning")
    p.add_argument("--covariances", metavar="COV.npz",
                   help="write each pose's marginal covariance at the result (numpy .npz: 'ids' (n,), 'covariances' "
                        "(n, d, d), d = 6 for SE(3) in gtsam's tangent order [rotation; translation] and body frame, "
                        "3 for SE(2) [x, y, θ]); FIX vertices and each component's anchor are held, so theirs are "
                        "zero and the others are relative to them; a landmark graph's file also holds 'landmark_ids' (L,) "
                        "and 'landmark_covariances' (L, s, s) of the points (world frame); written with OUT, or neither")
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")
    rerun_options(p)


def file_options(p) -> None:
    """The options that say how one file is optimised, not where its outputs go: repair, solver,
    robust, ``--fix``, ``--stats``, ``--quiet``. ``posegraph batch`` takes them too and passes them
    to each file (:mod:`posegraph.batch.options`)."""
    repair_option(p)
    solver_options(p)
    robust_options(p)
    p.add_argument("--fix", metavar="ID", nargs="+", action="extend", type=non_negative_int, default=[],
                   help="hold these vertex ids at their start, besides the file's FIX lines (which then anchor "
                        "their component instead of its smallest id); OUT keeps the file's FIX lines only")
    p.add_argument("--stats", action="store_true",
                   help="print count, chi2 and chi2 per edge by edge kind (odometry, loop closure) at the result")
    p.add_argument("--no-map-check", action="store_true",
                   help="skip the broken-map check after a least-squares solve (edges judged against each other by "
                        "short robust refits, about one to three times the solve's time; docs/robust.md)")
    quiet_option(p)
    p.add_argument("--certify", action="store_true",
                   help="also certify SE-Sync's isotropic problem (posegraph certify), polish its estimate with LM on "
                        "the file's cost, write that, and report whether it ends where LM from the chordal start does; "
                        "exit status 1 when not certified")


def run(args) -> int:
    _check_outputs(args)
    with open_recording(args, "posegraph optimize") as recording:
        return _run(args, recording)


def _run(args, recording) -> int:
    from posegraph.cli.startup import import_solver_modules

    status = Status(args.quiet)
    import_solver_modules()  # first: it sets one BLAS thread before numpy loads
    from posegraph.solve import optimize

    graph, held, start, file_cost, seconds = _start(args, status)
    if args.certify:  # refuse a graph SE-Sync's problem is not defined on before any solving
        from posegraph.certification.problem import sync_problem

        sync_problem(held)
    params = solver_params(args, callback=None if args.quiet else iteration_printer(status, args.max_iterations))
    recorder = optimize_recorder(recording, held, start)
    params = with_recorder(params, recorder)
    robust = None
    with Timer() as t_opt:
        if args.robust == "gnc":
            robust = run_gnc(held, start, with_recorder(solver_params(args), recorder), args, status)
            result = robust.result
        else:
            result = optimize(held, initial=start, params=params)
    seconds["optimise"] = t_opt.seconds
    certified = None
    if args.certify:
        from posegraph.cli.certified import polish_certified

        if robust is None:
            result, certified = polish_certified(held, result, params, status, seconds)
        else:  # the least-squares problem of the edges (and priors) GNC kept
            kept = output_graph(held, robust.weights, drop=True, prior_weights=robust.prior_weights)
            dropped = held.num_edges - kept.num_edges
            result, certified = polish_certified(kept, result, params, status, seconds, dropped)
    status(f"{result.method}: {result.termination} after {result.iterations} iterations ({t_opt.seconds:.3f} s): "
           f"{stop_reason(result, params)}")
    held = held.with_points(result.points)  # the landmarks where the solve left them: χ², covariances, output
    weights = final_weights(held, args, result, robust)
    prior_weights = final_prior_weights(held, args, result, robust)
    landmark_weights = final_landmark_weights(held, args, result, robust)
    inliers = output_graph(held, weights, drop=True, prior_weights=prior_weights, landmark_weights=landmark_weights)  # robust: χ², covariances of those kept
    chi2, verdict = _chi2_and_verdict(args, held, inliers, result, params, robust_run=weights is not None)
    covariances = _covariances(args, status, inliers, result, seconds) if args.covariances else None
    known = known_inlier_facts(held, robust)
    record_optimize_result(recorder, held, result, weights=weights, covariances=covariances, chi2=chi2, robust=robust,
                           title=f"posegraph optimize {os.path.basename(display_name(args.input))}")
    _write_outputs(args, status, graph, result, params, file_cost, seconds, chi2, weights, covariances, known,
                   prior_weights, certified, landmark_weights, recording, verdict)
    if not args.quiet:
        _print_summary(args, graph, result, params, file_cost, seconds, chi2, certified)
        robust_summary(graph, weights, args, prior_weights, landmark_weights)
    _warn_if_broken(held, chi2, verdict, result.converged)
    warn_about_known_inliers(graph, known)
    drawn = _draw(args, status, graph, result) if args.plot else True
    if result.converged:
        return EXIT_OK if drawn and (certified is None or certified["certified"]) else EXIT_NOT_CONVERGED
    warn(f"the solver stopped before converging ({result.termination}, {result.iterations} iterations); "
         f"the result was written to {display_name_out(args.output)} anyway")
    return EXIT_NOT_CONVERGED


def display_name_out(path: str) -> str:
    return "<stdout>" if path == STDIO else path


def _check_outputs(args) -> None:
    """Every output writable, none the input (unless ``--force``), no two the same; before any work."""
    check_robust_options(args)
    check_rerun_options(args)
    if args.certify:
        from posegraph.cli.certified import check_certify_options

        check_certify_options(args)
    check_output(args.output, inputs=[args.input], allow_input=args.force, what="result", stdout=True)
    if args.report:
        check_output(args.report, inputs=[args.input], what="report", stdout=True)
    if args.plot:
        check_figure(args.plot, inputs=[args.input])
    if args.covariances:
        check_output(args.covariances, inputs=[args.input], what="covariances")
    if args.output == STDIO and args.report == STDIO:
        raise UsageError("the result and the report cannot both go to standard output (-)")
    check_distinct([p for p in (args.output, args.report, args.plot, args.covariances, args.rerun) if p and p != STDIO])


def _start(args, status: Status):
    """Read and initialise: ``(graph as read, graph with --fix held, start, file cost, seconds per phase)``.

    The cost at the file's poses is printed and reported; with ``--quiet`` and no report nothing
    shows it, and it is NaN.
    """
    from posegraph.cli.solving import check_linear_solver
    from posegraph.solve.residuals import cost

    graph, seconds_read = read_graph(args.input, status, repair_information=args.repair_information,
                                     uses_file_poses=args.init == "file", **reader_options(args))
    check_linear_solver(graph, args.linear_solver, args.input)
    held = _with_fixed(graph, args.fix, args.input)
    file_cost = float(cost(graph)) if (not args.quiet or args.report) else float("nan")
    if graph.num_vertices > LARGE_GRAPH_POSES:
        status(f"initialising ({args.init}): {graph.num_vertices} poses …")
    with Ticker(status, f"initialising ({args.init})"), Timer() as t_init:
        start = initial_poses(held, args)
    if not args.quiet and start is not None:  # None: --robust gnc's robust start, made by the optimiser
        start_cost = float(cost(graph, start)) if args.init != "file" else file_cost
        status(f"initialised ({args.init}): cost {fmt_cost(file_cost)} -> {fmt_cost(start_cost)} "
               f"({t_init.seconds:.3f} s)")
    return graph, held, start, file_cost, {"read": seconds_read, "initialise": t_init.seconds}


def _with_fixed(graph, ids: list, path: str):
    """``graph`` with the vertices ``ids`` (``--fix``) held too; a usage error for an id not in the file."""
    if not ids:
        return graph
    import dataclasses

    import numpy as np

    missing = np.setdiff1d(np.asarray(ids, dtype=np.int64), graph.ids)
    if missing.size:
        raise UsageError(f"--fix: vertex id {int(missing[0])} is not in {display_name(path)}")
    fixed = graph.fixed.copy()
    fixed[graph.index_of(ids)] = True
    return dataclasses.replace(graph, fixed=fixed)


def _covariances(args, status: Status, held, result, seconds: dict):
    """``(n, d, d)`` marginal covariances at the result, in the solve's gauge (``held``: with ``--fix``, its points the solved ones),
    and with landmarks ``{"poses": …, "landmarks": (L, s, s)}`` (:func:`posegraph.analysis.covariance.landmark_covariances`).

    An H that is not positive definite there stops the command before anything is written.
    """
    from posegraph.linalg.cholmod import NotPositiveDefiniteError
    from posegraph.analysis.covariance import landmark_covariances, marginal_covariances
    from posegraph.errors import OutputError

    with Ticker(status, "computing covariances"), Timer() as t:
        try:
            points = None if held.landmarks is None else held.landmarks.positions  # the solved ones (run: with_points)
            covariances = marginal_covariances(held, result.poses, points=points)
            if held.landmarks is not None:
                covariances = {"poses": covariances, "landmarks": landmark_covariances(held, result.poses, points)}
        except NotPositiveDefiniteError as exc:
            raise OutputError(f"cannot compute the covariances: the Gauss-Newton matrix at the result is not "
                              f"positive definite ({exc}); nothing written", path=args.covariances) from None
    seconds["covariances"] = t.seconds
    status(f"covariances: {held.num_vertices} poses"
           + (f", {held.landmarks.count} landmarks" if held.landmarks is not None else "") + f" ({t.seconds:.3f} s)")
    return covariances


def _write_outputs(
    args, status: Status, graph, result, params, file_cost, seconds, chi2, weights=None, covariances=None, known=None,
    prior_weights=None, certified=None, landmark_weights=None, recording=None, verdict=None,
) -> None:
    """The result, the report and the covariances if asked, staged and renamed into place together
    (``-``: printed after)."""
    from posegraph.io.atomic import StagedOutputs, json_text
    from posegraph.io.g2o import format_g2o, write_g2o

    printed = []
    with StagedOutputs() as outputs:
        with Ticker(status, f"writing {args.output}"), Timer() as t_write:
            written = output_graph(graph.with_points(result.points), weights, drop=args.drop_outliers,
                                   prior_weights=prior_weights, landmark_weights=landmark_weights)
            if args.output == STDIO:
                printed.append(format_g2o(written, result.poses))
            else:
                with outputs.writing(args.output) as tmp:
                    write_g2o(tmp, written, result.poses)
        seconds["write"] = t_write.seconds
        if args.report:
            from posegraph.analysis.report import optimize_report

            report = optimize_report(
                display_name(args.input), display_name_out(args.output), graph, result, init=args.init,
                file_cost=file_cost, seconds=seconds, params=params, chi2=chi2,
            )
            if certified is not None:
                report["certify"] = certified
            _report_chi2_and_verdict(report, graph, chi2, verdict)
            report = json_text(robust_report(report, args, weights, known, prior_weights, graph, landmark_weights))
            if args.report == STDIO:
                printed.append(report)
            else:
                outputs.write_text(args.report, report)
        if covariances is not None:
            import numpy as np

            with outputs.writing(args.covariances) as tmp, open(tmp, "wb") as f:  # a file object: savez adds no ".npz"
                if isinstance(covariances, dict):  # a landmark graph: the landmarks' too
                    np.savez(f, ids=graph.ids, covariances=covariances["poses"], landmark_ids=graph.landmarks.ids,
                             landmark_covariances=covariances["landmarks"])
                else:
                    np.savez(f, ids=graph.ids, covariances=covariances)
        if recording is not None:
            recording.stage_into(outputs)
        outputs.commit()
    for text in printed:
        sys.stdout.write(text)
    sys.stdout.flush()


def _draw(args, status: Status, graph, result) -> bool:
    """The figure, once the result is safe: a failure (or Ctrl-C) is a warning, not a lost result."""
    from posegraph.analysis.plot import plot_trajectories

    try:
        with Ticker(status, f"drawing {args.plot}"):
            plot_trajectories(
                args.plot, [graph, graph.with_points(result.points)], [f"input ({os.path.basename(display_name(args.input))})", "optimised"],
                [graph.poses, result.poses], title=os.path.basename(display_name(args.input)),
            )
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP
        warn(f"interrupted while drawing {args.plot}: no figure; the result is in {display_name_out(args.output)}")
        raise SystemExit(interrupted_status(exc)) from None
    except Exception as exc:  # the result is written: losing the figure must not look like losing it
        warn(f"the figure {args.plot} was not drawn ({type(exc).__name__}: {' '.join(str(exc).split())}); "
             f"the result is in {display_name_out(args.output)}")
        return False
    return True


def _print_summary(args, graph, result, params, file_cost: float, seconds: dict, chi2: dict, certified=None) -> None:
    """The summary, on stdout (stderr when stdout carries the result or the report)."""
    from posegraph.analysis.report import dof_equation, per_dof_text

    out = sys.stderr if STDIO in (args.output, args.report) else sys.stdout
    lines = [
        f"input:          {display_name(args.input)} ({graph_size(graph)})",
        f"file cost:      {fmt_cost(file_cost)}",
        f"initial cost:   {fmt_cost(result.initial_cost)} (after {args.init} initialisation)",
        *_cost_lines(args, params, result, chi2),
        f"χ²/dof:         {per_dof_text(chi2)} ({'of the inliers; ' if 'every' in chi2 else ''}dof = {dof_equation(chi2)}; "
        "≈ 1 when the information matrices describe the noise)",
        f"iterations:     {result.iterations}",
        f"termination:    {result.termination} ({stop_reason(result, params)})",
        f"linear solver:  {result.linear_solver}",
        "seconds:        " + ", ".join(f"{k} {v:.3f}" for k, v in seconds.items())
        + f", total {sum(seconds.values()):.3f}",
        f"output:         {display_name_out(args.output)}"
        + "".join(f", {p}" for p in (args.report, args.plot, args.covariances) if p),
    ]
    if certified is not None:
        from posegraph.cli.certified import certify_summary

        lines += certify_summary(certified)
    if args.stats:
        lines += _stats_table(chi2)
    print("\n".join(lines), file=out, flush=True)


def _cost_lines(args, params, result, chi2: dict) -> list[str]:
    """The final cost, labelled as what the solver minimised, and χ² = Σ eᵀΩe over every measurement
    at the result; with a robust mode, plain ½χ² beside the robust cost and the inliers' χ² after."""
    if "every" not in chi2:
        return [f"final cost:     {fmt_cost(result.final_cost)} (cost = ½χ² = ½ Σ eᵀΩe, gtsam's error)",
                f"final χ²:       {fmt_cost(chi2['chi2'])} (Σ eᵀΩe, as g2o prints it)"]
    every = chi2["every"]
    kept = sum(kind["count"] for kind in chi2["by_kind"].values())
    total = sum(kind["count"] for kind in every["by_kind"].values())
    minimised = ("½ Σ w·eᵀΩe with GNC's weights w: ½χ² of the measurements kept" if args.robust == "gnc" else
                 f"robust cost ½ Σ ρ(eᵀΩe), {args.robust} loss: what the solver minimised")
    return [f"final cost:     {fmt_cost(result.final_cost)} ({minimised})",
            f"final ½χ²:      {fmt_cost(every['cost'])} (½ Σ eᵀΩe over all {total} measurements at the result, "
            "gtsam's error without the loss)",
            f"final χ²:       {fmt_cost(every['chi2'])} (Σ eᵀΩe over all {total} measurements, as g2o prints it)",
            f"inliers' χ²:    {fmt_cost(chi2['chi2'])} (Σ eᵀΩe over the {kept} of weight ≥ 0.5)"]


def _stats_table(chi2: dict) -> list[str]:
    """``--stats``: count, χ² and χ²/edge per edge kind (priors and landmark measurements too) at the
    result (g2o's ``-stats``, by kind)."""
    rows = [("odometry", chi2["by_kind"]["odometry"]), ("loop closure", chi2["by_kind"]["loop_closure"])]
    rows += [(kind, chi2["by_kind"][kind]) for kind in ("prior", "landmark") if kind in chi2["by_kind"]]
    count = sum(r["count"] for _, r in rows)
    rows.append(("all", {"count": count, "chi2": chi2["chi2"],
                         "chi2_per_edge": chi2["chi2"] / count if count else float("nan")}))
    lines = [f"{'edges':<14}{'count':>8}{'χ²':>16}{'χ²/edge':>14}"]
    lines += [f"{name:<14}{r['count']:>8}{r['chi2']:>16.6g}{r['chi2_per_edge']:>14.4g}" for name, r in rows]
    return lines


def _chi2_and_verdict(args, held, inliers, result, params, robust_run: bool):
    """``(χ² summary, broken-map verdict or None)`` at the result: χ² of ``inliers`` (``held`` unless a robust
    mode judged outliers), with a robust mode χ² over every measurement under ``"every"``; the verdict
    (:func:`posegraph.analysis.suspicious.suspicious_edges`) after least squares, unless ``--no-map-check``."""
    from posegraph.analysis.report import chi2_summary

    # the solver's last residuals are those of `inliers` unless the robust path dropped edges
    residuals = result.final_residuals if inliers is held and args.robust != "gnc" else None
    chi2 = chi2_summary(inliers, result.poses, residuals)
    if robust_run:  # χ² over every measurement too, at the same poses
        chi2["every"] = chi2_summary(held, result.poses)
    if args.robust != "none" or args.no_map_check:
        return chi2, None
    from posegraph.analysis.suspicious import suspicious_edges

    return chi2, suspicious_edges(held, result.poses, params)


def _report_chi2_and_verdict(report: dict, graph, chi2: dict, verdict) -> None:
    """The report's ``chi2_every`` (robust: χ² over every measurement at the result; its top-level ``chi2``
    is the inliers') and ``suspicious_edges`` (least squares: the broken-map check, every edge named)."""
    if "every" in chi2:
        every = chi2["every"]
        report["chi2_every"] = {"chi2": every["chi2"], "half_chi2": every["cost"], "dof": every["dof"],
                                "chi2_per_dof": every["chi2_per_dof"]}
    if verdict is not None:
        report["suspicious_edges"] = verdict.as_dict(graph)


SHOWN_SUSPICIOUS = 5
"""How many suspicious edges the broken-map warning names (the report lists them all)."""


def _warn_if_broken(graph, chi2: dict, verdict, converged: bool = True) -> None:
    """One warning: the broken-map verdict naming the suspicious edges, with χ²/dof if far above 1
    (:data:`posegraph.analysis.report.CHI2_PER_DOF_WARNING`); or χ²/dof alone, naming the largest χ², when
    no edge stands out after the refits. None when the solve ``converged`` and the edges agree with each
    other (``verdict.screened``): a clean graph whose information overstates its noise
    (sphere_bignoise_vertex3: χ²/dof 77) is not warned, the summary's χ²/dof line says what the ratio
    means; a solve stopped short (sphere2500 with 20 % wrong loop closures within 3 m) still is."""
    from posegraph.analysis.report import CHI2_PER_DOF_WARNING

    agreeing = verdict is not None and verdict.screened and converged
    high = chi2["chi2_per_dof"] > CHI2_PER_DOF_WARNING and not agreeing
    ratio = (f"χ²/dof = {chi2['chi2_per_dof']:.3g} is far above the ≈1 the information matrices predict "
             f"(> {CHI2_PER_DOF_WARNING:g})")
    if verdict is not None and verdict.broken:
        shown = "; ".join(_edge_text(row) for row in verdict.rows(graph, SHOWN_SUSPICIOUS))
        more = f" (and {len(verdict.edges) - SHOWN_SUSPICIOUS} more)" if len(verdict.edges) > SHOWN_SUSPICIOUS else ""
        warn((f"{ratio}; " if high else "") + f"the map looks broken: {len(verdict.edges)} loop closure"
             f"{'s' if len(verdict.edges) != 1 else ''} disagree with the rest of the graph (with them down-weighted, "
             f"the other edges' χ² falls {verdict.gain:.3g}-fold): {shown}{more}; wrong loop closures? "
             "try --robust gnc")
    elif high:
        worst = ", ".join(_edge_text(e) for e in chi2["worst_edges"])
        standout = ("; no edge stands out from the rest: information matrices that overstate the noise, or wrong "
                    "edges bending the whole map?" if verdict is not None and verdict.judged
                    else ": outliers or overconfident edges?")
        warn(f"{ratio}{standout} largest χ²: {worst}; try --robust gnc")


def _edge_text(edge: dict) -> str:
    """``"line 12 (3->40, χ² 1.2e+03)"`` (``edge N`` without a file line)."""
    where = f"line {edge['line']}" if edge["line"] is not None else "edge"
    return f"{where} ({edge['from_id']}->{edge['to_id']}, χ² {edge['chi2']:.3g})"
