"""posegraph.solve.gauge: a landmark graph solved with its central pose held, its answer in the conventional gauge."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.lie.group import SE2, SE3
from posegraph.model.graph import component_anchors
from posegraph.model.landmarks import Landmarks
from posegraph.solve.gauge import central_anchors, moved_back
from posegraph.solve.optimizer import optimize
from posegraph.solve.params import SolverParams


def _start(graph, seed=1, size=0.05):
    rng = np.random.default_rng(seed)
    poses = graph.poses @ graph.group.exp(rng.normal(size=(graph.num_vertices, graph.group.dim)) * size)
    return poses


@pytest.mark.parametrize("group, kinds", [(SE2, ("position", "bearing_range")), (SE3, ("position",))])
def test_the_answer_is_the_conventional_gauges(group, kinds):
    """Solved in the central gauge and moved back, the answer is the one holding the first pose: the
    anchor exactly at its start, every pose and point as the conventional solve's."""
    graph, _, _ = landmark_graph(group, 30, 12, kinds, noise=0.05, seed=3)
    start = _start(graph)
    assert central_anchors(graph, start)[0].fixed.nonzero()[0][0] != 0  # a pose other than the first is held
    tight = SolverParams(relative_tolerance=1e-14)  # both at the optimum, not just within the default tolerance of it
    result = optimize(graph, start, params=tight)
    conventional = optimize(graph, start, tight, hold=np.zeros(graph.num_vertices, dtype=bool))  # hold: not re-gauged
    np.testing.assert_array_equal(result.poses[0], start[0])
    np.testing.assert_allclose(result.poses, conventional.poses, atol=1e-7)
    np.testing.assert_allclose(result.points, conventional.points, atol=1e-7)
    assert result.final_cost == pytest.approx(conventional.final_cost, rel=1e-9)


def test_the_estimates_reported_on_the_way_are_in_the_outputs_gauge():
    """An ``estimate_callback`` (what ``--rerun`` records) sees every iteration's estimate moved back: the
    first pose at its start throughout, the last estimate the answer itself."""
    graph, _, _ = landmark_graph(SE2, 30, 12, ("position",), noise=0.05, seed=3)
    start = _start(graph)
    seen = []
    result = optimize(graph, start, SolverParams(estimate_callback=lambda record, poses, points: seen.append((poses, points))))
    assert len(seen) == result.iterations >= 2
    for poses, _ in seen:
        np.testing.assert_array_equal(poses[0], start[0])
    np.testing.assert_array_equal(seen[-1][0], result.poses)
    np.testing.assert_array_equal(seen[-1][1], result.points)


def test_the_central_pose_is_nearest_each_components_centroid():
    graph, _, _ = landmark_graph(SE2, 20, 6, ("position",), noise=0.01, seed=4)
    poses = np.array(graph.poses)
    poses[:, :2, 2] = np.arange(20)[:, None] * [1.0, 0.0]  # on a line: the centroid is at x = 9.5
    poses[9, :2, 2] = [9.4, 0.0]
    gauged, anchors = central_anchors(graph, poses)
    np.testing.assert_array_equal(np.flatnonzero(gauged.fixed), [9])
    np.testing.assert_array_equal(anchors, component_anchors(graph))


def test_moved_back_moves_each_component_by_its_own_motion():
    """Two components, each moved by a different rigid motion: moving back restores both anchors and
    keeps every relative pose and each point in its pose's frame."""
    graph, _, _ = landmark_graph(SE2, 8, 4, ("position",), noise=0.0, seed=2)
    n, L = graph.num_vertices, graph.landmarks.count
    double = _two_copies(graph)
    start = np.concatenate([graph.poses, graph.poses])
    points = np.concatenate([graph.landmarks.positions] * 2)
    motions = SE2.exp(np.array([[1.0, 2.0, 0.3], [-3.0, 0.5, -1.1]]))
    poses = np.concatenate([motions[0] @ graph.poses, motions[1] @ graph.poses])
    moved = np.concatenate([(points[:L] @ motions[0][:2, :2].T) + motions[0][:2, 2], (points[L:] @ motions[1][:2, :2].T) + motions[1][:2, 2]])
    anchors = component_anchors(double)
    np.testing.assert_array_equal(anchors, [0, n])
    back, back_points = moved_back(double, anchors, start, poses, moved)
    np.testing.assert_allclose(back, start, atol=1e-12)
    np.testing.assert_allclose(back_points, points, atol=1e-12)


def _two_copies(graph):
    """``graph`` twice, side by side (poses and landmarks renumbered), two components."""
    n, L = graph.num_vertices, graph.landmarks.count
    family = graph.landmarks.observations[0]
    twice = replace(family, pose=np.concatenate([family.pose, family.pose + n]), landmark=np.concatenate([family.landmark, family.landmark + L]),
                    measurements=np.concatenate([family.measurements] * 2), information=np.concatenate([family.information] * 2),
                    lines=None, text=None)
    landmarks = Landmarks(ids=np.arange(2 * L), positions=np.concatenate([graph.landmarks.positions] * 2),
                          fixed=np.zeros(2 * L, dtype=bool), observations=(twice,))
    return replace(graph, ids=np.arange(2 * n), poses=np.concatenate([graph.poses] * 2), fixed=np.zeros(2 * n, dtype=bool),
                   edge_from=np.concatenate([graph.edge_from, graph.edge_from + n]), edge_to=np.concatenate([graph.edge_to, graph.edge_to + n]),
                   measurements=np.concatenate([graph.measurements] * 2), information=np.concatenate([graph.information] * 2),
                   edge_lines=None, landmarks=landmarks)


def test_not_used_where_the_gauge_is_fixed_otherwise():
    graph, _, _ = landmark_graph(SE2, 10, 4, ("position",), noise=0.01, seed=1)
    fixed = np.zeros(graph.num_vertices, dtype=bool)
    fixed[3] = True
    assert central_anchors(replace(graph, fixed=fixed), graph.poses) is None
    assert central_anchors(replace(graph, landmarks=None), graph.poses) is None
    with_prior, _, _ = landmark_graph(SE2, 10, 4, ("position", "prior"), noise=0.01, seed=1)
    assert central_anchors(with_prior, with_prior.poses) is None


DATA = Path(__file__).resolve().parents[3] / "data-landmarks"
"""The public landmark files, fetched beside the checkout (benchmarks/bench_landmarks.py), never inside it."""


@pytest.mark.parametrize("name", ["world-2000-default.g2o.gz", "world-2000-lownoise-default.g2o.gz", "dlr.g2o"])
def test_the_central_gauge_takes_no_more_iterations_on_the_public_files(name):
    """From the same start, LM in the central gauge takes no more iterations than holding the first pose
    (the world-2000 defaults: about half), to the same cost."""
    import warnings

    from posegraph.init.relaxation import relaxed_start
    from posegraph.io.g2o import read_g2o

    if not (DATA / name).exists():
        pytest.skip(f"{DATA / name} (fetched outside the repository: benchmarks/bench_landmarks.py) is absent")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the files' DATA_FEATURE lines, which posegraph does not read
        graph = read_g2o(DATA / name)
    start = relaxed_start(graph)  # (the worlds' default start is their file's values, solve/file_start.py)
    central = optimize(graph, start)
    conventional = optimize(graph, start, hold=np.zeros(graph.num_vertices, dtype=bool))
    assert central.converged and central.iterations <= conventional.iterations
    if name.startswith("world"):  # the bend about the first pose (docs/landmarks.md): 16 → 8 and 22 → 9 measured
        assert central.iterations < conventional.iterations
    assert central.final_cost == pytest.approx(conventional.final_cost, rel=1e-6)
