"""What `optimize` prints and reports, as a g2o or gtsam user reads it: ½χ², χ², χ²/dof (robust
and landmark graphs too), the warning on a broken map, why the run stopped, progress, `--stats`, the report's fields."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from posegraph import cli
from tests.cli.conftest import run_cli


def printed(stdout: str, key: str) -> str:
    match = re.search(rf"^{re.escape(key)}:\s+(\S+)", stdout, re.MULTILINE)
    assert match, (key, stdout)
    return match.group(1)


@pytest.fixture(scope="module")
def sphere_run(tmp_path_factory):
    from tests.conftest import SHARED_DATASETS

    source = SHARED_DATASETS / "sphere2500.g2o"
    if not source.is_file():
        pytest.skip(f"shared dataset {source} is absent")
    folder = tmp_path_factory.mktemp("sphere")
    run = run_cli("optimize", source, "-o", folder / "out.g2o", "--report", folder / "r.json", "--stats")
    assert run.returncode == 0, run.stderr
    return run, json.loads((folder / "r.json").read_text())


def test_summary_says_what_the_cost_is_and_prints_chi2_and_chi2_per_dof(sphere_run):
    """sphere2500: ½χ² = 675.70 (gtsam's error), χ² = 1351.40 (g2o's), dof = 6·4949 − 6·2499."""
    run, report = sphere_run
    cost, chi2 = float(printed(run.stdout, "final cost")), float(printed(run.stdout, "final χ²"))
    assert cost == pytest.approx(675.70096, abs=1e-4) and chi2 == pytest.approx(1351.4019, abs=1e-3)
    assert chi2 == pytest.approx(2 * cost, rel=1e-11)
    assert "½χ²" in re.search(r"^final cost:.*$", run.stdout, re.MULTILINE).group(0)
    dof_line = re.search(r"^χ²/dof:\s+(\S+) \(dof = 6·4949 edges − 6·2499 free poses = 14700", run.stdout,
                         re.MULTILINE)
    assert dof_line and float(dof_line.group(1)) == pytest.approx(chi2 / 14700, rel=1e-3)
    assert "warning" not in run.stderr  # χ²/dof 0.09: nothing to warn about
    # The report: each field once, meaning what it says.
    assert report["chi2"] == pytest.approx(2 * report["final_cost"], rel=1e-12)
    assert report["dof"] == 14700 and report["chi2_per_dof"] == pytest.approx(report["chi2"] / 14700)
    assert "start_cost" not in report and "half chi2" in report["cost_definition"]
    assert all("attempts" not in r for r in report["records"])
    # A count of factorisations (0 when a step reused the previous one or none was needed).
    assert all(isinstance(r["factorizations"], int) and r["factorizations"] >= 0 for r in report["records"])
    assert report["records"][0]["factorizations"] >= 1  # the first linearisation has nothing to reuse


def test_stats_table_splits_chi2_by_edge_kind(sphere_run, shared_dataset):
    from posegraph.io.g2o import read_g2o

    run, report = sphere_run
    rows = {}
    for name in ("odometry", "loop closure", "all"):
        match = re.search(rf"^{name}\s+(\d+)\s+(\S+)\s+(\S+)$", run.stdout, re.MULTILINE)
        assert match, (name, run.stdout)
        rows[name] = (int(match.group(1)), float(match.group(2)), float(match.group(3)))
    graph = read_g2o(shared_dataset("sphere2500"))
    odometry = int(graph.odometry_mask().sum())
    assert rows["odometry"][0] == odometry and rows["loop closure"][0] == graph.num_edges - odometry
    assert rows["all"][0] == graph.num_edges
    assert rows["odometry"][1] + rows["loop closure"][1] == pytest.approx(rows["all"][1], rel=1e-5)
    assert rows["all"][1] == pytest.approx(report["chi2"], rel=1e-5)
    for count, chi2, per_edge in rows.values():
        assert per_edge == pytest.approx(chi2 / count, rel=1e-3)
    assert report["chi2_by_kind"]["odometry"]["count"] == odometry


def test_a_converged_run_ends_saying_why_and_progress_counts_to_the_cap(sphere_run):
    run, _ = sphere_run
    progress = [line for line in run.stderr_lines if line.strip().startswith("iter")]
    assert progress and all(re.match(r"\s*iter\s+\d+/100\s", line) for line in progress)
    assert "step rejected" not in progress[-1]  # a converged run does not end on a failure
    last = run.stderr_lines[-1]
    assert last.startswith("lm: converged") and ": " in last.split(" s)")[-1], last
    assert "termination:    converged" in run.stdout and "tolerance" in printed_line(run.stdout, "termination")


def printed_line(stdout: str, key: str) -> str:
    return re.search(rf"^{re.escape(key)}:.*$", stdout, re.MULTILINE).group(0)


def test_relative_decrease_stop_quotes_the_decrease_and_the_tolerance(tmp_path, shared_dataset):
    run = run_cli("optimize", shared_dataset("tinyGrid3D"), "-o", tmp_path / "o.g2o", "--init", "file")
    assert run.returncode == 0, run.stderr
    last = run.stderr_lines[-1]
    match = re.search(r"lowered the cost by (\S+) of it, within the relative tolerance 1e-07", last)
    assert last.startswith("lm: converged: relative decrease") and match, last
    assert float(match.group(1)) <= 1e-7


def outlier_grid(folder, outliers: float):
    """The bundled generator's 6×6×6 grid (216 poses), half the loop closures, ``outliers`` of them wrong."""
    from datasets.synthetic import NoiseParams, generate, write_dataset

    dataset = generate("grid", 216, noise=NoiseParams(loop_closure_density=0.5, outlier_fraction=outliers))
    path, _ = write_dataset(folder / f"grid-{outliers}.g2o", dataset)
    return path, dataset


def _edge_lines(path) -> list[int]:
    lines = path.read_text().splitlines()
    return [k + 1 for k, line in enumerate(lines) if line.startswith("EDGE_SE3:QUAT")]


def test_broken_map_is_warned_naming_the_wrong_loop_closures_by_line(tmp_path):
    """10 % wrong loop closures, plain least squares: exit 0 (it converged, to the wrong answer) and one
    warning saying the map looks broken, naming five of the wrong edges by line and ids, suggesting GNC;
    the report lists every suspicious edge, each a wrong one."""
    path, dataset = outlier_grid(tmp_path, 0.1)
    report = tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", tmp_path / "out.g2o", "--quiet", "--report", report)
    assert run.returncode == 0, run.stderr
    assert len(run.stderr_lines) == 1, run.stderr
    warning = run.stderr_lines[0]
    assert warning.startswith("posegraph: warning: χ²/dof = ") and "--robust gnc" in warning
    assert "the map looks broken" in warning
    assert float(re.search(r"χ²/dof = (\S+)", warning).group(1)) > 100
    named = [(int(n), int(i), int(j)) for n, i, j in re.findall(r"line (\d+) \((\d+)->(\d+)", warning)]
    assert len(named) == 5
    lines = path.read_text().splitlines()
    edge_lines = _edge_lines(path)
    outlier_lines = {edge_lines[e] for e in np.flatnonzero(dataset.outliers)}
    for number, i, j in named:  # each a wrong edge's line, with its ids printed
        assert lines[number - 1].split()[1:3] == [str(i), str(j)]
        assert number in outlier_lines
    verdict = json.loads(report.read_text())["suspicious_edges"]
    assert verdict["broken"] and verdict["agreement_gain"] > 10
    assert {e["line"] for e in verdict["edges"]} <= outlier_lines and verdict["count"] >= 0.8 * len(outlier_lines)

    clean, _ = outlier_grid(tmp_path, 0.0)
    run = run_cli("optimize", clean, "-o", tmp_path / "clean.g2o", "--report", report)
    assert run.returncode == 0 and "warning" not in run.stderr, run.stderr
    assert float(printed(run.stdout, "χ²/dof")) == pytest.approx(1.0, abs=0.2)
    verdict = json.loads(report.read_text())["suspicious_edges"]
    assert verdict["judged"] and not verdict["broken"] and verdict["count"] == 0 and verdict["edges"] == []


def _scaled_copy(path, folder, factor: float):
    import dataclasses

    from posegraph.io.g2o import read_g2o, write_g2o

    graph = read_g2o(path)
    scaled = folder / f"scaled-{factor:g}.g2o"
    write_g2o(scaled, dataclasses.replace(graph, information=graph.information * factor, edge_source=None))
    return scaled


@pytest.mark.parametrize("factor", [0.01, 100.0])
def test_clean_graph_with_misstated_information_is_not_called_broken(tmp_path, factor):
    """A clean grid whose information matrices understate (×0.01) or overstate (×100) the noise: no
    warning at all (its edges agree with each other), though χ²/dof is far above 10 when overstated."""
    clean, _ = outlier_grid(tmp_path, 0.0)
    report = tmp_path / "r.json"
    run = run_cli("optimize", _scaled_copy(clean, tmp_path, factor), "-o", tmp_path / "out.g2o", "-q", "--report", report)
    assert run.returncode == 0, run.stderr
    assert run.stderr_lines == []
    per_dof = json.loads(report.read_text())["chi2_per_dof"]
    assert (per_dof > 10) if factor > 1 else (per_dof < 0.1)


@pytest.mark.parametrize("option", [["--robust", "gnc"], ["--no-map-check"]])
def test_robust_runs_are_not_judged_again_nor_when_asked_not_to(tmp_path, option):
    """With --robust the outliers are reported by the robust mode, and --no-map-check skips the check:
    no broken-map warning, no verdict in the report."""
    path, _ = outlier_grid(tmp_path, 0.1)
    report = tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", tmp_path / "out.g2o", *option, "--report", report, "-q")
    assert run.returncode == 0, run.stderr
    assert "broken" not in run.stderr and "suspicious_edges" not in json.loads(report.read_text())


def test_robust_loss_summary_labels_the_robust_cost_and_prints_the_true_chi2(tmp_path):
    """--robust cauchy: the final cost is the robust cost ½ Σ ρ(eᵀΩe), labelled so; ½χ² and χ² are
    Σ eᵀΩe over every edge at the written poses; the inliers' χ² and χ²/dof beside them."""
    from posegraph.analysis.report import edge_chi2
    from posegraph.io.g2o import read_g2o
    from posegraph.robust import make_loss

    path, _ = outlier_grid(tmp_path, 0.1)
    out, report = tmp_path / "out.g2o", tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", out, "--robust", "cauchy", "--report", report)
    assert run.returncode == 0, run.stderr
    graph, poses = read_g2o(path), read_g2o(out).poses
    chi2 = edge_chi2(graph, poses)
    cost_line = printed_line(run.stdout, "final cost")
    assert "robust cost ½ Σ ρ(eᵀΩe), cauchy loss" in cost_line and "½χ² =" not in cost_line
    robust_cost = 0.5 * float(np.sum(make_loss("cauchy").rho(chi2)))
    assert float(printed(run.stdout, "final cost")) == pytest.approx(robust_cost, rel=1e-6)
    assert float(printed(run.stdout, "final ½χ²")) == pytest.approx(chi2.sum() / 2, rel=1e-6)
    assert float(printed(run.stdout, "final χ²")) == pytest.approx(chi2.sum(), rel=1e-6)
    assert float(printed(run.stdout, "final χ²")) > 100 * float(printed(run.stdout, "inliers' χ²"))
    assert "of the inliers; dof = 6·" in printed_line(run.stdout, "χ²/dof")
    data = json.loads(report.read_text())
    assert data["chi2_every"]["chi2"] == pytest.approx(chi2.sum(), rel=1e-6)
    assert data["chi2"] == pytest.approx(float(printed(run.stdout, "inliers' χ²")), rel=1e-6)


def test_landmark_dof_counts_rows_per_family_and_points_as_points(tmp_path):
    """The dof line of a landmark graph: pose edges' rows, each family's rows, free poses and free points."""
    from datasets.synthetic import landmark_graph
    from posegraph.io.g2o import write_g2o
    from posegraph.lie.group import SE2

    graph, _, _ = landmark_graph(SE2, 30, 12, ("position", "bearing"), noise=0.02, seed=11, per_landmark=4)
    path = tmp_path / "landmarks.g2o"
    write_g2o(path, graph)
    run = run_cli("optimize", path, "-o", tmp_path / "out.g2o", "--report", tmp_path / "r.json", "--stats")
    assert run.returncode == 0, run.stderr
    landmark = re.search(r"^landmark\s+(\d+)\s+\S+", run.stdout, re.MULTILINE)  # --stats: a row of their own
    everything = re.search(r"^all\s+(\d+)\s+(\S+)", run.stdout, re.MULTILINE)
    assert landmark and int(landmark.group(1)) == 96 and int(everything.group(1)) == 29 + 96
    assert float(everything.group(2)) == pytest.approx(float(printed(run.stdout, "final χ²")), rel=1e-5)
    assert ("(dof = 3·29 edges + 2·48 position measurements + 1·48 bearing measurements − 3·29 free poses "
            "− 2·12 free points = 120;") in printed_line(run.stdout, "χ²/dof")
    assert json.loads((tmp_path / "r.json").read_text())["dof"] == 120


def test_zero_dof_prints_undefined_and_reports_null(tmp_path):
    """An odometry chain (a tree: as many rows as free unknowns): χ²/dof undefined, null in the report."""
    path = tmp_path / "chain.g2o"
    path.write_text("".join(f"VERTEX_SE2 {k} {k} 0 0\n" for k in range(4))
                    + "".join(f"EDGE_SE2 {k} {k + 1} 1 0 0.1 1 0 0 1 0 1\n" for k in range(3)))
    report = tmp_path / "r.json"
    run = run_cli("optimize", path, "-o", tmp_path / "out.g2o", "--report", report)
    assert run.returncode == 0, run.stderr
    assert printed_line(run.stdout, "χ²/dof").startswith(
        "χ²/dof:         undefined (dof 0) (dof = 3·3 edges − 3·3 free poses = 0;")
    data = json.loads(report.read_text(), parse_constant=lambda name: pytest.fail(f"non-strict JSON {name}"))
    assert data["dof"] == 0 and data["chi2_per_dof"] is None


def test_slow_phases_announce_themselves_on_large_graphs(monkeypatch, capsys, tmp_path, shared_dataset):
    """Above the thresholds (lowered here) a line appears as reading and initialising start."""
    import posegraph.cli.common as common
    import posegraph.cli.optimize as optimize

    monkeypatch.setattr(common, "LARGE_FILE_BYTES", 1000)
    monkeypatch.setattr(optimize, "LARGE_GRAPH_POSES", 5)
    source = shared_dataset("tinyGrid3D")
    assert cli.main(["optimize", str(source), "-o", str(tmp_path / "o.g2o")]) == 0
    lines = capsys.readouterr().err.splitlines()
    reading = next(k for k, line in enumerate(lines) if line.startswith(f"reading {source} ("))
    read = next(k for k, line in enumerate(lines) if line.startswith(f"read {source}:"))
    starting = lines.index("initialising (chordal): 9 poses …")
    done = next(k for k, line in enumerate(lines) if line.startswith("initialised (chordal)"))
    assert reading < read < starting < done
    monkeypatch.setattr(common, "LARGE_FILE_BYTES", 10**9)
    monkeypatch.setattr(optimize, "LARGE_GRAPH_POSES", 10**6)
    assert cli.main(["optimize", str(source), "-o", str(tmp_path / "o.g2o")]) == 0
    assert "…" not in capsys.readouterr().err


def test_high_chi2_per_dof_is_warned_when_the_solve_stopped_short(tmp_path):
    """The clean grid at Ω×100 stopped after one iteration: its edges agree with each other at that point
    too, but a solve that did not converge is no evidence of a clean graph: the χ²/dof warning stays."""
    clean, _ = outlier_grid(tmp_path, 0.0)
    run = run_cli("optimize", _scaled_copy(clean, tmp_path, 100.0), "-o", tmp_path / "out.g2o", "-q",
                  "--max-iterations", "1", "--init", "odometry")
    assert run.returncode == 1, run.stderr  # the iteration cap
    assert any("χ²/dof = " in line and "largest χ²" in line for line in run.stderr_lines), run.stderr
