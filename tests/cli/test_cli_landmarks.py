"""The commands on landmark graphs: optimize, info, compare, certify, export, plot, batch, end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.io.g2o import read_g2o, write_g2o
from posegraph.lie.group import SE2, SE3
from posegraph.solve import optimize
from tests.cli.conftest import assert_one_error_line, run_cli
from tests.optional import import_or_skip


@pytest.fixture(scope="module")
def landmark_file(tmp_path_factory):
    """A 2D graph with positions, bearing-ranges and bearings (g2o tags where g2o has them)."""
    graph, _, _ = landmark_graph(SE2, 30, 12, ("position", "bearing"), noise=0.02, seed=11, per_landmark=4)
    path = tmp_path_factory.mktemp("landmarks") / "landmarks.g2o"
    write_g2o(path, graph)
    return path


def test_optimize_writes_the_solved_landmarks_and_counts_them_in_chi2(landmark_file, tmp_path):
    out, report = tmp_path / "out.g2o", tmp_path / "report.json"
    run = run_cli("optimize", landmark_file, "-o", out, "--report", report)
    assert run.returncode == 0, run.stderr
    facts = json.loads(report.read_text())
    expected = optimize(read_g2o(landmark_file))
    assert facts["final_cost"] == pytest.approx(expected.final_cost, rel=1e-12)
    assert facts["chi2"] == pytest.approx(2 * facts["final_cost"], rel=1e-12)  # landmark terms included
    assert facts["num_landmarks"] == 12 and facts["chi2_by_kind"]["landmark"]["count"] == facts["num_landmark_measurements"]
    graph = read_g2o(landmark_file)
    rows = sum(f.count * f.measurements.shape[1] for f in graph.landmarks.observations)
    assert facts["dof"] == 3 * graph.num_edges + rows - 3 * (graph.num_vertices - 1) - 2 * graph.landmarks.count
    written = read_g2o(out)
    np.testing.assert_allclose(written.landmarks.positions, expected.points, rtol=0, atol=1e-12)
    assert not np.allclose(written.landmarks.positions, read_g2o(landmark_file).landmarks.positions)
    assert "landmark measurements" in run.stdout


def test_info_names_the_landmarks(landmark_file):
    run = run_cli("info", landmark_file)
    assert run.returncode == 0, run.stderr
    line = next(line for line in run.stdout.splitlines() if line.startswith("landmarks:"))
    assert "12 points (2D), 0 fixed" in line and "EDGE_SE2_XY ×" in line and "EDGE_BEARING_SE2_XY ×" in line


def test_compare_agrees_with_gtsam(landmark_file, tmp_path):
    import_or_skip("gtsam", "posegraph compare")
    report = tmp_path / "compare.json"
    run = run_cli("compare", landmark_file, "-q", "--report", report)
    assert run.returncode == 0, run.stdout + run.stderr
    facts = json.loads(report.read_text())
    assert facts["agree"] and facts["posegraph"]["final_cost"] <= facts["gtsam"]["final_cost"] * (1 + 1e-9)
    shown = run_cli("compare", landmark_file, "--report", tmp_path / "again.json")
    assert "position measurements run as Python CustomFactors" in shown.stderr  # said before the wait


def test_certify_refuses_a_landmark_graph_in_one_line(landmark_file):
    run = run_cli("certify", landmark_file, "-q")
    assert run.returncode == 2
    assert_one_error_line(run, "12 landmarks", "SE-Sync's problem has no variables for")


def test_export_writes_the_landmarks(landmark_file, tmp_path):
    points = tmp_path / "points.txt"
    run = run_cli("export", landmark_file, "--landmarks", points)
    assert run.returncode == 0, run.stderr
    table = np.loadtxt(points)
    graph = read_g2o(landmark_file)
    order = np.argsort(graph.landmarks.ids)
    np.testing.assert_array_equal(table[:, 0], graph.landmarks.ids[order])
    np.testing.assert_array_equal(table[:, 1:], graph.landmarks.positions[order])


def test_export_landmarks_of_a_pose_graph_is_a_usage_error(tmp_path):
    graph, _, _ = landmark_graph(SE3, 5, 2, ("position",), noise=0.01, seed=1)
    from dataclasses import replace

    path = tmp_path / "poses.g2o"
    write_g2o(path, replace(graph, landmarks=None))
    run = run_cli("export", path, "--landmarks", tmp_path / "points.txt")
    assert run.returncode == 2 and not (tmp_path / "points.txt").exists()
    assert_one_error_line(run, "has no landmarks")


def test_optimize_plots_the_landmarks(landmark_file, tmp_path):
    import_or_skip("matplotlib", "posegraph optimize --plot")
    figure = tmp_path / "figure.png"
    run = run_cli("optimize", landmark_file, "-o", tmp_path / "out.g2o", "--plot", figure, "-q")
    assert run.returncode == 0, run.stderr
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_3d_landmark_file_with_offsets_is_solved_to_its_truth(tmp_path):
    graph, truth, points = landmark_graph(SE3, 12, 8, ("position",), noise=0.0, seed=4, offsets=True)
    path, out = tmp_path / "track.g2o", tmp_path / "out.g2o"
    write_g2o(path, graph)
    run = run_cli("optimize", path, "-o", out, "-q", "--init", "odometry")
    assert run.returncode == 0, run.stderr
    solved = read_g2o(out)
    assert "EDGE_SE3_TRACKXYZ" in out.read_text() and "PARAMS_SE3OFFSET" in out.read_text()
    np.testing.assert_allclose(solved.landmarks.positions, points, atol=1e-6)


def test_gnc_names_the_wrong_associations_and_drops_them(tmp_path):
    from tests.robust.test_landmark_gnc import wrong_associations

    graph, _, points = landmark_graph(SE2, 30, 20, ("position",), noise=0.01, seed=0, per_landmark=4)
    bad, wrong = wrong_associations(graph, 0.15, seed=1)
    path, out, report = tmp_path / "bad.g2o", tmp_path / "out.g2o", tmp_path / "report.json"
    write_g2o(path, bad)
    run = run_cli("optimize", path, "-o", out, "--report", report, "--robust", "gnc", "--drop-outliers")
    assert run.returncode == 0, run.stderr
    facts = json.loads(report.read_text())
    read = read_g2o(path)
    lines = read.landmarks.observations[0].lines
    flagged = {row["line"] for row in facts["outlier_landmark_measurements"]}
    assert set(lines[wrong].tolist()) <= flagged and len(flagged - set(lines[wrong].tolist())) <= 2
    assert f"of {read.landmarks.num_measurements} landmark measurements" in run.stdout
    kept = read_g2o(out)
    assert kept.landmarks.num_measurements == read.landmarks.num_measurements - len(flagged)
    np.testing.assert_allclose(kept.landmarks.positions, points, atol=0.05)


def test_covariances_of_a_landmark_graph_hold_the_landmarks_too(landmark_file, tmp_path):
    from posegraph.analysis.covariance import landmark_covariances, marginal_covariances

    out, cov = tmp_path / "out.g2o", tmp_path / "cov.npz"
    run = run_cli("optimize", landmark_file, "-o", out, "--covariances", cov, "-q")
    assert run.returncode == 0, run.stderr
    saved = np.load(cov)
    solved = read_g2o(out)
    expected = optimize(read_g2o(landmark_file))
    graph = read_g2o(landmark_file).with_points(expected.points)
    np.testing.assert_array_equal(saved["landmark_ids"], solved.landmarks.ids)
    np.testing.assert_allclose(saved["landmark_covariances"], landmark_covariances(graph, expected), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(saved["covariances"], marginal_covariances(graph, expected), rtol=1e-9, atol=1e-15)
    assert saved["landmark_covariances"].shape == (12, 2, 2) and np.all(np.linalg.eigvalsh(saved["landmark_covariances"]) > 0)


def test_replay_solves_a_landmark_graph_and_writes_its_landmarks(landmark_file, tmp_path):
    out, report = tmp_path / "out.g2o", tmp_path / "report.json"
    run = run_cli("replay", landmark_file, "-q", "-o", out, "--report", report)
    assert run.returncode == 0, run.stderr
    facts = json.loads(report.read_text())
    expected = optimize(read_g2o(landmark_file))
    # the incremental optimiser's default tolerance (1e-7) on landmark updates too (held analysis): ≤ 1e-6 as asserted for pose graphs
    assert facts["final_cost"] <= expected.final_cost * (1 + 1e-6)
    assert facts["incremental"]["relative_excess"] <= 1e-6
    assert facts["chi2"] == pytest.approx(2 * facts["final_cost"], rel=1e-9)  # the landmark terms counted
    assert facts["chi2_by_kind"]["landmark"]["count"] == facts["num_landmark_measurements"] > 0
    written = read_g2o(out)
    np.testing.assert_array_equal(written.landmarks.ids, read_g2o(landmark_file).landmarks.ids)
    # the cost within 1e-7 leaves points in this graph's flat directions ~3e-4 from the batch optimum's
    np.testing.assert_allclose(written.landmarks.positions, expected.points, rtol=0, atol=2e-3)


def test_pcg_on_a_landmark_graph_is_one_line_and_nothing_written(landmark_file, tmp_path):
    run = run_cli("optimize", landmark_file, "-o", tmp_path / "out.g2o", "--linear-solver", "pcg", "-q")
    assert_one_error_line(run, "linear solver 'pcg' takes pose graphs only")
    assert not (tmp_path / "out.g2o").exists()


@pytest.mark.parametrize("command", [["optimize", "-o", "OUT"], ["optimize", "-o", "OUT", "--init", "odometry"],
                                     ["replay", "-o", "OUT"], ["compare"]])
def test_pcg_on_a_landmark_graph_is_refused_as_soon_as_the_file_is_read(landmark_file, tmp_path, command):
    """No start is made (no `initialised` line, nor compare's run line): the read line, then the refusal naming the file."""
    if command[0] == "compare":
        import_or_skip("gtsam")
    out = tmp_path / "out.g2o"
    argv = [str(out) if a == "OUT" else a for a in command]
    run = run_cli(argv[0], landmark_file, *argv[1:], "--linear-solver", "pcg")
    assert run.returncode == 2, run.stderr
    read, refusal = run.stderr_lines
    assert read.startswith(f"read {landmark_file}: 30 vertices"), run.stderr
    assert refusal == (f"posegraph: error: {landmark_file}: linear solver 'pcg' takes pose graphs only (its multigrid "
                       "knows blocks of one size); use 'cholmod' or 'scipy' (or 'auto') for a graph with landmarks")
    assert list(tmp_path.iterdir()) == []
