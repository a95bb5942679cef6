"""The entry point: parse, run the subcommand, and turn what went wrong into one line and an exit status."""

from __future__ import annotations

import sys
import warnings

from posegraph.cli.common import (
    EXIT_BUG, EXIT_NOT_CONVERGED, EXIT_USAGE, OPTIONAL_MODULES, PROG, UsageError, WarningPrinter, error,
    interrupted_message, interrupted_status,
)
from posegraph.cli.parser import COMMANDS, build_parser


DEBUG_OPTION = "--debug"
"""Anywhere on the command line: an internal error shows its traceback instead of one line."""


def main(argv=None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``) and return the exit status.

    Every exception ends as one line on stderr and an exit status (docs/cli.md): a user's mistake
    as status 2, a bug (any other exception) as status 3 with a hint to rerun with ``--debug``,
    which re-raises it with its traceback.
    """
    from posegraph.io.atomic import forget_committed_outputs
    from posegraph.cli.common import CLOSED_STREAMS
    from posegraph.cli.startup import reopen_closed_streams, stop_signals_interrupt

    CLOSED_STREAMS.update(reopen_closed_streams())  # first: a message printed before would fail
    argv = sys.argv[1:] if argv is None else list(argv)
    forget_committed_outputs()  # what this run delivers, for the message if it is interrupted
    try:
        with stop_signals_interrupt():
            return _run(argv)
    except Exception as exc:  # a bug of ours, not a user's mistake
        if DEBUG_OPTION in argv:
            raise
        text = " ".join(str(exc).split())[:300]
        error(f"internal error ({type(exc).__name__}: {text}); rerun with {DEBUG_OPTION} for the traceback "
              "and report it")
        return EXIT_BUG


def _show_warnings(everything: bool) -> None:
    """Show each of posegraph's own warnings (:class:`~posegraph.errors.PosegraphWarning`: input
    repaired or skipped, suspicious results), every time it is raised; other packages' warnings
    follow Python's filters (its defaults, ``-W``, ``PYTHONWARNINGS``), or with ``--debug`` all
    show. Filters added later take precedence, so ours goes last."""
    from posegraph.errors import PosegraphWarning

    if everything:
        warnings.simplefilter("always")
    warnings.simplefilter("always", PosegraphWarning)


def _run(argv: list) -> int:
    """Parse and run; map a user's mistakes (and Ctrl-C) to one line and an exit status; bugs propagate."""
    printer = WarningPrinter()
    try:
        with warnings.catch_warnings():
            _show_warnings(everything=DEBUG_OPTION in argv)
            warnings.showwarning = printer
            try:
                named = argv[0] if argv and argv[0] in COMMANDS else None
                args = build_parser(only=named).parse_args(argv)
                return args.func(args)
            finally:
                printer.finish()
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (posegraph.errors.Interrupted)
        print(f"\n{PROG}: {interrupted_message(exc)}", file=sys.stderr, flush=True)
        return interrupted_status(exc)
    except UsageError as exc:
        error(str(exc))
        return EXIT_USAGE
    except SystemExit as exc:  # --help and --version
        return exc.code if isinstance(exc.code, int) else 0
    except ImportError as exc:
        # An optional dependency is missing: say so in one line (our messages include how to install
        # it). Any other ImportError is a bug of ours (main reports it).
        if exc.name not in OPTIONAL_MODULES and "pip install" not in str(exc):
            raise
        error(" ".join(str(exc).split()))
        return EXIT_USAGE
    except BrokenPipeError:  # pragma: no cover - e.g. `posegraph info x.g2o | head -1`
        sys.stderr.close()
        return EXIT_NOT_CONVERGED
    except OSError as exc:
        where = exc.filename if exc.filename is not None else ""
        error(f"{where}: {exc.strerror or exc}" if where else str(exc))
        return EXIT_USAGE
    except ValueError as exc:
        from posegraph.errors import InputError

        if isinstance(exc, InputError):
            error(" ".join(str(exc).split()))
            return EXIT_USAGE
        raise
