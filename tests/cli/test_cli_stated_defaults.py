"""The defaults the help texts and docs/cli.md state are the ones the command and the library use."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from posegraph.cli.parser import build_parser

CLI_DOC = Path(__file__).resolve().parents[2] / "docs" / "cli.md"
NUMBER = r"[0-9][0-9.]*(?:e-?[0-9]+)?"


def library_defaults() -> dict:
    """``{option dest: the value used when the option is not given}`` for the options whose parser default
    is None because the library's own default applies."""
    from posegraph.certification.verify import DEFAULT_TOLERANCE as CERTIFY_ETA
    from posegraph.incremental.optimizer import DEFAULT_TOLERANCE as INCREMENTAL_TOLERANCE
    from posegraph.robust.active import DEFAULT_REANALYSE_FRACTION
    from posegraph.solve import SolverParams

    solver = SolverParams()
    return {"relative_tolerance": solver.relative_tolerance, "absolute_tolerance": solver.absolute_tolerance,
            "eta": CERTIFY_ETA, "tolerance": INCREMENTAL_TOLERANCE, "reanalyse_fraction": DEFAULT_REANALYSE_FRACTION}


def _options():
    parser = build_parser()
    for command, subparser in parser._subparsers._group_actions[0].choices.items():
        for action in subparser._actions:
            match = re.search(r"\(default:? ([^)]*)\)", action.help or "")
            if match:
                yield command, action, match.group(1)


def _effective(action, defaults: dict):
    return action.default if action.default is not None else defaults.get(action.dest)


def _same(stated: str, value) -> bool:
    """Whether the help's ``(default …)`` text gives ``value``: its first number, or its first word."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        number = re.search(NUMBER, stated)
        return number is not None and math.isclose(float(number.group()), value, rel_tol=1e-12)
    return stated.split(":")[0].split()[0] == str(value)


def test_every_default_a_help_text_states_is_the_one_used():
    defaults, checked = library_defaults(), []
    for command, action, stated in _options():
        value = _effective(action, defaults)
        if value is None:  # described, not a value: "the loss's own", "one per core", "file names"
            continue
        assert _same(stated, value), (command, action.dest, stated, value)
        checked.append(action.dest)
    assert {"max_iterations", "relative_tolerance", "absolute_tolerance", "eta", "max_rank", "tolerance",
            "max_time_diff", "reanalyse_fraction"} <= set(checked)


def test_eval_time_difference_is_evos():
    from posegraph.io.trajectory import EVO_MAX_TIME_DIFF

    args = build_parser(only="eval").parse_args(["eval", "est.txt", "gt.txt"])
    assert args.max_time_diff == EVO_MAX_TIME_DIFF


def _parse(argv: list):
    return build_parser(only=argv[0]).parse_args(argv)


def _doc_value(pattern: str) -> str:
    text = " ".join(CLI_DOC.read_text().split())  # lines joined: a statement may wrap
    match = re.search(pattern, text)
    assert match, pattern
    return match.group(1)


def _gnc_scale() -> float:
    from posegraph.robust.gnc import GncParams, inlier_thresholds

    return math.sqrt(inlier_thresholds(6, 1, GncParams())[0])


DOC_STATEMENTS = [
    (r"\(`SolverParams`: relative (" + NUMBER + "),", lambda: library_defaults()["relative_tolerance"]),
    (r"\(`SolverParams`: relative \S+ absolute (" + NUMBER + "),", lambda: library_defaults()["absolute_tolerance"]),
    (r"\(`SolverParams`: [^)]*at most ([0-9]+) iterations\)", lambda: _parse(["optimize", "i", "-o", "o"]).max_iterations),
    (r"`--linear-solver`: `(\w+)` \(the default\)", lambda: _parse(["optimize", "i", "-o", "o"]).linear_solver),
    (r"\(`--init (\w+)`, the default", lambda: _parse(["optimize", "i", "-o", "o"]).init),
    (r"`--known-inliers` \(default the (\w+) edges\)", lambda: _parse(["optimize", "i", "-o", "o"]).known_inliers),
    (r"`--robust (\w+)` \(the default\)", lambda: _parse(["optimize", "i", "-o", "o"]).robust),
    (r"`--reanalyse-fraction F` \(gnc only, F in \[0, 1\], default (" + NUMBER + r")\)", lambda: library_defaults()["reanalyse_fraction"]),
    (r"√χ²₀\.₉₉\(6\) = (" + NUMBER + r")\)", _gnc_scale),
    (r"--cost-tolerance` \(default \*\*(" + NUMBER + r")\*\*\)", lambda: _parse(["compare", "i"]).cost_tolerance),
    (r"ETA·F\(x\) \(default (" + NUMBER + ");", lambda: library_defaults()["eta"]),
    (r"`--max-rank R` \(default (" + NUMBER + "),", lambda: _parse(["certify", "i"]).max_rank),
]


@pytest.mark.parametrize("pattern, used", DOC_STATEMENTS, ids=[f"statement{k}" for k in range(len(DOC_STATEMENTS))])
def test_every_default_docs_cli_states_is_the_one_used(pattern, used):
    stated = _doc_value(pattern)
    value = used()
    if isinstance(value, str):
        assert stated == value
    else:
        digits = len(stated.split(".")[1]) if "." in stated and "e" not in stated else None
        assert (round(value, digits) == float(stated)) if digits else math.isclose(float(stated), value, rel_tol=1e-12), \
            (pattern, stated, value)
