"""Point elimination (benchmarks/point_elimination.py, measured in docs/landmarks.md): the explicit Schur
complement on the points and CHOLMOD with the points ordered first solve the same damped system as
today's CHOLMOD (AMD) path, to round-off, and LM through them reaches the same optimum."""

from dataclasses import replace

import numpy as np
import pytest

from benchmarks.point_elimination import PointsFirstCholmod, SchurComplementSolver, reduced_pose_graph
from datasets.synthetic import landmark_graph
from posegraph.lie.group import SE2, SE3
from posegraph.solve.landmark_terms import add_landmark_gradient, add_landmark_hessian
from posegraph.solve.linear import NotPositiveDefiniteError, cholmod_available
from posegraph.solve.objective import Objective
from posegraph.solve.optimizer import analyze, optimize
from posegraph.solve.sparsity import gradient_values, hessian_values

pytestmark = pytest.mark.skipif(not cholmod_available(), reason="cvxopt's CHOLMOD is not installed")

GRAPHS = [
    pytest.param(SE2, ("position", "bearing_range", "prior"), False, id="2d"),
    pytest.param(SE3, ("position",), True, id="3d-offsets"),
]
ELIMINATIONS = [pytest.param(SchurComplementSolver, id="schur"), pytest.param(PointsFirstCholmod, id="points-first")]


def _graph(group, kinds, offsets, seed=5):
    graph, _, _ = landmark_graph(group, 12, 9, kinds, noise=0.05, seed=seed, per_landmark=4, offsets=offsets)
    return graph


def _system(graph):
    """``(analysis, lower-triangle data of H, g, dense symmetric H)`` at the graph's own values."""
    analysis = analyze(graph)
    pattern, objective = analysis.pattern, Objective(graph)
    points = graph.landmarks.positions
    blocks = objective.linearize(graph.poses, objective.evaluate(graph.poses, points))
    gradient = gradient_values(pattern, blocks.gradient)
    add_landmark_gradient(pattern, gradient, blocks.landmarks)
    data = hessian_values(pattern, blocks.hessian_slice)
    add_landmark_hessian(pattern, data, blocks.landmarks)
    lower = np.zeros((pattern.dimension, pattern.dimension))
    lower[pattern.indices, pattern.entry_columns] = data
    return analysis, data, gradient, lower + np.tril(lower, -1).T


@pytest.mark.parametrize("group, kinds, offsets", GRAPHS)
@pytest.mark.parametrize("elimination", ELIMINATIONS)
@pytest.mark.parametrize("damping", [0.0, 1e-3, 10.0])
def test_the_point_eliminated_solve_equals_the_full_one(group, kinds, offsets, elimination, damping):
    graph = _graph(group, kinds, offsets)
    analysis, data, gradient, dense = _system(graph)
    pattern = analysis.pattern
    assert pattern.num_variables > pattern.num_pose_variables > 0  # points to eliminate, poses to keep
    shift = damping * np.abs(dense.diagonal()) + damping
    full = analysis.solver
    full.factorize(data, shift)
    eliminated = elimination(pattern)
    eliminated.factorize(data, shift)
    rhs = -gradient
    expected = np.linalg.solve(dense + np.diag(shift), rhs)
    for solver in (full, eliminated):
        np.testing.assert_allclose(solver.solve(rhs), expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    several = np.random.default_rng(1).normal(size=(3, pattern.dimension))  # the held factor serves any rhs
    for rhs in several:
        np.testing.assert_allclose(eliminated.solve(rhs), full.solve(rhs), rtol=0, atol=1e-9 * np.abs(full.solve(rhs)).max())


@pytest.mark.parametrize("group, kinds, offsets", GRAPHS)
def test_the_reduced_pose_graph_joins_the_poses_that_share_a_point(group, kinds, offsets):
    graph = _graph(group, kinds, offsets)
    pattern = analyze(graph).pattern
    reduced = reduced_pose_graph(pattern)
    variable = pattern.variable_of
    expected = set()
    for first, second in zip(variable[graph.edge_from], variable[graph.edge_to]):
        if first >= 0 and second >= 0:
            expected.add((max(first, second), min(first, second)))
    seen_by = [(variable[f.pose], f.landmark) for f in graph.landmarks.observations if f.kind != "prior"]
    pose, landmark = (np.concatenate(parts) for parts in zip(*seen_by))
    for point in np.unique(landmark):
        seen = np.unique(pose[(landmark == point) & (pose >= 0)])
        expected.update((int(a), int(b)) for a in seen for b in seen if a > b)
    columns = np.repeat(np.arange(reduced.num_variables), np.diff(reduced.block_indptr))
    stored = {(int(r), int(c)) for r, c in zip(reduced.block_indices, columns) if r != c}
    assert stored == expected


def test_a_point_block_that_is_not_positive_definite_is_refused():
    graph = _graph(SE2, ("position",), False)
    analysis, data, _, _ = _system(graph)
    pattern = analysis.pattern
    solver = SchurComplementSolver(pattern)
    first_point = pattern.offsets[pattern.num_pose_variables]
    shift = np.zeros(pattern.dimension)
    shift[first_point] = -2.0 * data[pattern.diagonal[first_point]]  # that point's block made indefinite
    with pytest.raises(NotPositiveDefiniteError):
        solver.factorize(data, shift)
    with pytest.raises(RuntimeError):
        solver.solve(np.zeros(pattern.dimension))


@pytest.mark.parametrize("group, kinds, offsets", GRAPHS)
@pytest.mark.parametrize("elimination", ELIMINATIONS)
def test_lm_through_the_elimination_reaches_the_same_optimum(group, kinds, offsets, elimination):
    graph = _graph(group, kinds, offsets, seed=8)
    analysis = analyze(graph)
    today = optimize(graph, "file", analysis=analysis)
    other = optimize(graph, "file", analysis=replace(analysis, solver=elimination(analysis.pattern)))
    assert today.converged and other.converged and today.iterations > 1
    assert other.iterations == today.iterations
    np.testing.assert_allclose(other.final_cost, today.final_cost, rtol=1e-9)
    np.testing.assert_allclose(other.poses, today.poses, atol=1e-7)
    np.testing.assert_allclose(other.points, today.points, atol=1e-7)
