"""What every subcommand shares: ``-q``/``--quiet`` and usage errors that point at the subcommand's help."""

from __future__ import annotations

from pathlib import Path

import pytest

from posegraph import cli
from posegraph.cli.common import QUIET_HELP
from posegraph.cli.parser import COMMANDS, build_parser

EXAMPLE = Path(__file__).resolve().parents[2] / "datasets" / "example_sphere.g2o"
GROUND_TRUTH = EXAMPLE.with_name("example_sphere_groundtruth.g2o")

REQUIRED = {
    "optimize": ["in.g2o", "-o", "out.g2o"], "batch": ["in.g2o", "-o", "out"], "compare": ["in.g2o"],
    "verify-jacobians": [], "info": ["in.g2o"], "eval": ["est.g2o", "gt.g2o"], "plot": ["in.g2o", "-o", "f.png"],
    "export": ["in.g2o", "--tum", "t.txt"], "certify": ["in.g2o"], "replay": ["in.g2o"],
}
"""The fewest arguments each subcommand parses (nothing is read: only the parser runs)."""


def test_every_command_is_listed_here():
    assert sorted(REQUIRED) == sorted(COMMANDS)


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("flag", ["-q", "--quiet"])
def test_every_command_takes_quiet_with_the_same_help(command, flag):
    parser = build_parser(only=command)
    args = parser.parse_args([command, *REQUIRED[command], flag])
    assert args.quiet is True
    assert parser.parse_args([command, *REQUIRED[command]]).quiet is False
    subparser = parser._subparsers._group_actions[0].choices[command]
    assert subparser._option_string_actions["--quiet"].help == QUIET_HELP


def _quiet_run(capsys, argv) -> str:
    assert cli.main(argv) == 0, capsys.readouterr().err
    captured = capsys.readouterr()
    assert "error" not in captured.err, captured.err
    return captured.out


def test_quiet_info_and_eval_still_print_their_tables(capsys):
    assert _quiet_run(capsys, ["info", str(EXAMPLE), "-q"]).startswith("file:")
    assert "ATE translation" in _quiet_run(capsys, ["eval", str(EXAMPLE), str(GROUND_TRUTH), "--quiet"])


def test_quiet_plot_and_export_write_their_outputs(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    _quiet_run(capsys, ["plot", str(EXAMPLE), "-o", str(tmp_path / "f.png"), "-q"])
    _quiet_run(capsys, ["export", str(EXAMPLE), "--tum", str(tmp_path / "t.txt"), "-q"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "t.txt"]


@pytest.mark.parametrize("command", ["info", "eval", "optimize", "certify"])
def test_an_unknown_option_points_at_the_subcommands_help(command, capsys):
    assert cli.main([command, *REQUIRED[command], "--no-such-option"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"posegraph: error: unrecognized arguments: --no-such-option (see 'posegraph {command} --help')")


def test_an_extra_file_points_at_the_subcommands_help(capsys):
    assert cli.main(["info", str(EXAMPLE), str(EXAMPLE)]) == 2
    assert "(see 'posegraph info --help')" in capsys.readouterr().err


def test_a_mistake_before_any_subcommand_points_at_the_top_level_help(capsys):
    assert cli.main(["optimise", "in.g2o"]) == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'optimise'" in err and "(see 'posegraph --help')" in err
