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
