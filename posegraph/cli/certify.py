"""``posegraph certify``: prove (or fail to prove) the global optimality of SE-Sync's isotropic problem."""

from __future__ import annotations

import sys

from posegraph.cli.common import (
    EXIT_NOT_CONVERGED, EXIT_OK, STDIO, Status, Timer, UsageError, check_distinct, check_output, display_name,
    positive_float, positive_int, read_graph, repair_option, print_all, stage_or_print,
)

NAME = "certify"
HELP = "certify the global optimum of SE-Sync's isotropic problem"
DESCRIPTION = (
    "Solve SE-Sync's isotropic version of the pose graph (each edge's information reduced to a "
    "rotational precision kappa and a translational tau, as SE-Sync's reader does) and certify the "
    "solution globally optimal through the semidefinite relaxation: a Cholesky factorisation proves "
    "lambda_min(Q - Lambda) > -sigma, so that tr(Lambda) - dn sigma is a lower bound on the global "
    "minimum, and the estimate is certified when F(x) is within ETA F(x) of that bound. Each connected "
    "component is certified on its own; pose priors are edges from a world pose. First a cheap candidate "
    "(chordal + Levenberg-Marquardt, then Newton steps) is checked at rank d; only if that fails does the "
    "Riemannian staircase run, and the best estimate it finds is written. Prints F(x) (SE-Sync's "
    "objective), the proven lower bound, the minimum eigenvalue of Q - Lambda with its residual, and "
    "seconds per phase. The certificate covers "
    "SE-Sync's isotropic objective, not the file's full anisotropic cost (optimize --certify "
    "polishes that from the certified estimate). Exit status 0 certified, 1 not certified (the bound "
    "is printed; OUT and the report are still written), 2 bad input."
)
EXAMPLES = """
  posegraph certify sphere2500.g2o
  posegraph certify intel.g2o -o intel-certified.g2o --report certificate.json
  posegraph certify garage.g2o --eta 1e-4 --max-rank 8"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="input pose graph (- for standard input)")
    p.add_argument("-o", "--output", metavar="OUT.g2o",
                   help="write the certified estimate (SE-Sync's rounded poses; - for standard output)")
    p.add_argument("--report", metavar="REPORT.json", help="write the certificate as JSON (- for standard output)")
    p.add_argument("--eta", type=positive_float, default=None, metavar="ETA",
                   help="relative tolerance: certified when F(x) - (proven lower bound) <= ETA F(x) "
                        "(default 1e-6)")
    p.add_argument("--max-rank", type=max_rank, default=10, metavar="R",
                   help="highest rank of the Riemannian staircase (default 10, SE-Sync's rmax); at least the "
                        "rotations' dimension d (2 in 2D, 3 in 3D), where it starts: R = d tests the rank-d "
                        "candidate alone")
    repair_option(p)
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")


LOWEST_RANK = 2
"""The rotations' dimension d of a 2D graph: no relaxation has a lower rank (a 3D graph's is 3)."""


def max_rank(text: str) -> int:
    """argparse type of ``--max-rank``: an integer >= :data:`LOWEST_RANK` (the graph's own d is checked
    once it is read, :func:`check_max_rank`)."""
    import argparse

    value = positive_int(text)
    if value < LOWEST_RANK:
        raise argparse.ArgumentTypeError(f"must be >= {LOWEST_RANK}, the rotations' dimension d of a 2D graph "
                                         f"(3 for a 3D one), where the staircase starts: {text}")
    return value


def check_max_rank(rank: int, graph) -> None:
    """A :class:`UsageError` when ``--max-rank`` is below the graph's rotation dimension d: the staircase
    starts at rank d (the candidate's rotations), so a lower cap would be ignored."""
    d = graph.group.space_dim
    if rank < d:
        raise UsageError(f"--max-rank {rank} is below {d}, the rotations' dimension d of this {d}D graph, where "
                         f"the staircase starts: give R >= {d} (R = {d} tests the rank-{d} candidate alone)")


def run(args) -> int:
    from posegraph.cli.startup import import_solver_modules

    status = Status(args.quiet)
    _check_outputs(args)
    import_solver_modules()
    from posegraph.certification.certificate import certify
    from posegraph.certification.verify import DEFAULT_TOLERANCE

    graph, seconds_read = read_graph(args.input, status, repair_information=args.repair_information,
                                     uses_file_poses=False)  # the candidate starts from the chordal relaxation
    check_max_rank(args.max_rank, graph)
    with Timer() as t:
        certificate = certify(graph, eta=DEFAULT_TOLERANCE if args.eta is None else args.eta, max_rank=args.max_rank)
    status(f"certify: {certificate.status} ({t.seconds:.3f} s)")
    _write_outputs(args, graph, certificate, seconds_read)
    if not args.quiet:
        print_certificate(certificate, sys.stderr if STDIO in (args.output, args.report) else sys.stdout)
    return EXIT_OK if certificate.certified else EXIT_NOT_CONVERGED


def _check_outputs(args) -> None:
    if args.output:
        check_output(args.output, inputs=[args.input], allow_input=args.force, what="result", stdout=True)
    if args.report:
        check_output(args.report, inputs=[args.input], what="report", stdout=True)
    if args.output == STDIO and args.report == STDIO:
        raise UsageError("the result and the report cannot both go to standard output (-)")
    check_distinct([p for p in (args.output, args.report) if p and p != STDIO])


def certificate_report(certificate, source: str, graph) -> dict:
    """The JSON report of a certificate: its fields, the input and its size."""
    report = {"input": source, "vertices": graph.num_vertices, "edges": graph.num_edges}
    report.update(certificate.report())
    return report


def _write_outputs(args, graph, certificate, seconds_read: float) -> None:
    """OUT and the report, staged and renamed into place together (``-``: printed after)."""
    from posegraph.io.atomic import StagedOutputs, json_text
    from posegraph.io.g2o import format_g2o, write_g2o

    printed = []
    with StagedOutputs() as outputs:
        if args.output == STDIO:
            printed.append(format_g2o(graph, certificate.poses))
        elif args.output:
            with outputs.writing(args.output) as tmp:
                write_g2o(tmp, graph, certificate.poses)
        if args.report:
            report = certificate_report(certificate, display_name(args.input), graph)
            report["seconds"] = {"read": seconds_read, **report["seconds"]}
            stage_or_print(outputs, args.report, json_text(report), printed)
        outputs.commit()
    print_all(printed)


def print_certificate(certificate, out) -> None:
    """The certificate's summary lines."""
    c = certificate
    lines = [
        f"certified:           {'yes' if c.certified else 'NO'} ({c.status})",
        f"F(x):                {c.sesync_objective:.6g} (SE-Sync's objective at the estimate)",
        f"lower bound:         {c.lower_bound:.6g} (proven: tr(Lambda) {c.dual_bound:.6g} - dn sigma)",
        f"suboptimality bound: {c.suboptimality_bound:.3g} ({c.relative_suboptimality:.3g} of F(x); eta = {c.eta:g})",
        f"min eigenvalue:      {c.min_eigenvalue:.3g} of Q - Lambda (residual {c.eigenvalue_residual:.2g}; proven "
        f"> {c.proven_min_eigenvalue:.3g})",
        f"rank:                {c.rank}" + (f" ({c.components} components)" if c.components > 1 else ""),
        "seconds:             " + ", ".join(f"{k} {v:.3f}" for k, v in c.seconds.items()),
    ]
    print("\n".join(lines), file=out, flush=True)
