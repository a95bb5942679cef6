"""The solver options ``optimize`` and ``compare`` share, and what they turn into: the start and the parameters."""

from __future__ import annotations

import argparse

from posegraph.cli.common import Status, display_name, non_negative_float, non_negative_int


def solver_options(p: argparse.ArgumentParser) -> None:
    """``--method``, ``--init``, the iteration cap, the tolerances and ``--linear-solver``."""
    p.add_argument("--method", choices=("lm", "gn"), default="lm",
                   help="Levenberg-Marquardt (default) or Gauss-Newton")
    p.add_argument("--init", choices=("chordal", "odometry", "file"), default="chordal",
                   help="start: chordal relaxation of the rotations (default; a landmark graph whose file "
                        "values already fit its measurements, cost <= 1 per residual row, starts from them), "
                        "chaining the odometry edges, or the poses in the file")
    p.add_argument("-i", "--max-iterations", type=non_negative_int, default=100, metavar="N",
                   help="iteration cap (default 100; -i as in g2o); reaching it gives exit status 1")
    p.add_argument("--relative-tolerance", type=non_negative_float, default=None, metavar="TOL",
                   help="stop when an iteration lowers the cost by at most this fraction "
                        "(default: the solver's, 1e-7)")
    p.add_argument("--absolute-tolerance", type=non_negative_float, default=None, metavar="TOL",
                   help="stop when an iteration lowers the cost by at most this much "
                        "(default: the solver's, 1e-12)")
    p.add_argument("--linear-solver", choices=("auto", "cholmod", "scipy", "pcg"), default="auto",
                   help="sparse solver: CHOLMOD (from the cvxopt wheel), scipy's SuperLU, or pcg "
                        "(multigrid-preconditioned conjugate gradients, no factorisation: memory linear "
                        "in the graph; needs pyamg); auto picks CHOLMOD when cvxopt is installed, and "
                        "pcg when CHOLMOD's factor would not fit in the memory available")


def solver_params(args, callback=None):
    """:class:`posegraph.solve.SolverParams` from the options of :func:`solver_options`."""
    from posegraph.solve import SolverParams

    from posegraph.cli.robust import robust_loss

    options = dict(method=args.method, max_iterations=args.max_iterations,
                   linear_solver=args.linear_solver, callback=callback, loss=robust_loss(args))
    if args.relative_tolerance is not None:
        options["relative_tolerance"] = args.relative_tolerance
    if args.absolute_tolerance is not None:
        options["absolute_tolerance"] = args.absolute_tolerance
    return SolverParams(**options)


def check_linear_solver(graph, linear_solver: str, path: str) -> None:
    """:class:`~posegraph.errors.GraphError` naming ``path`` when ``--linear-solver pcg`` meets a graph with
    landmarks, which its multigrid cannot solve: said as soon as the file is read, before any start is made."""
    from posegraph.errors import GraphError
    from posegraph.solve.linear import PCG_POSES_ONLY

    if linear_solver == "pcg" and graph.landmarks is not None and graph.landmarks.count:
        raise GraphError(PCG_POSES_ONLY, display_name(path))


def initial_poses(graph, args):
    """The start ``(n, 4, 4)`` that ``--init`` names; None for ``--robust gnc --init chordal`` (the
    robust chordal start, which GNC makes)."""
    from posegraph.solve.file_start import start_poses

    if getattr(args, "robust", "none") == "gnc" and args.init == "chordal":
        return None
    if args.init == "chordal":
        return start_poses(graph, "chordal", linear_solver=args.linear_solver)
    return start_poses(graph, args.init)


def iteration_printer(status: Status, max_iterations: int):
    """A solver callback printing one line per iteration on ``status``: ``iter k/max``, cost,
    decrease, LM λ, seconds, and why no step was taken when none was."""
    width = len(str(max_iterations))

    def callback(record) -> None:
        status(
            f"  iter {record.iteration:>{width}}/{max_iterations}  cost {record.cost:.10e}  "
            f"decrease {record.cost_decrease:.3e}  lambda {record.lambda_:.1e}  {record.seconds:.3f} s"
            f"{_no_step_note(record)}"
        )

    return callback


def _no_step_note(record) -> str:
    if record.accepted:
        return ""
    if record.step_norm == 0:  # the solver judged a step not worth taking: its stop test follows
        return "  (no step needed)"
    return "  (step rejected)"


def stop_reason(result, params) -> str:
    """Why the solver stopped, in words with the numbers that decided it (one line, no newline).

    ``result.termination`` is the solver's reason (:class:`posegraph.solve.result.OptimizeResult`);
    the decrease quoted is that of the last accepted step, relative to the cost before it.
    """
    accepted = [r for r in result.records if r.accepted]
    decrease = accepted[-1].cost_decrease if accepted else 0.0
    before = accepted[-1].cost + decrease if accepted else 0.0
    relative = decrease / before if before > 0 else 0.0
    reasons = {
        "converged: relative decrease": (
            f"the last step lowered the cost by {relative:.1e} of it, within the relative tolerance "
            f"{params.relative_tolerance:g}"),
        "converged: absolute decrease": (
            f"the last step lowered the cost by {decrease:.1e}, within the "
            f"absolute tolerance {params.absolute_tolerance:g}"),
        "converged: cost below tolerance": "the cost is below the cost tolerance",
        "converged: predicted decrease below tolerance": "no step can lower the cost by more than the tolerances",
        "converged: Newton decrement below tolerance": (
            "a further step would lower the cost by far less than the tolerances"),
        "converged: nothing to optimise": "every vertex is held (FIX or gauge anchor)",
        "maximum iterations": (
            f"the iteration cap ({params.max_iterations}, --max-iterations/-i) came before convergence"),
        "lambda exceeded bound": "no damped step lowered the cost (LM's lambda passed its bound)",
        "no decrease": "no step, nor any shortening of it, lowered the cost (Gauss-Newton)",
    }
    return reasons.get(result.termination, result.termination)
