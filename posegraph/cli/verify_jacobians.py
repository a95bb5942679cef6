"""``posegraph verify-jacobians``: the Lie-group core and edge Jacobians against gtsam and finite differences."""

from __future__ import annotations

from posegraph.cli.common import reader_options, EXIT_NOT_CONVERGED, EXIT_OK, Status, non_negative_int, read_graph, repair_option, warn

NAME = "verify-jacobians"
HELP = "check the Lie-group core and edge Jacobians"
DESCRIPTION = (
    "Cross-validate SO(3)/SE(3)/SO(2)/SE(2) Exp, Log, adjoints, Jacobians and the edge-residual Jacobians "
    "(3D and 2D) against gtsam and against central finite differences, on random samples, on angles near 0 and "
    "near pi, and on the edges of IN when given. Prints the largest difference per quantity and "
    "its tolerance; exit status 1 when any exceeds it."
)
EXAMPLES = """
  posegraph verify-jacobians
  posegraph verify-jacobians sphere2500.g2o --samples 2000
  posegraph verify-jacobians intel.g2o      (a 2D graph: BetweenFactorPose2)
  posegraph verify-jacobians --no-gtsam       (finite differences only)"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", nargs="?", help="also check the Jacobians of this graph's edges")
    repair_option(p)
    p.add_argument("--samples", type=non_negative_int, default=500, metavar="N",
                   help="random samples per quantity (default 500)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--no-gtsam", action="store_true", help="skip the comparisons with gtsam")


def run(args) -> int:
    from posegraph.crosscheck.jacobians import format_checks, verify_all

    if not args.no_gtsam:
        from posegraph.crosscheck.gtsam_bridge import require_gtsam

        try:
            require_gtsam()
        except ImportError as exc:
            raise ImportError(f"{exc}; or run verify-jacobians --no-gtsam (finite differences only)") from exc
    graph = None
    if args.input:
        graph, _ = read_graph(args.input, Status(True), repair_information=args.repair_information,
                              uses_file_poses=False, **reader_options(args))  # the Jacobians hold at any poses
    checks = verify_all(graph=graph, samples=args.samples, seed=args.seed, use_gtsam=not args.no_gtsam)
    print(format_checks(checks))
    failed = [c for c in checks if not c.passed]
    if failed:
        warn(f"{len(failed)} of {len(checks)} checks exceed their tolerance: " + ", ".join(c.name for c in failed))
        return EXIT_NOT_CONVERGED
    return EXIT_OK
