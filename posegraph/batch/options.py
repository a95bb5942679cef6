"""``optimize``'s per-file options as keywords of :func:`posegraph.optimize_many`, and back to a command line.

The options are defined once, by :func:`posegraph.cli.optimize.file_options`; this module reads
their names, defaults and kinds off a parser built by that function, so ``posegraph batch``,
``optimize_many`` and ``posegraph optimize`` cannot drift apart. Each file is then run as the
command line ``posegraph optimize IN -o OUT --report R [options]`` (:mod:`posegraph.batch.task`).
"""

from __future__ import annotations

import argparse

__all__ = ["BatchError", "file_option_defaults", "option_argv", "check_options"]


class BatchError(ValueError):
    """A batch that cannot start: an option ``optimize`` refuses, two inputs sharing outputs, an
    output that would overwrite an input, a scheduler that cannot be reached. Nothing is run."""


def _file_option_actions() -> dict:
    """``{dest: argparse.Action}`` of :func:`posegraph.cli.optimize.file_options`."""
    from posegraph.cli.common import ArgumentParser
    from posegraph.cli.optimize import file_options

    parser = ArgumentParser(add_help=False)
    file_options(parser)
    return {action.dest: action for action in parser._actions}


def file_option_defaults() -> dict:
    """``{name: default}`` of every per-file option (``max_iterations``: 100, ``robust``: ``"none"`` …)."""
    return {dest: action.default for dest, action in _file_option_actions().items()}


def option_argv(options: dict) -> list[str]:
    """The ``posegraph optimize`` arguments giving ``options`` (names as in :func:`file_option_defaults`);
    options at their default are left out. Raises :class:`TypeError` for an unknown name."""
    actions = _file_option_actions()
    unknown = sorted(set(options) - set(actions))
    if unknown:
        raise TypeError(f"unknown optimize option{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                        f"known: {', '.join(sorted(actions))}")
    argv = []
    for dest, action in actions.items():  # in the parser's order, so equal options give equal commands
        value = options.get(dest, action.default)
        if value == action.default or value is None:
            continue
        flag = max(action.option_strings, key=len)  # the long form: --max-iterations, not -i
        if isinstance(action, argparse._StoreTrueAction):
            argv += [flag] if value else []
        elif isinstance(value, (list, tuple)):
            argv += [flag, *map(str, value)] if value else []
        else:
            argv += [flag, str(value)]  # str(float) is its shortest round-trip repr
    return argv


def check_options(argv: list[str], input_path: str, output_path: str) -> None:
    """Parse ``posegraph optimize input -o output *argv`` as ``optimize`` will and apply its option checks:
    a :class:`BatchError` with ``optimize``'s message for a value or combination it refuses."""
    from posegraph.cli.common import UsageError
    from posegraph.cli.parser import build_parser
    from posegraph.cli.robust import check_robust_options

    try:
        args = build_parser(only="optimize").parse_args(["optimize", input_path, "-o", output_path, *argv])
        check_robust_options(args)
    except UsageError as exc:
        raise BatchError(str(exc)) from None
