"""Every command on 2D (SE(2)) graphs, end to end: intel from the shared datasets and a small synthetic one."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from tests.cli.conftest import run_cli

INTEL_OPTIMUM = 22.50211654  # gtsam 4.3 LM, ../shared/datasets/README.md


def table_row(stdout: str, label: str) -> list[float]:
    match = re.search(rf"^{re.escape(label)}\s+(.*)$", stdout, re.MULTILINE)
    assert match, (label, stdout)
    return [float(x) for x in match.group(1).split()]


@pytest.fixture(scope="module")
def planar(tmp_path_factory):
    """A noisy synthetic Manhattan world (300 poses) and its ground truth, as g2o files."""
    from datasets.synthetic import generate, write_dataset

    folder = tmp_path_factory.mktemp("planar")
    graph_path, truth_path = write_dataset(folder / "city.g2o", generate("manhattan", 300, seed=4))
    return graph_path, truth_path


def test_optimize_writes_a_2d_file_at_gtsams_optimum(tmp_path, shared_dataset):
    out, report = tmp_path / "out.g2o", tmp_path / "report.json"
    run = run_cli("optimize", shared_dataset("intel"), "-o", out, "--report", report, "--quiet")
    assert run.returncode == 0, run.stderr
    lines = out.read_text().splitlines()
    assert lines[0].startswith("VERTEX_SE2 0 ") and len(lines[0].split()) == 5
    assert all(line.split()[0] in ("VERTEX_SE2", "EDGE_SE2") for line in lines)
    final = json.loads(report.read_text())["final_cost"]
    assert INTEL_OPTIMUM * (1 - 1e-6) <= final <= INTEL_OPTIMUM * (1 + 1e-6)


def test_info_names_the_group_and_the_3x3_blocks(shared_dataset):
    run = run_cli("info", shared_dataset("intel"))
    assert run.returncode == 0, run.stderr
    assert "(2D: SE(2) poses)" in run.stdout
    assert "information, 3x3:" in run.stdout and "nan" not in run.stdout
    assert "1728 (ids 0..1727" in run.stdout
    as_json = json.loads(run_cli("info", shared_dataset("intel"), "--json").stdout)
    assert as_json["group"] == "SE2"
    assert as_json["information"]["rotation"]["diagonal_min"] > 0


def test_eval_aligns_in_the_plane_and_reports_zero_for_a_moved_copy(tmp_path, planar):
    from posegraph.io.g2o import read_g2o, write_g2o
    from posegraph.lie import se2

    _, truth_path = planar
    truth = read_g2o(truth_path)
    moved = tmp_path / "moved.g2o"
    write_g2o(moved, truth, se2.from_xytheta([4.0, -2.0, 2.5]) @ truth.poses)
    run = run_cli("eval", moved, truth_path)
    assert run.returncode == 0, run.stderr
    assert "least-squares SE(2) alignment" in run.stdout
    for label in ("ATE translation (m)", "ATE rotation (deg)", "RPE translation (m)", "RPE rotation (deg)"):
        assert max(table_row(run.stdout, label)) < 1e-9, label
    unaligned = run_cli("eval", moved, truth_path, "--no-align")
    assert table_row(unaligned.stdout, "ATE translation (m)")[0] > 1.0


def test_optimising_brings_the_estimate_closer_to_the_truth(tmp_path, planar):
    graph_path, truth_path = planar
    out = tmp_path / "out.g2o"
    assert run_cli("optimize", graph_path, "-o", out, "--quiet").returncode == 0
    before = table_row(run_cli("eval", graph_path, truth_path).stdout, "ATE translation (m)")[0]
    after = table_row(run_cli("eval", out, truth_path).stdout, "ATE translation (m)")[0]
    assert after < 0.5 * before


def test_plot_draws_a_top_view(tmp_path, planar):
    pytest.importorskip("matplotlib")
    graph_path, truth_path = planar
    figure = tmp_path / "city.png"
    run = run_cli("plot", graph_path, truth_path, "-o", figure)
    assert run.returncode == 0, run.stderr
    assert run.stderr_lines == []  # no matplotlib warning about fixed limits
    assert figure.stat().st_size > 10_000


def test_export_embeds_the_plane_at_z_zero(tmp_path, planar):
    graph_path, _ = planar
    tum = tmp_path / "city.tum"
    run = run_cli("export", graph_path, "--tum", tum)
    assert run.returncode == 0, run.stderr
    rows = np.loadtxt(tum)
    assert rows.shape == (300, 8)
    np.testing.assert_array_equal(rows[:, 3], 0.0)  # z
    np.testing.assert_array_equal(rows[:, 4:6], 0.0)  # qx, qy: rotations about z only


def test_compare_agrees_with_gtsams_pose2_path_from_both_starts(shared_dataset):
    pytest.importorskip("gtsam")
    for start in ("same", "own"):
        run = run_cli("compare", shared_dataset("intel"), "--quiet", "--gtsam-start", start)
        assert run.returncode == 0, run.stdout + run.stderr
        assert "agree" in run.stdout
        ours, theirs = table_row(run.stdout, "final cost")
        assert ours <= theirs * (1 + 1e-6)


def test_verify_jacobians_passes_on_a_2d_graph(shared_dataset):
    run = run_cli("verify-jacobians", shared_dataset("intel"), "--samples", "40")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "gtsam BetweenFactorPose2" in run.stdout and "edges of intel.g2o" in run.stdout
    assert re.search(r"^(\d+) of \1 checks within tolerance$", run.stdout, re.MULTILINE)
