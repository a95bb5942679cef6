"""The command line on graphs with priors, TORO files and landmark graphs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from posegraph.io.g2o import read_g2o
from tests.cli.conftest import run_cli
from tests.io.test_g2o_priors import CHAIN_2D, PRIORS_2D
from tests.io.test_g2o_read import CHAIN
from tests.io.test_g2o_toro import TORO_ENTRIES, toro_file

PRIORS_3D = "\n".join([
    "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1",
    "EDGE_SE3_XYZ_PRIOR 0 0 5 -3 2 4 0 0 4 0 4",
    "EDGE_SE3_XYZ_PRIOR 1 0 6 -3 2 4 0 0 4 0 4",
    "EDGE_SE3_XYZ_PRIOR 2 0 6 -2 2.5 4 0 0 4 0 4",
])


def test_optimize_reports_the_cost_with_the_priors_and_writes_them_back(tmp_path):
    source, output, report = tmp_path / "in.g2o", tmp_path / "out.g2o", tmp_path / "report.json"
    source.write_text(CHAIN + "\n" + PRIORS_3D + "\n")
    run = run_cli("optimize", source, "-o", output, "--report", report, "--stats")
    assert run.returncode == 0, run.stderr
    result = read_g2o(output)
    from posegraph.solve.residuals import cost

    data = json.loads(report.read_text())
    assert data["final_cost"] == pytest.approx(cost(result), rel=1e-9)
    assert "+ 3·3 position priors − 6·3 free poses = 9" in run.stdout and "prior" in run.stdout
    # the priors moved the graph: vertex 0 (held without priors) is near its GNSS fix, not at the origin
    assert np.linalg.norm(result.poses[0, :3, 3] - [5, -3, 2]) < 1.0
    assert output.read_text().splitlines()[-4:] == PRIORS_3D.splitlines()


def test_info_counts_the_priors(tmp_path):
    source = tmp_path / "in.g2o"
    source.write_text(CHAIN_2D + "\n" + PRIORS_2D + "\n")
    run = run_cli("info", source)
    assert run.returncode == 0, run.stderr
    assert "1 pose, 2 position" in run.stdout


def test_eval_against_the_priors_of_the_result(tmp_path):
    source, output = tmp_path / "in.g2o", tmp_path / "out.g2o"
    source.write_text(CHAIN + "\n" + PRIORS_3D + "\n")
    assert run_cli("optimize", source, "-o", output).returncode == 0
    run = run_cli("eval", output, "--priors", "--json")
    assert run.returncode == 0, run.stderr
    data = json.loads(run.stdout)
    graph = read_g2o(output)
    errors = np.linalg.norm(graph.poses[graph.priors.position_vertex, :3, 3] - graph.priors.position_measurements, axis=1)
    assert data["num_matched"] == 3
    assert data["ate_translation"]["rmse"] == pytest.approx(np.sqrt(np.mean(errors**2)), rel=1e-9)
    refused = run_cli("eval", output, source, "--priors")
    assert refused.returncode == 2 and "not both" in refused.stderr


def test_toro_order_option_and_landmark_lines(tmp_path):
    ambiguous = tmp_path / "ambiguous.graph"
    ambiguous.write_text(toro_file("2 0 1 2 0 1"))
    run = run_cli("optimize", ambiguous, "-o", tmp_path / "out.g2o")
    assert run.returncode == 2 and f"{ambiguous}:5:" in run.stderr and not (tmp_path / "out.g2o").exists()
    assert run_cli("optimize", ambiguous, "-o", tmp_path / "out.g2o", "--edge2-information", "toro").returncode == 0
    landmarks = tmp_path / "landmarks.graph"
    landmarks.write_text(toro_file(TORO_ENTRIES, *[f"LANDMARK2 {k} 10 1.0 2.0 1 0 1" for k in range(3)]))
    from posegraph.io.g2o import read_g2o

    assert read_g2o(landmarks).landmarks.num_measurements == 3  # read now, no refusal (solving them: the solver's part)
    run = run_cli("optimize", landmarks, "-o", tmp_path / "out2.g2o", "--poses-only")
    assert run.returncode == 0 and "LANDMARK2 ×3" in run.stderr


def test_robust_gnc_reports_and_drops_a_wrong_prior(tmp_path):
    from posegraph.io.g2o import write_g2o
    from tests.robust.test_priors_gnc import graph_with_priors

    graph, _, outliers, priors = graph_with_priors(1)
    source, output, report = tmp_path / "in.g2o", tmp_path / "out.g2o", tmp_path / "report.json"
    write_g2o(source, graph)
    run = run_cli("optimize", source, "-o", output, "--robust", "gnc", "--drop-outliers", "--report", report)
    assert run.returncode == 0, run.stderr
    assert f"1 of {len(priors)} priors" in run.stdout and "far above" not in run.stderr
    data = json.loads(report.read_text())
    assert data["outlier_priors"] == [2] and sorted(data["outlier_edges"]) == sorted(outliers.tolist())
    written = read_g2o(output).priors
    assert written.num_position == len(priors) - 1 and 8 not in written.position_vertex.tolist()  # vertex of prior 2
