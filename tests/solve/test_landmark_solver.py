"""The solver over poses and landmarks: blocks of two sizes in one system (posegraph.solve.sparsity,
landmark_terms, optimizer), checked against finite differences, the noise-free truth and gtsam."""

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.lie.group import SE2, SE3
from posegraph.model.graph import held_vertices
from posegraph.solve.landmark_terms import add_landmark_gradient, add_landmark_hessian
from posegraph.solve.objective import Objective
from posegraph.solve.optimizer import analyze, optimize
from posegraph.solve.params import SolverParams
from posegraph.solve.sparsity import gradient_values, hessian_values

CASES = [
    (SE2, ("position", "bearing_range", "bearing", "prior"), False),
    (SE2, ("position",), False),
    (SE3, ("position",), True),
    (SE3, ("position", "prior"), True),
]


def _perturbed(graph, truth, points, seed, size=0.05):
    rng = np.random.default_rng(seed)
    poses = truth @ graph.group.exp(rng.normal(size=(graph.num_vertices, graph.group.dim)) * size)
    return poses, points + rng.normal(size=points.shape) * size


def _system(graph, poses, points):
    """(pattern, held, g, dense symmetric H) of the solver's assembly at poses, points."""
    analysis = analyze(graph)
    pattern, objective = analysis.pattern, Objective(graph)
    evaluation = objective.evaluate(poses, points)
    blocks = objective.linearize(poses, evaluation)
    gradient = gradient_values(pattern, blocks.gradient)
    add_landmark_gradient(pattern, gradient, blocks.landmarks)
    data = hessian_values(pattern, blocks.hessian_slice)
    add_landmark_hessian(pattern, data, blocks.landmarks)
    size = pattern.dimension
    lower = np.zeros((size, size))
    lower[pattern.indices, pattern.entry_columns] = data
    return analysis, objective, gradient, lower + np.tril(lower, -1).T


def _moved(analysis, graph, poses, points, delta):
    pattern = analysis.pattern
    moved = poses.copy()
    free = ~analysis.held
    moved[free] = poses[free] @ graph.group.exp(delta[: pattern.pose_dimension].reshape(-1, graph.group.dim))
    return moved, points + pattern.expand_points(delta)


def _whitened(objective, graph, poses, points):
    evaluation = objective.evaluate(poses, points)
    root = np.linalg.cholesky(graph.information)
    parts = [np.einsum("mji,mj->mi", root, evaluation.residuals).ravel()]
    for e, family in zip(evaluation.landmarks.residuals, graph.landmarks.observations):
        parts.append(np.einsum("mji,mj->mi", np.linalg.cholesky(family.information), e).ravel())
    return np.concatenate(parts)


@pytest.mark.parametrize("group, kinds, offsets", CASES)
def test_gradient_and_hessian_equal_finite_differences(group, kinds, offsets):
    graph, truth, points = landmark_graph(group, 7, 5, kinds, noise=0.05, seed=3, offsets=offsets)
    fixed = np.zeros(graph.landmarks.count, dtype=bool)
    fixed[1] = True  # a FIX landmark has no variable
    graph = replace(graph, landmarks=replace(graph.landmarks, fixed=fixed))
    poses, start = _perturbed(graph, truth, points, seed=4)
    analysis, objective, gradient, hessian = _system(graph, poses, start)
    free_poses = graph.num_vertices - int(held_vertices(graph).sum())
    assert free_poses == graph.num_vertices  # the FIX landmark ties the gauge: no pose is held
    assert analysis.pattern.dimension == group.dim * free_poses + group.space_dim * (graph.landmarks.count - 1)
    h = 1e-6
    eye = np.eye(analysis.pattern.dimension)
    cost = lambda delta: objective.evaluate(*_moved(analysis, graph, poses, start, delta)).cost  # noqa: E731
    numeric = np.array([(cost(h * e) - cost(-h * e)) / (2 * h) for e in eye])
    np.testing.assert_allclose(gradient, numeric, rtol=1e-6, atol=1e-6 * np.abs(gradient).max())
    residual = lambda delta: _whitened(objective, graph, *_moved(analysis, graph, poses, start, delta))  # noqa: E731
    jacobian = np.array([(residual(h * e) - residual(-h * e)) / (2 * h) for e in eye]).T
    np.testing.assert_allclose(hessian, jacobian.T @ jacobian, atol=1e-6 * np.abs(hessian).max())


@pytest.mark.parametrize("group, kinds, offsets", CASES)
def test_a_noise_free_graph_reaches_its_truth(group, kinds, offsets):
    graph, truth, points = landmark_graph(group, 12, 8, kinds, noise=0.0, seed=5, offsets=offsets)
    poses, start = _perturbed(graph, truth, points, seed=6, size=0.1)
    poses[0] = truth[0]  # the anchor (first pose) is held where it is
    result = optimize(graph, poses, initial_points=start)
    assert result.converged and result.final_cost < 1e-12 * result.initial_cost
    if "prior" not in kinds:  # point priors tie the gauge by themselves (held nothing): then the cost says it
        np.testing.assert_allclose(result.poses, truth, atol=1e-7)
        np.testing.assert_allclose(result.points, points, atol=1e-7)


def test_a_fixed_landmark_stays_and_the_others_move():
    graph, truth, points = landmark_graph(SE2, 10, 6, ("position", "bearing_range"), noise=0.05, seed=7)
    fixed = np.zeros(graph.landmarks.count, dtype=bool)
    fixed[[0, 3]] = True
    graph = replace(graph, landmarks=replace(graph.landmarks, fixed=fixed))
    result = optimize(graph, "file", initial_points=graph.landmarks.positions)
    np.testing.assert_array_equal(result.points[fixed], graph.landmarks.positions[fixed])
    assert np.all(np.abs(result.points[~fixed] - graph.landmarks.positions[~fixed]).max(axis=1) > 0)
    assert held_vertices(graph).sum() == 0  # the fixed landmarks anchor the component: no pose held
    assert result.converged and result.final_cost < result.initial_cost


@pytest.mark.parametrize("group, kinds, offsets", CASES[:3])
@pytest.mark.parametrize("linear_solver", ["cholmod", "scipy"])
def test_the_optimum_is_gtsams(group, kinds, offsets, linear_solver):
    pytest.importorskip("gtsam")
    from posegraph.crosscheck.gtsam_landmarks import gtsam_landmark_cost, run_gtsam_landmarks

    graph, truth, points = landmark_graph(group, 15, 10, kinds, noise=0.05, seed=8, offsets=offsets)
    ours = optimize(graph, "file", SolverParams(linear_solver=linear_solver, relative_tolerance=1e-12, absolute_tolerance=0.0),
                    initial_points=graph.landmarks.positions)  # fmt: skip
    theirs = run_gtsam_landmarks(graph)
    assert abs(gtsam_landmark_cost(graph, ours.poses, ours.points) - ours.final_cost) <= 1e-9 * ours.final_cost
    assert ours.final_cost <= theirs.final_cost * (1 + 1e-6)
    np.testing.assert_allclose(ours.points, theirs.points, atol=1e-5)


def test_pcg_is_refused_with_landmarks():
    graph, _, _ = landmark_graph(SE2, 6, 4, ("position",), noise=0.01, seed=1)
    from posegraph.errors import GraphError

    with pytest.raises(GraphError, match="pcg"):
        optimize(graph, "file", SolverParams(linear_solver="pcg"), initial_points=graph.landmarks.positions)


def test_a_landmark_seen_by_one_bearing_is_named(recwarn):
    from posegraph.errors import InputWarning
    from posegraph.model.landmarks import Observations

    graph, _, _ = landmark_graph(SE2, 8, 4, ("position",), noise=0.01, seed=2)
    landmarks = graph.landmarks
    lonely = Observations("bearing", np.array([3]), np.array([4]), np.array([[0.3]]), np.array([[[100.0]]]), tag="EDGE_BEARING_SE2_XY")
    landmarks = replace(landmarks, ids=np.append(landmarks.ids, 777), positions=np.vstack([landmarks.positions, [[0.0, 0.0]]]),
                        fixed=np.append(landmarks.fixed, False), observations=landmarks.observations + (lonely,))  # fmt: skip
    graph = replace(graph, landmarks=landmarks)
    with pytest.warns(InputWarning, match=r"1 landmark not determined .*: 777;"):
        result = optimize(graph, "odometry")
    assert np.all(np.isfinite(result.points)) and result.final_cost <= result.initial_cost


def test_cost_counts_the_landmark_terms_as_the_solver_starts():
    from posegraph.solve.landmark_residuals import landmark_cost
    from posegraph.solve.residuals import cost, edge_residuals, weighted_cost

    graph, truth, _ = landmark_graph(SE2, 9, 5, ("position", "bearing"), noise=0.05, seed=9)
    pose_terms = weighted_cost(edge_residuals(graph.poses, graph), graph.information)
    assert cost(graph) == pytest.approx(pose_terms + landmark_cost(graph.group, graph.poses, graph.landmarks.positions, graph.landmarks), rel=1e-14)
    assert cost(graph) > pose_terms
    started = optimize(graph, truth, SolverParams(max_iterations=1))
    assert cost(graph, truth) == pytest.approx(started.initial_cost, rel=1e-14)  # landmarks started from the poses


@pytest.mark.parametrize("method", ["chordal", "odometry"])
def test_point_priors_alone_tie_the_gauge_and_the_start_still_works(method):
    graph, truth, points = landmark_graph(SE2, 10, 6, ("position", "prior"), noise=0.02, seed=12)
    assert held_vertices(graph).sum() == 0  # the point priors hold the gauge: no pose is held
    result = optimize(graph, method)
    from_truth = optimize(graph, truth, initial_points=points)
    assert result.converged and result.final_cost == pytest.approx(from_truth.final_cost, rel=1e-9)
    np.testing.assert_allclose(result.points, from_truth.points, atol=1e-6)


def test_a_graph_without_pose_edges_solves_its_landmarks():
    """gtsam's edge_se3_trackxyz_*.g2o: one pose, one landmark, one measurement through an offset."""
    from posegraph.model.graph import PoseGraph
    from posegraph.model.landmarks import Landmarks, Observations

    offset = SE3.exp(np.array([[0.1, -0.2, 0.3, 0.5, 0.0, -0.1]]))
    pose = SE3.exp(np.array([[0.0, 0.0, 0.7, 1.0, -2.0, 0.5]]))
    z = np.array([[2.0, 1.0, 3.0]])
    family = Observations("position", np.array([0]), np.array([0]), z, np.eye(3)[None] * 4.0, offsets=offset)
    graph = PoseGraph(np.array([7]), pose, np.zeros(0, int), np.zeros(0, int), np.zeros((0, 4, 4)), np.zeros((0, 6, 6)),
                      landmarks=Landmarks(np.array([9]), np.array([[0.0, 0.0, 3.5]]), (family,)))  # fmt: skip
    result = optimize(graph, "file", initial_points=graph.landmarks.positions)
    sensor = pose[0] @ offset[0]
    np.testing.assert_allclose(result.points[0], sensor[:3, :3] @ z[0] + sensor[:3, 3], atol=1e-9)
    assert result.final_cost < 1e-18
