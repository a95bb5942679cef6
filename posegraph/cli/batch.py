"""``posegraph batch``: ``optimize`` over many files in parallel on Dask, one summary row per file."""

from __future__ import annotations

import sys

from posegraph.cli.common import (
    EXIT_NOT_CONVERGED, EXIT_OK, PROG, UsageError, interrupted_status, positive_int, warn,
)

NAME = "batch"
HELP = "optimise many g2o files in parallel on Dask (a local cluster, or --scheduler)"
DESCRIPTION = (
    "Run `posegraph optimize` on each IN with the options given, in parallel on a Dask cluster: a local "
    "one of --workers processes (default one per core), or the one whose scheduler --scheduler names. "
    "OUT_DIR gets, per input NAME.g2o, the result NAME.g2o (byte for byte what `posegraph optimize` "
    "writes), its report NAME.report.json and NAME.log (what optimize printed, and its exit status); "
    "the summary (file, vertices, edges, final cost, chi2/dof, iterations, seconds, outliers, status, "
    "reason) goes to SUMMARY.json and SUMMARY.csv (default OUT_DIR/summary.json). A file that fails is "
    "one failed row with optimize's one-line reason; the others go on. Files whose outputs an earlier "
    "run with the same options completed after the input last changed are skipped (--force redoes "
    "them). Exit status 1 when any file failed or did not converge. Needs dask.distributed: "
    'pip install "posegraph[batch]".'
)
EXAMPLES = """
  posegraph batch data/*.g2o -o results/
  posegraph batch data/*.g2o -o results/ --robust gnc --workers 4 --report sweep-gnc.json
  posegraph batch data/*.g2o -o results/ --scheduler tcp://10.0.0.5:8786   (an existing Dask cluster)
  posegraph batch data/*.g2o -o results/ --force      (redo files already done)"""


def add_arguments(p) -> None:
    from posegraph.cli.optimize import file_options

    p.add_argument("inputs", metavar="IN.g2o", nargs="+", help="input pose graphs")
    p.add_argument("-o", "--output-dir", dest="out_dir", metavar="OUT_DIR", required=True,
                   help="folder for each file's result, report and log (made if absent)")
    p.add_argument("--report", metavar="SUMMARY.json",
                   help="the summary as JSON, and as CSV beside it (default OUT_DIR/summary.json)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", metavar="N", type=positive_int,
                       help="worker processes of the local cluster (default one per core, at most one per file)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on the Dask cluster whose scheduler is at ADDRESS (tcp://host:port); its "
                            "workers must have posegraph installed and see the input and OUT_DIR paths")
    p.add_argument("--force", action="store_true", help="redo the files whose outputs are already complete")
    p.add_argument("--plot", action="store_true", help="draw each file's trajectories into OUT_DIR/NAME.png")
    p.add_argument("--covariances", action="store_true",
                   help="write each file's marginal covariances into OUT_DIR/NAME.cov.npz")
    file_options(p.add_argument_group("optimize options, passed to each file (see posegraph optimize --help)"))


def run(args) -> int:
    from posegraph.batch import BatchError, optimize_many
    from posegraph.batch.options import file_option_defaults

    options = {name: getattr(args, name) for name in file_option_defaults()}
    progress = ProgressLine(quiet=args.quiet)
    try:
        rows = optimize_many(
            args.inputs, args.out_dir, scheduler=args.scheduler, workers=args.workers, force=args.force,
            report=args.report, plot=args.plot, covariances=args.covariances, progress=progress, **options,
        )
    except BatchError as exc:
        raise UsageError(str(exc)) from None
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP
        progress.finish()
        print(f"\n{PROG}: interrupted; the files finished are in {args.out_dir} (a re-run skips them)",
              file=sys.stderr, flush=True)
        return interrupted_status(exc)
    progress.finish()
    _print_table(rows, args)
    bad = [row["file"] for row in rows if row["status"] in ("failed", "not converged")]
    if bad:
        shown = ", ".join(bad[:5]) + (f", … {len(bad) - 5} more" if len(bad) > 5 else "")
        warn(f"{len(bad)} of {len(rows)} files failed or did not converge ({shown}); their reasons are in the "
             f"summary and each NAME.log in {args.out_dir}")
    return EXIT_NOT_CONVERGED if bad else EXIT_OK


class ProgressLine:
    """The batch's progress on stderr: on a terminal one line redrawn in place (done, failed,
    running, waiting), with each failure printed above it; elsewhere one line per file as it ends."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.terminal = sys.stderr.isatty()
        self.drawn = False

    def __call__(self, row, counts: dict) -> None:
        if self.quiet and (row is None or row["status"] == "ok"):
            return
        finished = counts["done"] + counts["failed"]
        text = (f"{_bar(finished, counts['total'])} {counts['done']} done, {counts['failed']} failed, "
                f"{counts['running']} running, {counts['waiting']} waiting, of {counts['total']}")
        if row is not None and (not self.terminal or row["status"] != "ok"):
            reason = f": {row['reason']}" if row["reason"] else ""
            self._clear()
            print(f"[{finished}/{counts['total']}] {row['status']} {row['file']}{reason}", file=sys.stderr, flush=True)
        if self.terminal and not self.quiet:
            sys.stderr.write(f"\r\033[K{text}")
            sys.stderr.flush()
            self.drawn = True

    def _clear(self) -> None:
        if self.drawn:
            sys.stderr.write("\r\033[K")

    def finish(self) -> None:
        if self.drawn:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self.drawn = False


def _bar(finished: int, total: int, width: int = 24) -> str:
    """``[#########...............]``: the share of files finished."""
    filled = width * finished // max(total, 1)
    return "[" + "#" * filled + "." * (width - filled) + "]"


def _print_table(rows: list, args) -> None:
    """The summary on stdout (unless ``--quiet``): one line per file, then the counts and where it is."""
    from posegraph.batch.many import SUMMARY_NAME
    from posegraph.batch.rows import summary_paths, tally

    if args.quiet:
        return
    width = max(len(row["file"]) for row in rows)
    print(f"{'file':<{width}}  {'status':<13}{'final cost':>16}{'χ²/dof':>10}{'iter':>6}{'seconds':>9}")
    for row in rows:
        cost = "" if row["final_cost"] is None else f"{row['final_cost']:.10g}"
        ratio = "" if row["chi2_per_dof"] is None else f"{row['chi2_per_dof']:.4g}"
        iterations = "" if row["iterations"] is None else row["iterations"]
        seconds = "" if row["seconds"] is None else f"{row['seconds']:.3f}"
        print(f"{row['file']:<{width}}  {row['status']:<13}{cost:>16}{ratio:>10}{iterations:>6}{seconds:>9}")
    import os

    summary = args.report or os.path.join(args.out_dir, SUMMARY_NAME)
    counts = ", ".join(f"{n} {status}" for status, n in tally(rows).items() if n)
    print(f"{len(rows)} file{'s' if len(rows) != 1 else ''}: {counts}; summary: {', '.join(summary_paths(summary))}", flush=True)
