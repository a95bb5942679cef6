"""The benchmark harness end to end on a tiny synthetic graph, and its measuring and bookkeeping parts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import harness
from datasets.synthetic import sphere, write_dataset

ROOT = Path(__file__).resolve().parent.parent


def test_run_process_measures_this_childs_memory_and_time():
    allocate = "import time, numpy as np; a = np.ones(40_000_000); time.sleep(0.2)"  # 320 MB
    big = harness.run_process([sys.executable, "-c", allocate])
    small = harness.run_process([sys.executable, "-c", "pass"])
    assert big.returncode == 0 and small.returncode == 0
    assert big.max_rss > 320e6 and small.max_rss < 100e6  # per child, not the maximum over all children
    assert big.wall >= 0.2 and big.wall > small.wall
    failed = harness.run_process([sys.executable, "-c", "import sys; sys.exit('boom')"])
    assert failed.returncode == 1 and "boom" in failed.stderr
    killed = harness.run_process([sys.executable, "-c", "import time; time.sleep(30)"], timeout=0.5)
    assert killed.returncode < 0 and killed.wall < 10


def test_normalise_report_reads_both_sides():
    ours = {"initial_cost": 5.0, "final_cost": 1.0, "iterations": 3, "linear_solver": "cholmod",
            "seconds": {"read": 0.1, "initialise": 0.2, "optimise": 0.3, "write": 0.4}}
    theirs = {"initial_cost": 5.0, "final_cost": 1.0, "iterations": 4,
              "seconds": {"import": 0.3, "read": 0.1, "initialize": 0.2, "optimize": 0.3, "write": 0.4}}
    for report in (ours, theirs):
        out = harness.normalise_report(report)
        assert out["seconds"] == {"read": 0.1, "initialize": 0.2, "optimize": 0.3, "write": 0.4}
        assert (out["initial_cost"], out["final_cost"]) == (5.0, 1.0)
    assert harness.normalise_report(ours)["linear_solver"] == "cholmod"


def test_compare_says_by_how_much_a_target_is_missed():
    def summary(wall, cost):
        return {"ok": True, "wall": wall, "final_cost": cost, "seconds": {"read": 0.1, "initialize": 0.1, "optimize": wall - 0.3, "write": 0.05, "other": 0.05}}

    tools = {"posegraph": summary(1.2, 10.0), "gtsam-lm": summary(2.0, 10.0 * (1 + 1e-7)), "gtsam-gn": summary(1.0, 10.5)}
    out = harness.compare("torus3D", tools)
    assert out["ratio_vs_gtsam-lm"] == pytest.approx(0.6) and out["ratio_vs_gtsam-gn"] == pytest.approx(1.2)
    assert out["cost_ok"] and out["gtsam_best_cost"] == pytest.approx(10.0 * (1 + 1e-7))
    target = out["target"]
    assert not target["ratio_met"] and target["ratio_over_by"] == pytest.approx(0.2)
    assert target["seconds_over_budget"] == pytest.approx(0.2) and target["largest_phase"] == "optimize"
    tools["posegraph"] = summary(0.9, 10.0 * (1 + 3e-6))
    out = harness.compare("torus3D", tools)
    assert out["target"]["ratio_met"] and not out["cost_ok"] and out["cost_excess"] == pytest.approx(2.9e-6, rel=1e-3)
    assert "target" not in harness.compare("smallGrid3D", tools)


def test_harness_end_to_end_on_a_tiny_graph(tmp_path):
    """``python -m benchmarks`` on one tiny file, 1 round, ours and gtsam: JSON and Markdown with sane values."""
    pytest.importorskip("gtsam")
    data = sphere(rings=5, nodes_per_ring=6, seed=1)
    path, _ = write_dataset(tmp_path / "tiny_sphere.g2o", data)
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks", "--datasets", str(path), "--repeats", "1", "--warmup", "0",
         "--tools", "posegraph", "gtsam-lm", "--startup-runs", "1", "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads((out / "benchmark_results.json").read_text())
    markdown = (out / "benchmark_results.md").read_text()
    (entry,) = result["datasets"]
    assert (entry["dataset"], entry["vertices"], entry["edges"]) == ("tiny_sphere", 30, data.graph.num_edges)
    ours, gtsam = entry["tools"]["posegraph"], entry["tools"]["gtsam-lm"]
    assert ours["ok"] and gtsam["ok"], (ours, gtsam)
    for summary in (ours, gtsam):
        assert summary["repeats"] == 1
        assert 0 <= summary["final_cost"] <= summary["initial_cost"]
        assert summary["iterations"] >= 1
        phases = summary["seconds"]
        assert set(phases) == {"read", "initialize", "optimize", "write", "other"}
        assert all(v >= 0 for v in phases.values())
        assert sum(phases.values()) == pytest.approx(summary["wall"], rel=1e-6)
        assert 0.02 < summary["wall"] < 60
        assert 10 * 2**20 < summary["max_rss"] < 4 * 2**30
    # Both reach the same optimum on this easy graph (gtsam stops at its looser default tolerance).
    assert ours["final_cost"] == pytest.approx(gtsam["final_cost"], rel=1e-4)
    comparison = entry["comparison"]
    assert comparison["ratio_vs_gtsam-lm"] == pytest.approx(ours["wall"] / gtsam["wall"])
    assert comparison["gtsam_best_cost"] == gtsam["final_cost"]
    # Machine description and start-up times.
    assert result["machine"]["cores"] >= 1 and result["machine"]["numpy"]
    assert set(result["startup"]) == {"python -c pass", "import posegraph", "cli.py --help"}
    assert result["startup"]["import posegraph"]["median"] > 0
    # Markdown: both tables with their columns, one row per tool.
    for column in harness.SUMMARY_COLUMNS + harness.RUN_COLUMNS:
        assert column in markdown
    assert markdown.count("| tiny_sphere |") == 3
    assert "Traceback" not in done.stdout + done.stderr


def test_dataset_discovery(tmp_path):
    (tmp_path / "a.g2o").write_text("# comment\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n")
    (tmp_path / "b.g2o").write_text("VERTEX_SE2 0 0 0 0\n")
    (tmp_path / "c.txt").write_text("EDGE3 0 1 1 0 0 0 0 0 " + " ".join(["1"] * 21) + "\n")
    (tmp_path / "d.csv").write_text("VERTEX_SE3:QUAT\n")
    (tmp_path / "e.g2o").write_text("VERTEX_TRACKXYZ 0 1 2 3\n")
    names = [d.name for d in harness.user_datasets([str(tmp_path)])]
    assert names == ["a", "b", "c"]  # 3D and 2D pose graphs; neither a .csv nor other tags
    assert harness.count_graph(tmp_path / "c.txt") == (2, 1)
    with pytest.raises(FileNotFoundError):
        harness.user_datasets([str(tmp_path / "missing")])


def test_scaling_points_table_and_plot(tmp_path):
    """Two tiny scaling points end to end (worker process, fill-in analysis), then the table and the figure."""
    pytest.importorskip("cvxopt")
    pytest.importorskip("matplotlib")
    from benchmarks import scaling

    points = [scaling.run_point("sphere", size, timeout=120, log=lambda _: None) for size in (64, 144)]
    for point, side in zip(points, (8, 12)):
        assert "error" not in point, point
        assert point["vertices"] == side * side and point["converged"]
        assert set(point["seconds"]) >= {"read", "initialize", "optimize", "write"}
        assert all(point["peak_bytes"][k] > 10 * 2**20 for k in ("read", "initialize", "optimize", "write"))
        assert point["max_rss"] >= max(point["peak_bytes"].values())
        # Cholesky fill: the factor holds at least the matrix's lower triangle.
        assert point["fill"]["amd"]["nnz_L"] >= point["fill"]["nnz_H"] and point["fill"]["metis"]["flops"] > 0
        assert point["factorizations"] >= 1 and point["iterations"] >= 1
    assert scaling.log_log_slope([1, 10, 100], [2, 20, 200]) == pytest.approx(1.0)
    slopes = scaling.slopes(points)["sphere"]
    assert slopes["edges"] == [p["edges"] for p in points]
    table = scaling.markdown_table(points)
    assert table.count("\n| sphere |") == 2 and "nnz(L)" in table
    scaling.plot(points, tmp_path / "scaling.png")
    assert (tmp_path / "scaling.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _landmark_file(tmp_path):
    """A tiny SE(2) landmark graph (poses + VERTEX_XY + EDGE_SE2_XY) written as g2o."""
    from datasets.synthetic import landmark_graph
    from posegraph.io.g2o import write_g2o
    from posegraph.lie.group import SE2

    graph, _, _ = landmark_graph(SE2, num_poses=10, num_landmarks=6, noise=0.01, seed=3)
    path = tmp_path / "tiny_landmarks.g2o"
    write_g2o(path, graph)
    return path, graph


def test_landmark_children_reports_parse_and_tabulate(tmp_path):
    """g2opy and gtsam children on a tiny landmark file: their JSON parsed, the not-read rule, the table."""
    from benchmarks import bench_landmarks, g2opy_pipeline, gtsam_landmarks
    from tests.optional import import_or_skip

    import_or_skip("g2opy", "the g2o side of the landmark benchmark")
    import_or_skip("gtsam", "the gtsam side of the landmark benchmark")
    path, graph = _landmark_file(tmp_path)
    measurements = graph.num_edges + graph.landmarks.num_measurements
    assert g2opy_pipeline.measurement_lines(str(path)) == measurements
    g2o_report, gtsam_report = tmp_path / "g2o.json", tmp_path / "gtsam.json"
    assert g2opy_pipeline.main([str(path), "-o", str(tmp_path / "g2o_out.g2o"), "--report", str(g2o_report)]) == 0
    assert gtsam_landmarks.main([str(path), "-o", str(tmp_path / "gtsam_out.g2o"), "--report", str(gtsam_report)]) == 0
    g2o = bench_landmarks.parse_report("g2opy", json.loads(g2o_report.read_text()))
    gtsam = bench_landmarks.parse_report("gtsam", json.loads(gtsam_report.read_text()))
    assert g2o["not_read"] is None and g2o["cost"] == pytest.approx(g2o["chi2"] / 2) and 0 <= g2o["chi2"] < 1e3
    assert g2o["iterations"] >= 1 and (tmp_path / "g2o_out.g2o").is_file()
    # gtsam's readG2o keeps the VERTEX_XY values but drops the EDGE_SE2_XY measurements: not read, with the counts.
    assert gtsam["not_read"] == f"gtsam.readG2o built {graph.num_edges} factors of {measurements} measurement lines"
    posegraph = bench_landmarks.parse_report("posegraph", {
        "final_cost": 0.5 * g2o["chi2"], "chi2": g2o["chi2"], "iterations": 4, "converged": True, "num_vertices": 10,
        "num_edges": graph.num_edges, "num_landmarks": 6, "num_landmark_measurements": graph.landmarks.num_measurements,
        "seconds": {"read": 0.01, "optimise": 0.02, "total": 0.03, "solver": {"factorize": 0.01}}})  # fmt: skip
    assert posegraph["counts"] == {"poses": 10, "landmarks": 6, "measurements": measurements}
    assert "solver" not in posegraph["seconds"]

    def summary(parsed, wall):
        return {**bench_landmarks.median_summary([{**parsed, "ok": parsed["not_read"] is None, "wall": wall}])}

    result = {"file": path.name, "posegraph_g2o_chi2": g2o["chi2"] * (1 + 2e-6), "posegraph_g2o_chi2_note": None,
              "tools": {"posegraph": summary(posegraph, 0.3), "g2opy": summary(g2o, 1.0), "gtsam": summary(gtsam, 0.5)}}
    result["comparison"] = bench_landmarks.compare(result)
    assert not result["comparison"]["chi2_met"] and result["comparison"]["ratio_vs_g2opy"] == pytest.approx(0.3)
    table = "\n".join(bench_landmarks.file_table(result))
    assert f"10 poses, 6 landmarks, {measurements} measurements" in table
    assert f"| gtsam | not read: gtsam.readG2o built {graph.num_edges} factors" in table
    assert "χ² ≤ g2opy's × (1 + 1e-6), g2o's definition: NO (relative +2.000e-06" in table
    assert "end-to-end ≤ 0.5 × g2opy's: yes (ratio 0.30)" in table
    # g2opy's answer scored by the common cost: read back by posegraph, the same number as posegraph's cost of it
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.objective import Objective

    answer = read_g2o(tmp_path / "g2o_out.g2o")
    common = bench_landmarks.common_cost_of(tmp_path / "g2o_out.g2o")
    assert common == pytest.approx(Objective(answer).evaluate(answer.poses, answer.landmarks.positions).cost, rel=1e-12)
    result["g2opy_common_cost"] = result["tools"]["posegraph"]["cost"] * (1 - 3e-6)  # g2opy's answer a little lower
    result["comparison"] = bench_landmarks.compare(result)
    table = "\n".join(bench_landmarks.file_table(result))
    assert "posegraph's at or below (1e-6): NO" in table and not result["comparison"]["common_cost_met"]
    assert "in process (read + start + solve + write): posegraph 0.030 s" in table
    assert bench_landmarks.common_cost_of(tmp_path / "missing.g2o") is None


def test_landmark_files_say_why_one_is_skipped(tmp_path):
    from benchmarks import bench_landmarks

    (tmp_path / "isam_victoriaPark.txt").write_text("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\n")
    entries = {e["name"]: e for e in bench_landmarks.landmark_files(tmp_path)}
    assert entries["isam_victoriaPark.txt"]["path"] == tmp_path / "isam_victoriaPark.txt"
    assert entries["victoriaPark-full.g2o.gz"]["path"] is None
    assert entries["victoriaPark-full.g2o.gz"]["reason"].startswith("absent: ")
    command = bench_landmarks.tool_command("posegraph", tmp_path / "isam_victoriaPark.txt", tmp_path / "o", tmp_path / "r")
    assert command[-2:] == ["--isam-information", "covariance"]
    assert "--isam-information" not in bench_landmarks.tool_command("posegraph", tmp_path / "a.g2o.gz", tmp_path / "o", tmp_path / "r")


def test_converged_isam2_reaches_the_batch_optimum_where_default_isam2_does_not():
    """bench_incremental's ``gtsam-converged`` side (ISAM2 iterated to posegraph's stopping rule) is
    within 1e-6 of the batch optimum at every check; ISAM2 with its defaults, on the same replay, is not
    (so the comparison it serves is between equally accurate answers)."""
    pytest.importorskip("gtsam")
    from benchmarks import bench_incremental
    from datasets.synthetic import generate

    graph = generate("manhattan", 300, seed=1).graph
    default = bench_incremental.run_gtsam(graph, 100)
    converged = bench_incremental.run_gtsam(graph, 100, threshold=1e-4)
    assert max(check[2] for check in default["checks"]) > 1e-6
    assert max(check[2] for check in converged["checks"]) <= 1e-6
    assert converged["extra_updates"] > 0 and "extra_updates" not in default
    assert [c[0] for c in converged["checks"]] == [100, 200, 300]


def test_victoria_park_as_gtsam_reads_it_is_the_same_problem_for_both_tools(tmp_path):
    """bench_incremental_landmarks writes gtsam's ``load2D`` reading of victoria_park.txt (odometry,
    ``BearingRangeFactor2D``) as a file posegraph reads: posegraph's cost at the file's estimate equals
    gtsam's own graph error at its initial values, and the ISAM2 side's per-update batches hold every
    factor exactly once."""
    gtsam = pytest.importorskip("gtsam")
    from benchmarks import bench_incremental_landmarks as bench
    from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam
    from posegraph.crosscheck.gtsam_landmarks import landmark_factors
    from posegraph.incremental.replay import replay_batches
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.objective import Objective

    source = bench.file_path("gtsam:victoria_park.txt")
    graph = read_g2o(bench.gtsam_problem_file(source, tmp_path / "problem.g2o"))
    factors, initial = gtsam.load2D(str(source))
    ours = Objective(graph).evaluate(graph.poses, graph.landmarks.positions).cost
    assert [f.kind for f in graph.landmarks.observations] == ["bearing_range"]
    assert ours == pytest.approx(factors.error(initial), rel=1e-12)
    edges, measured = graph_to_gtsam(graph), landmark_factors(graph)
    counts = [bench.batch_factors(graph, batch, edges, measured, [0]).size() for batch in replay_batches(graph, 1)]
    assert sum(counts) == factors.size() == graph.num_edges + graph.landmarks.num_measurements


def test_victoria_park_isam2_error_is_posegraphs_cost_on_the_same_prefix(tmp_path):
    """The ISAM2 side of bench_incremental_landmarks on victoria_park.txt's first 300 poses: at each check
    the error of the factors ISAM2 holds (without its anchoring prior) equals posegraph's cost of ISAM2's
    estimate on :func:`landmark_prefix` to 1e-9 relative, and that prefix is the graph posegraph's replay
    holds after as many updates (same counts, same cost at the replay's estimate)."""
    pytest.importorskip("gtsam")
    from benchmarks import bench_incremental_landmarks as bench
    from posegraph.incremental.replay import replay, replay_batches
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.objective import Objective

    graph = read_g2o(bench.gtsam_problem_file(bench.file_path("gtsam:victoria_park.txt"), tmp_path / "problem.g2o"))
    first, _, _ = bench.landmark_prefix(graph, list(replay_batches(graph, 1)), 300)
    isam2 = bench.run_isam2(first, 100)
    assert [c[0] for c in isam2["checks"]] == [100, 200, 300]
    assert max(c[2] for c in isam2["checks"]) <= 1e-9
    assert all(c[1] >= 0.0 for c in isam2["checks"])
    batches, seen = list(replay_batches(first, 1)), {}

    def at_150(result, number):
        if number == 150:
            opt = result.optimizer
            held, vertices, landmarks = bench.landmark_prefix(first, batches, 150)
            row = {int(i): r for r, i in enumerate(opt.landmark_ids.tolist())}
            points = opt.landmark_positions[[row[int(i)] for i in held.landmarks.ids]]
            theirs = opt.graph()
            seen["counts"] = [(g.num_vertices, g.num_edges, g.landmarks.count, g.landmarks.num_measurements)
                              for g in (held, theirs)]
            seen["costs"] = (Objective(held).evaluate(opt.poses, points).cost,
                             Objective(theirs).evaluate(theirs.poses, theirs.landmarks.positions).cost)

    replay(first, 1, progress=at_150)
    assert seen["counts"][0] == seen["counts"][1] and seen["counts"][0][3] > 0
    assert seen["costs"][0] == pytest.approx(seen["costs"][1], rel=1e-12) and seen["costs"][1] > 0


def test_point_elimination_benchmark_runs_every_variant_to_the_same_optimum(tmp_path):
    """bench_point_elimination on a tiny landmark file: every variant's LM from one start, same cost and
    iterations as today's path, one table row each, the points' statistics counted."""
    from benchmarks import bench_point_elimination as bench
    from posegraph.solve.linear import cholmod_available

    if not cholmod_available():
        pytest.skip("cvxopt's CHOLMOD is not installed")
    path, graph = _landmark_file(tmp_path)
    figures = bench.measure(path, rounds=2)
    rows = figures["variants"]
    assert {"amd", "points-first", "schur"} <= set(rows)
    assert all(row["cost_relative"] <= 1e-9 and row["iterations"] == rows["amd"]["iterations"] for row in rows.values())
    assert rows["amd"]["iterations"] >= 1 and all(row["lm_s"] > 0 and row["mflop"] > 0 for row in rows.values())
    assert figures["points"]["points"] == graph.landmarks.count
    assert figures["points"]["pose_pairs"] > 0 and 0 <= figures["points"]["points_in_amd_first_half"] <= 1
    table = bench.table({path.name: figures}).splitlines()
    assert len(table) == 2 + len(rows) and all(path.name in line for line in table[2:])


def test_left_out_sightings_bound_reaches_the_replay_and_keeps_its_answer():
    """The benchmark's bound is the one the replay runs with: at 0 nothing is left out, at 16 re-sightings
    after a gap are (fewer analyses), and both end at the same cost within the optimiser's tolerance."""
    pytest.importorskip("gtsam")
    from benchmarks.bench_left_out_sightings import spawn

    none, some = (spawn("gtsam:victoria_park.txt", 600, bound, 300) for bound in (0, 16))
    assert none["left_out"] == 0 < some["left_out"], (none, some)
    assert some["analyses"] < none["analyses"], (none, some)
    assert some["final_cost"] == pytest.approx(none["final_cost"], rel=1e-7)
    assert max(none["excess_max"], some["excess_max"]) <= 1e-6
