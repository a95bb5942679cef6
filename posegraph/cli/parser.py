"""The command-line parser: the top-level options and help, and one subparser per subcommand module.

Each subcommand is a module of :mod:`posegraph.cli` with ``NAME``, ``HELP``, ``DESCRIPTION``,
``EXAMPLES``, ``add_arguments(parser)`` and ``run(args) -> exit status``; adding one is a new
module and a line in :data:`COMMANDS`.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from posegraph.cli.common import PROG, ArgumentParser, quiet_option

COMMANDS = ("optimize", "batch", "compare", "verify-jacobians", "info", "eval", "plot", "export", "certify", "replay")
"""The subcommands, in the order of ``--help``; ``posegraph.cli.<name with _ for ->`` implements each."""

DESCRIPTION = "SE(3) pose-graph optimisation over g2o files, cross-checked against gtsam."
EPILOG = """exit status: 0 success, 1 not converged / figure not drawn / checks or comparison failed
(results still written), 2 bad input or usage (nothing written), 3 internal error (rerun with
--debug), 130 interrupted.

examples:
  posegraph info sphere2500.g2o
  posegraph optimize sphere2500.g2o -o sphere2500-opt.g2o --report report.json --plot before-after.png
  posegraph batch data/*.g2o -o results/ --report summary.json   (many files, in parallel on Dask)
  posegraph compare parking-garage.g2o
  posegraph certify sphere2500.g2o --report certificate.json
  posegraph eval sphere2500-opt.g2o ground-truth.g2o
  posegraph <command> --help      (options and examples of one command)
"""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command-line parser; ``only`` (a subcommand's name) builds that subcommand alone.

    ``main`` passes the subcommand the command line names, if any: the other six would cost ~4 ms
    of argparse set-up on every run for nothing (their options are never parsed). Without a
    known subcommand (``--help``, a typo, nothing) the whole parser is built, so the help and
    the "invalid choice" error list every command.
    """
    parser = ArgumentParser(prog=PROG, description=DESCRIPTION, epilog=EPILOG, formatter_class=HelpFormatter)
    parser.add_argument("--version", action=_VersionAction, nargs=0, help="print the version and exit")
    _debug_option(parser)
    sub = parser.add_subparsers(dest="command", metavar="<command>", parser_class=ArgumentParser)
    sub.required = True
    for name in COMMANDS if only is None else (only,):
        _add_command(sub, command_module(name))
    return parser


def command_module(name: str):
    """The module implementing subcommand ``name`` (``verify-jacobians`` → ``posegraph.cli.verify_jacobians``)."""
    return importlib.import_module("posegraph.cli." + name.replace("-", "_"))


def _add_command(sub, module) -> None:
    import textwrap

    p = sub.add_parser(
        module.NAME, help=module.HELP, description=textwrap.fill(module.DESCRIPTION, width=88),
        epilog="examples:\n" + module.EXAMPLES.strip("\n") + "\n",
        formatter_class=HelpFormatter,
    )
    module.add_arguments(p)
    if "--quiet" not in p._option_string_actions:  # optimize and batch have it among their per-file options
        quiet_option(p)
    _debug_option(p)
    p.set_defaults(func=module.run)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """argparse's formatter keeping descriptions and epilogs as written, as wide as the terminal.

    argparse makes one for every ``add_argument`` (to check the metavar) and, without a width,
    imports :mod:`shutil` for ``shutil.get_terminal_size()`` — with bz2, lzma and fnmatch, ~2 ms of
    every command, which nothing else on the way to a result needs. The width here is the one
    shutil would give (:func:`terminal_columns`), less 2 as argparse takes it.
    """

    def __init__(self, prog, indent_increment=2, max_help_position=24, width=None):
        super().__init__(prog, indent_increment, max_help_position, terminal_columns() - 2 if width is None else width)


def terminal_columns() -> int:
    """``shutil.get_terminal_size().columns``: ``$COLUMNS`` if a positive integer, else the width of
    the terminal on standard output, else 80."""
    try:
        columns = int(os.environ.get("COLUMNS", 0))
    except ValueError:
        columns = 0
    if columns <= 0:
        try:
            columns = os.get_terminal_size(sys.__stdout__.fileno()).columns
        except (AttributeError, ValueError, OSError):  # no stdout, or not a terminal
            columns = 0
    return columns if columns > 0 else 80


def _debug_option(p: argparse.ArgumentParser) -> None:
    """``--debug`` (read by :func:`posegraph.cli.program.main` from the raw command line)."""
    p.add_argument("--debug", action="store_true", help="on an internal error, show its traceback")


def _version() -> str:
    try:
        from posegraph import __version__  # the package's __init__ imports nothing heavy

        return __version__
    except ImportError:  # e.g. a stale editable install that maps posegraph as a namespace package
        from importlib.metadata import version

        return version("posegraph")


class _VersionAction(argparse.Action):
    """``--version``, looked up only when asked for (keeps ``--help`` free of metadata imports)."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{PROG} {_version()}")
        parser.exit()
