"""`posegraph certify` and `optimize --certify` end to end: exit statuses, report, atomic outputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from posegraph.errors import InputWarning
from posegraph.io.g2o import read_g2o, write_g2o
from posegraph.lie.group import SE2, SE3
from tests.certification.graphs import loop_graph
from tests.cli.conftest import assert_one_error_line, run_cli

REPORT_FIELDS = {"certified", "sesync_objective", "lower_bound", "dual_bound", "suboptimality_bound",
                 "relative_suboptimality", "min_eigenvalue", "eigenvalue_residual", "proven_min_eigenvalue", "rank",
                 "components", "seconds", "eta", "status"}


def _graph_file(tmp_path, group, name="in.g2o", **noise):
    graph, truth = loop_graph(21, n=25, loops=15, group=group, **noise)
    path = tmp_path / name
    write_g2o(path, graph)
    return path, truth


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
def test_certified_graph_exit_zero_with_report_and_output(tmp_path, group):
    path, _ = _graph_file(tmp_path, group, rotation_noise=0.05, translation_noise=0.05)
    run = run_cli("certify", path, "-o", tmp_path / "out.g2o", "--report", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    assert REPORT_FIELDS <= set(report) and report["certified"] is True
    assert report["rank"] == group.space_dim and {"read", "candidate", "refine", "verify"} <= set(report["seconds"])
    assert f"{report['sesync_objective']:.6g}" in run.stdout and "certified:           yes" in run.stdout
    out = read_g2o(tmp_path / "out.g2o")
    assert out.num_vertices == 25 and out.group.name == group.name
    from posegraph.certification.certificate import certify

    again = certify(read_g2o(path), poses=out.poses, refine=False)  # the written poses certify (to the file's digits)
    assert again.sesync_objective == pytest.approx(report["sesync_objective"], rel=1e-6)


def test_not_certified_exit_one_prints_the_bound(tmp_path):
    graph, _ = loop_graph(0, n=10, loops=10, rotation_noise=2.0, translation_noise=0.5, group=SE2)
    write_g2o(tmp_path / "hard.g2o", graph)
    run = run_cli("certify", tmp_path / "hard.g2o", "--report", tmp_path / "r.json", "-o", tmp_path / "o.g2o")
    assert run.returncode == 1, run.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["certified"] is False and report["suboptimality_bound"] > 0
    assert "certified:           NO" in run.stdout and "suboptimality bound:" in run.stdout
    assert (tmp_path / "o.g2o").exists()  # results are still written


def test_bad_input_exit_two_writes_nothing(tmp_path):
    graph, _ = loop_graph(6, n=6, loops=0)
    import dataclasses

    information = graph.information.copy()
    information[2, 3:, 3:] = 0.0  # no τ: SE-Sync's problem is not defined
    write_g2o(tmp_path / "singular.g2o", dataclasses.replace(graph, information=information))
    run = run_cli("certify", tmp_path / "singular.g2o", "-o", tmp_path / "o.g2o", "--report", tmp_path / "r.json",
                  "-q")
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr_lines[-1].startswith("posegraph: error: ") and "κ and τ" in run.stderr_lines[-1]
    assert not (tmp_path / "o.g2o").exists() and not (tmp_path / "r.json").exists()
    assert_one_error_line(run_cli("certify", tmp_path / "missing.g2o"), "missing.g2o")
    write_g2o(tmp_path / "ok.g2o", graph)
    same = run_cli("certify", tmp_path / "ok.g2o", "-o", tmp_path / "ok.g2o", "-q")
    assert_one_error_line(same)
    for bad in ("0", "-1", "nan", "inf"):
        assert_one_error_line(run_cli("certify", tmp_path / "ok.g2o", "--eta", bad), "--eta")


def test_two_components_are_certified_each_in_its_own_gauge(tmp_path):
    """A graph in two pieces: certified piece by piece, F the sum, each piece anchored at its smallest id."""
    import dataclasses

    from posegraph.certification.certificate import certify

    graph, _ = loop_graph(6, n=12, loops=0, rotation_noise=0.05, translation_noise=0.05)
    keep = graph.edge_from != 5
    cut = dataclasses.replace(graph, edge_from=graph.edge_from[keep], edge_to=graph.edge_to[keep],
                              measurements=graph.measurements[keep], information=graph.information[keep])
    write_g2o(tmp_path / "cut.g2o", cut)
    run = run_cli("certify", tmp_path / "cut.g2o", "-o", tmp_path / "o.g2o", "--report", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["certified"] and report["components"] == 2 and "(2 components)" in run.stdout
    halves = [dataclasses.replace(cut, ids=cut.ids[part], poses=cut.poses[part], fixed=cut.fixed[part],
                                  edge_from=cut.edge_from[edges] - part[0], edge_to=cut.edge_to[edges] - part[0],
                                  measurements=cut.measurements[edges], information=cut.information[edges],
                                  edge_source=None, edge_lines=None)  # fmt: skip
              for part, edges in ((np.arange(6), cut.edge_to < 6), (np.arange(6, 12), cut.edge_from >= 6))]
    each = [certify(half) for half in halves]
    assert report["sesync_objective"] == pytest.approx(sum(c.sesync_objective for c in each), rel=1e-9)
    out = read_g2o(tmp_path / "o.g2o")
    for half, c, part in zip(halves, each, (np.arange(6), np.arange(6, 12))):
        np.testing.assert_allclose(out.poses[part[0]], cut.poses[part[0]], atol=1e-6)  # its anchor kept
        np.testing.assert_allclose(out.poses[part], c.poses, atol=1e-6)


def test_eta_given_on_the_command_line_is_the_tolerance_used(tmp_path):
    """A graph whose relaxation is not tight: its relative gap g decides — certified with --eta above g, not below."""
    from datasets.certify_cases import lattice

    write_g2o(tmp_path / "grid.g2o", lattice(2, 6, 0.6, 0.6, seed=2))
    first = run_cli("certify", tmp_path / "grid.g2o", "--report", "-", "-q")
    gap = json.loads(first.stdout)["relative_suboptimality"]
    assert first.returncode == 1 and 1e-5 < gap < 0.5, first.stdout
    loose = run_cli("certify", tmp_path / "grid.g2o", "--report", "-", "-q", "--eta", f"{2 * gap:g}")
    assert loose.returncode == 0 and json.loads(loose.stdout)["eta"] == pytest.approx(2 * gap, rel=1e-5)
    tight = run_cli("certify", tmp_path / "grid.g2o", "--report", "-", "-q", "--eta", f"{gap / 2:g}")
    assert tight.returncode == 1 and not json.loads(tight.stdout)["certified"]


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
def test_optimize_certify_reports_the_basin(tmp_path, group):
    path, _ = _graph_file(tmp_path, group, rotation_noise=0.05, translation_noise=0.05)
    run = run_cli("optimize", path, "-o", tmp_path / "out.g2o", "--certify", "--report", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    section = json.loads((tmp_path / "r.json").read_text())["certify"]
    assert section["certified"] and section["same_basin"]
    assert abs(section["cost_difference"]) <= 1e-6 * section["chordal_lm_cost"]
    assert section["max_rotation_difference_rad"] < 1e-4
    assert "certificate:    certified" in run.stdout and "same basin" in run.stdout
    assert section["certified_graph"] == "file" and section["certified_edges"] == read_g2o(path).num_edges
    huber = run_cli("optimize", path, "-o", tmp_path / "o2.g2o", "--certify", "--robust", "huber")
    assert_one_error_line(huber, "--certify")
    assert not (tmp_path / "o2.g2o").exists()


def test_gnc_certify_certifies_the_edges_gnc_kept(tmp_path):
    """A wrong loop closure (rotated by 3 rad): GNC drops it, and the certificate is of the other edges' problem."""
    import dataclasses

    from posegraph.certification.certificate import certify

    graph, _ = loop_graph(21, n=25, loops=15, rotation_noise=0.02, translation_noise=0.02)
    wrong = graph.measurements.copy()
    closure = int(np.flatnonzero(np.abs(graph.edge_to - graph.edge_from) > 1)[0])
    wrong[closure] = wrong[closure] @ SE3.exp(np.array([3.0, 0, 0, 0.0, 5.0, 0]))
    write_g2o(tmp_path / "wrong.g2o", dataclasses.replace(graph, measurements=wrong))
    run = run_cli("optimize", tmp_path / "wrong.g2o", "-o", tmp_path / "o.g2o", "--robust", "gnc", "--certify",
                  "--report", tmp_path / "r.json")  # fmt: skip
    assert run.returncode == 0, run.stderr
    section = json.loads((tmp_path / "r.json").read_text())["certify"]
    assert section["certified"] and section["certified_graph"] == "gnc_inliers"
    assert section["certified_edges"] == graph.num_edges - 1 and "edges GNC kept" in run.stdout
    keep = np.arange(graph.num_edges) != closure
    inliers = dataclasses.replace(graph, edge_from=graph.edge_from[keep], edge_to=graph.edge_to[keep],
                                  measurements=graph.measurements[keep], information=graph.information[keep])
    assert section["sesync_objective"] == pytest.approx(certify(inliers).sesync_objective, rel=1e-9)
    everything = run_cli("certify", tmp_path / "wrong.g2o", "-q", "--report", "-")
    assert everything.returncode == 1  # with the wrong closure, F's optimum is not certified at this noise


def test_shared_datasets_match_sesync_digits(shared_dataset):
    """F(x) to SE-Sync's six printed digits (issue #25's table), certified, through the command line."""
    for name, expected in (("smallGrid3D", "1025.4"), ("intel", "52.3482"), ("sphere2500", "1687.01")):
        run = run_cli("certify", shared_dataset(name), "--report", "-", "-q")
        assert run.returncode == 0, run.stderr
        report = json.loads(run.stdout)
        assert report["certified"] and f"{report['sesync_objective']:.6g}" == expected
        assert np.isfinite(report["min_eigenvalue"]) and abs(report["suboptimality_bound"]) < 1e-6 * 2000


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
def test_max_rank_below_the_rotations_dimension_is_a_usage_error(tmp_path, group):
    """The staircase starts at rank d (2 in 2D, 3 in 3D): a lower --max-rank would be ignored. Below 2 no
    graph is read; below a 3D graph's 3, once the file says d; R = d runs (the candidate alone)."""
    path, _ = _graph_file(tmp_path, group, rotation_noise=0.05, translation_noise=0.05)
    out = tmp_path / "out.g2o"
    assert_one_error_line(run_cli("certify", path, "-q", "-o", out, "--max-rank", "1"),
                          "argument --max-rank: must be >= 2", "(see 'posegraph certify --help')")
    if group is SE3:
        assert_one_error_line(run_cli("certify", path, "-q", "-o", out, "--max-rank", "2"),
                              "--max-rank 2 is below 3, the rotations' dimension d of this 3D graph", "give R >= 3")
    assert not out.exists()
    run = run_cli("certify", path, "-q", "-o", out, "--max-rank", str(group.space_dim))
    assert run.returncode == 0 and out.exists(), run.stderr
