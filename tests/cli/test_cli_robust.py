"""`posegraph optimize --robust …` end to end: GNC finds the injected outliers, the report lists
them, --drop-outliers writes the graph without them, bad values exit 2 with one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.cli.conftest import assert_one_error_line, run_cli


@pytest.fixture(scope="module")
def corrupted(tmp_path_factory):
    """A synthetic grid with 20 % injected outliers, written as g2o: ``(path, outlier indices)``."""
    from datasets.synthetic import grid, inject_outliers
    from posegraph.io.g2o import write_g2o

    graph, indices = inject_outliers(grid(4, 4, 3, seed=1).graph, fraction=0.2, seed=1)
    path = tmp_path_factory.mktemp("robust") / "grid_outliers.g2o"
    write_g2o(path, graph)
    return path, indices


def test_gnc_reports_and_drops_exactly_the_outliers(corrupted, tmp_path):
    from posegraph.io.g2o import read_g2o

    path, indices = corrupted
    out, report = tmp_path / "out.g2o", tmp_path / "report.json"
    run = run_cli("optimize", path, "-o", out, "--robust", "gnc", "--report", report, "--drop-outliers")
    assert run.returncode == 0, run.stderr
    assert json.loads(report.read_text())["outlier_edges"] == indices.tolist()
    loops = int(np.count_nonzero(~read_g2o(path).odometry_mask()))
    assert f"outliers:       {len(indices)} of {loops} loop closures" in run.stdout
    kept = read_g2o(path).num_edges - len(indices)
    assert f"dof = 6·{kept} edges" in run.stdout  # χ² over the inliers
    gnc_lines = [line for line in run.stderr_lines if line.strip().startswith(("gnc ", "tls "))]
    assert gnc_lines and all("mu " in line and "inliers " in line and "cost " in line for line in gnc_lines)
    source, written = read_g2o(path), read_g2o(out)
    keep = np.setdiff1d(np.arange(source.num_edges), indices)
    assert written.num_edges == len(keep)
    np.testing.assert_array_equal(written.measurements, source.measurements[keep])
    np.testing.assert_array_equal(written.information, source.information[keep])
    np.testing.assert_array_equal(source.ids[written.edge_from], source.ids[source.edge_from[keep]])


def test_gnc_results_do_not_depend_on_when_the_sparsity_is_analysed(corrupted, tmp_path):
    """Analyse once (0), on every change of the active edges (1), and the default: the same outliers,
    the same poses to round-off."""
    from posegraph.io.g2o import read_g2o

    path, indices = corrupted
    poses = []
    for fraction in ("0", "1", None):
        out, report = tmp_path / f"out_{fraction}.g2o", tmp_path / f"r_{fraction}.json"
        extra = [] if fraction is None else ["--reanalyse-fraction", fraction]
        run = run_cli("optimize", path, "-o", out, "--robust", "gnc", "--report", report, "-q", *extra)
        assert run.returncode == 0, run.stderr
        assert json.loads(report.read_text())["outlier_edges"] == indices.tolist()
        poses.append(read_g2o(out).poses)
    np.testing.assert_allclose(poses[0], poses[1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(poses[2], poses[1], rtol=0, atol=1e-9)


def test_without_drop_outliers_every_edge_is_written(corrupted, tmp_path):
    from posegraph.io.g2o import read_g2o

    path, _ = corrupted
    out = tmp_path / "out.g2o"
    assert run_cli("optimize", path, "-o", out, "--robust", "gnc", "-q").returncode == 0
    assert read_g2o(out).num_edges == read_g2o(path).num_edges


def test_m_estimator_report_lists_low_weight_edges(corrupted, tmp_path):
    path, indices = corrupted
    report = tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", tmp_path / "o.g2o", "--robust", "cauchy", "--robust-scale", "3", "-q", "--report", report)
    assert run.returncode == 0, run.stderr
    listed = json.loads(report.read_text())["outlier_edges"]
    assert set(indices.tolist()) <= set(listed)  # every wrong loop closure ends with weight < 0.5


def test_default_report_has_no_robust_fields(corrupted, tmp_path):
    path, _ = corrupted
    report = tmp_path / "r.json"
    assert run_cli("optimize", path, "-o", tmp_path / "o.g2o", "-q", "--report", report).returncode == 0
    assert "outlier_edges" not in json.loads(report.read_text())


@pytest.mark.parametrize(
    "args, fragments",
    [
        (["--robust", "huber", "--robust-scale", "0"], ["--robust-scale", "> 0"]),
        (["--robust", "cauchy", "--robust-scale", "-1"], ["--robust-scale", "> 0"]),
        (["--robust", "welsch"], ["--robust", "invalid choice", "gnc"]),
        (["--drop-outliers"], ["--drop-outliers", "--robust"]),
        (["--robust-scale", "2"], ["--robust-scale", "--robust"]),
        (["--robust", "gnc", "--reanalyse-fraction", "1.5"], ["--reanalyse-fraction", "[0, 1]"]),
        (["--robust", "huber", "--reanalyse-fraction", "0.5"], ["--reanalyse-fraction", "--robust gnc"]),
        (["--strict-known-inliers"], ["--strict-known-inliers", "--robust gnc"]),
    ],
)
def test_bad_values_exit_2_with_one_line(corrupted, tmp_path, args, fragments):
    path, _ = corrupted
    out = tmp_path / "o.g2o"
    assert_one_error_line(run_cli("optimize", path, "-o", out, *args), *fragments)
    assert not out.exists()


def test_drop_outliers_never_overwrites_the_input(corrupted, tmp_path):
    import shutil

    path = tmp_path / "in.g2o"
    shutil.copy(corrupted[0], path)
    before = path.read_bytes()
    run = run_cli("optimize", path, "-o", path, "--robust", "gnc", "--drop-outliers", "--force")
    assert_one_error_line(run, "--drop-outliers", "input")
    assert path.read_bytes() == before


@pytest.fixture(scope="module")
def wrong_odometry(tmp_path_factory):
    """A grid with 20 % outliers whose odometry edges on two lines are wrong (no parallel edge tells):
    ``(path, the two edges' file lines, their indices, the outlier indices)``."""
    from dataclasses import replace

    from datasets.synthetic import grid, inject_outliers, random_relative_poses
    from posegraph.io.g2o import read_g2o, write_g2o

    graph, indices = inject_outliers(grid(4, 4, 3, seed=3).graph, fraction=0.2, seed=1)
    rng = np.random.default_rng(5)
    wrong = np.sort(rng.choice(np.flatnonzero(graph.odometry_mask())[5:-5], 2, replace=False))
    measurements = graph.measurements.copy()
    measurements[wrong] = random_relative_poses(rng, 2, 5.0)
    path = tmp_path_factory.mktemp("trust") / "wrong_odometry.g2o"
    write_g2o(path, replace(graph, measurements=measurements, edge_source=None))
    return path, read_g2o(path).edge_lines[wrong].tolist(), wrong, indices


def test_gnc_releases_wrong_odometry_names_its_lines_and_reports_it(wrong_odometry, tmp_path):
    path, lines, wrong, indices = wrong_odometry
    report = tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", tmp_path / "o.g2o", "--robust", "gnc", "--report", report, "-q")
    assert run.returncode == 0, run.stderr
    released = [line for line in run.stderr_lines if "were released" in line]
    assert len(released) == 1 and all(str(n) in released[0] for n in lines), run.stderr
    known = json.loads(report.read_text())["known_inliers"]
    assert set(wrong.tolist()) <= set(known["released"]) and known["suspicious"] == []
    assert known["mode"] == "odometry" and known["strict"] is False
    assert json.loads(report.read_text())["outlier_edges"] == sorted(set(indices.tolist()) | set(wrong.tolist()))


def test_strict_known_inliers_keeps_them_and_warns(wrong_odometry, tmp_path):
    path, lines, wrong, _ = wrong_odometry
    report = tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", tmp_path / "o.g2o", "--robust", "gnc", "--strict-known-inliers", "--report", report, "-q")
    assert run.returncode == 0, run.stderr
    failing = [line for line in run.stderr_lines if "fail the inlier test" in line]
    assert len(failing) == 1 and all(str(n) in failing[0] for n in lines), run.stderr
    known = json.loads(report.read_text())["known_inliers"]
    assert known["released"] == [] and set(wrong.tolist()) <= set(known["suspicious"]) and known["strict"] is True


def test_a_clean_gnc_run_warns_of_nothing(corrupted, tmp_path):
    path, _ = corrupted
    report = tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", tmp_path / "o.g2o", "--robust", "gnc", "--report", report, "-q")
    assert run.returncode == 0 and run.stderr == "", run.stderr
    known = json.loads(report.read_text())["known_inliers"]
    assert known["released"] == known["suspicious"] == [] and 0 < known["chi2_per_dof"] < 10
