"""``optimize --rerun`` and ``replay --rerun`` end to end: the ``.rrd`` read back with Rerun's own reader
(``rerun.chunk.RrdReader``) holds the graph's poses and edges, the report's outliers and the ``-o`` poses;
bad paths fail in one line before any solving, leaving no file behind."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest

from tests.cli.conftest import PROJECT_ROOT, assert_one_error_line, run_cli
from tests.optional import import_or_skip

import_or_skip("rerun", "the Rerun recording tests")

EXAMPLE = PROJECT_ROOT / "datasets" / "example_sphere.g2o"


def read_recording(path) -> tuple[dict, dict]:
    """``(static, temporal)`` of the recording at ``path``: ``static[entity][column]`` the last value
    logged, ``temporal[entity]`` a list of ``(time, {column: value})`` rows sorted by time."""
    from rerun.chunk import RrdReader

    static, temporal = defaultdict(dict), defaultdict(list)
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch().to_pydict()
        columns = [c for c in batch if not c.startswith("rerun.") and c != "log_time"]
        timelines = [t for t in chunk.timeline_names if t != "log_time"]
        for row in range(chunk.num_rows):
            values = {c: batch[c][row] for c in columns if c not in timelines and batch[c][row] is not None}
            if chunk.is_static:
                static[chunk.entity_path].update(values)
            else:
                temporal[chunk.entity_path].append((batch[timelines[0]][row], values))
    for rows in temporal.values():
        rows.sort(key=lambda row: row[0])
    return static, temporal


def last(rows: list, column: str):
    """The value of ``column`` in the latest row holding it."""
    return [values[column] for _, values in rows if column in values][-1]


@pytest.fixture(scope="module")
def corrupted(tmp_path_factory):
    """A synthetic 3D grid with 20 % injected outliers: ``(path, outlier indices)``."""
    from datasets.synthetic import grid, inject_outliers
    from posegraph.io.g2o import write_g2o

    graph, indices = inject_outliers(grid(4, 4, 3, seed=1).graph, fraction=0.2, seed=1)
    path = tmp_path_factory.mktemp("rerun") / "grid_outliers.g2o"
    write_g2o(path, graph)
    return path, np.asarray(indices)


def _pose_values(values: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ids = np.asarray(values["vertex_id"])
    t = np.stack([values[k] for k in ("tx", "ty", "tz")], axis=1)
    q = np.stack([values[k] for k in ("qx", "qy", "qz", "qw")], axis=1)
    return ids, t, q


def assert_final_poses_are_the_output(rows: list, out_path) -> None:
    """The float64 poses at the recording's last time are those ``-o`` wrote (by vertex id)."""
    from posegraph.io.g2o import read_g2o
    from posegraph.lie import so3

    written = read_g2o(out_path)
    ids, t, q = _pose_values([values for _, values in rows if "vertex_id" in values][-1])
    index = written.index_of(ids)
    k = written.poses.shape[-1] - 1
    np.testing.assert_allclose(t[:, :k], written.poses[index, :k, k], atol=1e-7)
    rotation = so3.from_quaternion(q)[:, :k, :k]
    np.testing.assert_allclose(rotation, written.poses[index, :k, :k], atol=1e-7)


def test_optimize_gnc_recording_holds_the_graph_outliers_and_output(corrupted, tmp_path):
    path, indices = corrupted
    out, report, rrd = tmp_path / "out.g2o", tmp_path / "r.json", tmp_path / "run.rrd"
    run = run_cli("optimize", path, "-o", out, "--robust", "gnc", "--report", report, "--rerun", rrd, "-q")
    assert run.returncode == 0, run.stderr
    static, temporal = read_recording(rrd)
    from posegraph.io.g2o import read_g2o

    graph = read_g2o(path)
    for entity in ("/world/initial/odometry", "/world/chi2", "/summary", "/world/estimate/odometry"):
        assert entity in static, entity
    poses = last(temporal["/world/estimate/poses"], "Points3D:positions")
    assert len(poses) == graph.num_vertices
    edges = static["/world/estimate/odometry"]["edge"] + static["/world/estimate/loop_closures"]["edge"]
    assert sorted(edges) == list(range(graph.num_edges))
    strips = [len(last(temporal[f"/world/estimate/{name}"], "LineStrips3D:strips")) for name in ("odometry", "loop_closures")]
    assert sum(strips) == graph.num_edges
    flagged = sorted(e for name in ("odometry", "loop_closures")
                     for e, bad in zip(static[f"/world/estimate/{name}"]["edge"], static[f"/world/estimate/{name}"]["outlier"]) if bad)
    assert flagged == json.loads(report.read_text())["outlier_edges"] == indices.tolist()
    assert_final_poses_are_the_output(temporal["/world/estimate/poses"], out)
    np.testing.assert_allclose(np.asarray(poses), _pose_values(last_values(temporal["/world/estimate/poses"]))[1], atol=1e-4)
    assert "outlier edges" in static["/summary"]["TextDocument:text"][0]
    rounds = temporal["/metrics/gnc/inliers"]
    assert [time for time, _ in rounds] == list(range(len(rounds))) and len(rounds) > 1
    assert all(0 < values["Scalars:scalars"][0] <= graph.num_edges for _, values in rounds)


def last_values(rows: list) -> dict:
    return [values for _, values in rows if "vertex_id" in values][-1]


def test_optimize_recording_has_an_iteration_per_solver_iteration(tmp_path):
    out, report, rrd = tmp_path / "out.g2o", tmp_path / "r.json", tmp_path / "run.rrd"
    run = run_cli("optimize", EXAMPLE, "-o", out, "--report", report, "--rerun", rrd, "-q")
    assert run.returncode == 0, run.stderr
    static, temporal = read_recording(rrd)
    iterations = json.loads(report.read_text())["iterations"]
    costs = [values["Scalars:scalars"][0] for _, values in temporal["/metrics/cost"]]
    assert [time for time, _ in temporal["/metrics/cost"]] == list(range(1, iterations + 1))
    assert costs[-1] == pytest.approx(json.loads(report.read_text())["final_cost"], rel=1e-12)
    estimates = sorted({time for time, values in temporal["/world/estimate/poses"] if "Points3D:positions" in values})
    assert estimates == list(range(iterations + 1))  # the start, then every iteration: a small graph is not decimated
    assert_final_poses_are_the_output(temporal["/world/estimate/poses"], out)
    assert static["/world/estimate/odometry"]["outlier"] == [False] * len(static["/world/estimate/odometry"]["edge"])


def test_optimize_2d_covariances_are_ellipses_in_the_plane(tmp_path):
    from posegraph.io.g2o import write_g2o

    path = tmp_path / "planar.g2o"
    graph = _planar_graph()
    write_g2o(path, graph)
    out, cov, rrd = tmp_path / "out.g2o", tmp_path / "cov.npz", tmp_path / "run.rrd"
    run = run_cli("optimize", path, "-o", out, "--covariances", cov, "--rerun", rrd, "-q")
    assert run.returncode == 0, run.stderr
    static, temporal = read_recording(rrd)
    outlines = np.asarray(static["/world/covariance"]["LineStrips3D:strips"])
    assert outlines.shape[0] == min(graph.num_vertices, 200)
    assert np.all(outlines[..., 2] == 0)  # drawn in the plane z = 0
    assert np.all(np.asarray(last(temporal["/world/estimate/poses"], "Points3D:positions"))[:, 2] == 0)
    assert_final_poses_are_the_output(temporal["/world/estimate/poses"], out)


def _planar_graph():
    """A small SE(2) loop with noise: 40 poses, odometry and a few loop closures."""
    from posegraph.lie import se2
    from posegraph.model.graph import PoseGraph
    from posegraph.lie.group import SE2

    rng = np.random.default_rng(4)
    n = 40
    angle = np.linspace(0, 2 * np.pi, n, endpoint=False)
    truth = se2.from_xytheta(np.stack([10 * np.cos(angle), 10 * np.sin(angle), angle + np.pi / 2], axis=1))
    pairs = [(i, i + 1) for i in range(n - 1)] + [(i, i + 20) for i in range(0, 20, 5)] + [(n - 1, 0)]
    i, j = np.array(pairs).T
    measurements = se2.between(truth[i], truth[j]) @ se2.exp(0.01 * rng.standard_normal((len(i), 3)))
    start = truth @ se2.exp(0.05 * rng.standard_normal((n, 3)))
    return PoseGraph(ids=np.arange(n), poses=start, edge_from=i, edge_to=j, measurements=measurements,
                     information=np.broadcast_to(np.eye(3) * 100, (len(i), 3, 3)).copy(), group=SE2)


def test_replay_recording_holds_each_logged_update_and_the_output(tmp_path):
    out, rrd = tmp_path / "out.g2o", tmp_path / "replay.rrd"
    run = run_cli("replay", EXAMPLE, "-o", out, "--rerun", rrd, "--check-every", "100", "-q")
    assert run.returncode == 0, run.stderr
    static, temporal = read_recording(rrd)
    from posegraph.io.g2o import read_g2o

    graph = read_g2o(EXAMPLE)
    closures = np.flatnonzero(~graph.odometry_mask())
    updates = temporal["/metrics/update_ms"]
    assert [time for time, _ in updates] == list(range(1, graph.num_vertices + 1))  # every update, one pose each
    for time, values in temporal["/world/estimate/trajectory"]:
        assert len(values["LineStrips3D:strips"][0]) == time  # the estimate of `time` poses
    logged = [time for time, _ in temporal["/world/estimate/trajectory"]]
    assert logged == list(range(1, graph.num_vertices + 1))  # 225 updates: within the frame limit, all logged
    assert sorted(last(temporal["/world/loop_closures/all"], "edge")) == closures.tolist()
    new = [e for _, values in temporal["/world/loop_closures/new"] for e in values.get("edge", [])]
    assert sorted(new) == closures.tolist()  # each loop closure highlighted once, when it enters
    assert [time for time, _ in temporal["/metrics/cost_excess"]] == [100, 200, graph.num_vertices]
    assert_final_poses_are_the_output(temporal["/world/estimate/poses"], out)


@pytest.mark.parametrize("command", ["optimize", "replay"])
@pytest.mark.parametrize("where", ["missing folder", "folder", "input"])
def test_bad_recording_path_is_one_line_before_any_solving(tmp_path, command, where):
    source = tmp_path / "in.g2o"
    source.write_bytes(open(EXAMPLE, "rb").read())
    target = {"missing folder": tmp_path / "nowhere" / "x.rrd", "folder": tmp_path, "input": source}[where]
    before = sorted(p.name for p in tmp_path.iterdir())
    run = run_cli(command, source, "-o", tmp_path / "out.g2o", "--rerun", target)
    assert_one_error_line(run, str(target))
    assert "optimis" not in run.stderr and "replay:" not in run.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no .rrd, no temporary file, no output
    assert source.read_bytes() == open(EXAMPLE, "rb").read()


def test_a_failed_run_leaves_no_partial_recording(tmp_path):
    """An error found after the recording opened (an unknown --fix id): exit 2, no file left."""
    run = run_cli("optimize", EXAMPLE, "-o", tmp_path / "out.g2o", "--rerun", tmp_path / "run.rrd", "--fix", "999999", "-q")
    assert_one_error_line(run, "999999")
    assert list(tmp_path.iterdir()) == []


def test_no_viewer_at_the_connect_address_is_one_line_before_any_solving(tmp_path):
    import socket

    with socket.socket() as probe:  # a port nothing listens on once closed
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    run = run_cli("optimize", EXAMPLE, "-o", tmp_path / "out.g2o", "--rerun-connect", f"127.0.0.1:{port}")
    assert_one_error_line(run, "--rerun-connect", f"127.0.0.1:{port}")
    assert list(tmp_path.iterdir()) == []


def test_landmark_graph_recordings_hold_the_landmarks(tmp_path):
    """optimize (with covariances: poses' and points') and replay of a 2D landmark graph."""
    from posegraph.io.g2o import read_g2o, write_g2o
    from posegraph.lie.group import SE2
    from datasets.synthetic import landmark_graph

    graph, _, _ = landmark_graph(SE2, 30, 12, ("position", "bearing"), noise=0.02, seed=11, per_landmark=4)
    path = tmp_path / "landmarks.g2o"
    write_g2o(path, graph)
    for command, extra in (("optimize", ["--covariances", tmp_path / "cov.npz"]), ("replay", [])):
        out, rrd = tmp_path / f"{command}.g2o", tmp_path / f"{command}.rrd"
        run = run_cli(command, path, "-o", out, "--rerun", rrd, "-q", *extra)
        assert run.returncode == 0, run.stderr
        static, temporal = read_recording(rrd)
        points = np.asarray(last(temporal["/world/estimate/landmarks"], "Points3D:positions"))
        written = read_g2o(out).landmarks
        assert points.shape == (written.count, 3) and np.all(points[:, 2] == 0)
        np.testing.assert_allclose(np.sort(points[:, 0]), np.sort(written.positions[:, 0]), atol=1e-4)
        assert_final_poses_are_the_output(temporal["/world/estimate/poses"], out)
