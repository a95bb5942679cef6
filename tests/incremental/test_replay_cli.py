"""``posegraph replay`` end to end on a shared graph."""

from __future__ import annotations

import json

import numpy as np
import pytest

from posegraph.cli import main


def test_replay_intel_end_to_end(shared_dataset, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    path = shared_dataset("intel")
    out, report, plot = tmp_path / "out.g2o", tmp_path / "r.json", tmp_path / "r.png"
    status = main(["replay", str(path), "--batch-size", "25", "--check-every", "600", "-o", str(out),
                   "--report", str(report), "--plot", str(plot)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "per update mean" in printed and "p99" in printed and "final cost" in printed
    data = json.loads(report.read_text())
    assert abs(data["final_cost"] - 22.50211654) < 1e-6
    assert data["incremental"]["relative_excess"] <= 1e-6
    assert set(data["incremental"]["update_seconds"]) >= {"mean", "median", "p99", "max"}
    assert len(data["incremental"]["checks"]) >= 2 and plot.stat().st_size > 0
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.residuals import cost

    written = read_g2o(out)
    assert written.num_vertices == 1728 and abs(cost(written) - data["final_cost"]) < 1e-6 * data["final_cost"]


def test_replay_refuses_bad_options(shared_dataset, tmp_path):
    path = shared_dataset("intel")
    assert main(["replay", str(path), "--tolerance", "0"]) == 2
    assert main(["replay", str(path), "-o", str(path)]) == 2


def test_the_help_states_the_optimisers_default_tolerance(shared_dataset, tmp_path):
    """The CLI leaves --tolerance to the optimiser (help must come without numpy), so its help text
    repeats the default: it must be the library's."""
    import argparse

    from posegraph.cli import replay as replay_cli
    from posegraph.incremental.optimizer import DEFAULT_TOLERANCE

    parser = argparse.ArgumentParser()
    replay_cli.add_arguments(parser)
    action = next(a for a in parser._actions if "--tolerance" in a.option_strings)
    stated = float(action.help.split("(default ")[1].split(";")[0])
    assert stated == DEFAULT_TOLERANCE and action.default is None
    report = tmp_path / "r.json"
    assert main(["replay", str(shared_dataset("intel")), "--batch-size", "400", "-q", "--report", str(report)]) == 0
    assert json.loads(report.read_text())["incremental"]["tolerance"] == DEFAULT_TOLERANCE
