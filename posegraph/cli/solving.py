"""The solver options ``optimize`` and ``compare`` share, and what they turn into: the start and the parameters."""

from __future__ import annotations

import argparse

from posegraph.cli.common import Status, non_negative_float, non_negative_int


def solver_options(p: argparse.ArgumentParser) -> None:
    """``--method``, ``--init``, the iteration cap, the tolerances and ``--linear-solver``."""
    p.add_argument("--method", choices=("lm", "gn"), default="lm",
                   help="Levenberg-Marquardt (default) or Gauss-Newton")
    p.add_argument("--init", choices=("chordal", "odometry", "file"), default="chordal",
                   help="start: chordal relaxation of the rotations (default), chaining the odometry "
                        "edges, or the poses in the file")
    p.add_argument("--max-iterations", type=non_negative_int, default=100, metavar="N",
                   help="iteration cap (default 100); reaching it gives exit status 1")
    p.add_argument("--relative-tolerance", type=non_negative_float, default=None, metavar="TOL",
                   help="stop when an iteration lowers the cost by at most this fraction "
                        "(default: the solver's, 1e-7)")
    p.add_argument("--absolute-tolerance", type=non_negative_float, default=None, metavar="TOL",
                   help="stop when an iteration lowers the cost by at most this much "
                        "(default: the solver's, 1e-12)")
    p.add_argument("--linear-solver", choices=("auto", "cholmod", "scipy"), default="auto",
                   help="sparse Cholesky backend: CHOLMOD (the system library, else scikit-sparse) or scipy; auto picks "
                        "CHOLMOD when installed")


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


def initial_poses(graph, args):
    """The start ``(n, 4, 4)`` that ``--init`` names; None for ``--robust gnc --init chordal`` (the
    robust chordal start, which GNC makes)."""
    from posegraph.init import initialize

    if getattr(args, "robust", "none") == "gnc" and args.init == "chordal":
        return None
    if args.init == "chordal":
        return initialize(graph, method="chordal", linear_solver=args.linear_solver)
    return initialize(graph, method=args.init)


def iteration_printer(status: Status):
    """A solver callback printing one line per iteration on ``status``."""
    def callback(record) -> None:
        note = "" if record.accepted else "  (step rejected)"
        status(
            f"  iter {record.iteration:3d}  cost {record.cost:.10e}  decrease {record.cost_decrease:.3e}  "
            f"lambda {record.lambda_:.1e}  {record.seconds:.3f} s{note}"
        )

    return callback
