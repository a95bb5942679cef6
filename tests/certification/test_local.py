"""The rank-d Newton refinement: exact derivatives of F ∘ retraction, convergence to a critical point."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.certification.certificate import poses_to_blocks
from posegraph.certification.local import generators, newton_blocks, refine_poses, retract_poses
from posegraph.certification.problem import edge_maps, objective, sync_problem
from posegraph.lie.group import SE2, SE3
from posegraph.solve.sparsity import analyze_pattern, gradient_values, hessian_values
from tests.certification.graphs import loop_graph

GROUPS = pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])


def _dense_newton(problem, u):
    n, d = problem.num_poses, problem.d
    p = d + d * (d - 1) // 2
    pattern = analyze_pattern(n, problem.edge_from, problem.edge_to, np.zeros(n, bool), p)
    blocks, grads, cost = newton_blocks(problem, u, edge_maps(problem), generators(d))
    lower = np.zeros((pattern.dimension,) * 2)
    lower[pattern.indices, pattern.entry_columns] = hessian_values(pattern, blocks)
    return lower + np.tril(lower, -1).T, gradient_values(pattern, grads), cost, p


@GROUPS
def test_gradient_and_hessian_match_finite_differences(group):
    """g and H are the first and second derivatives of x ↦ F(retract(u, x)) at 0 (central differences)."""
    graph, _ = loop_graph(7, n=5, loops=3, rotation_noise=0.5, translation_noise=0.5, group=group)
    problem = sync_problem(graph)
    u = poses_to_blocks(graph.poses)
    hessian, gradient, cost, p = _dense_newton(problem, u)
    assert cost == pytest.approx(objective(problem, u), rel=1e-13)
    n, h = problem.num_poses, 1e-4
    f = lambda x: objective(problem, retract_poses(u, x.reshape(n, p)))  # noqa: E731
    size = n * p
    basis = np.eye(size)
    numeric_gradient = np.array([(f(h * e) - f(-h * e)) / (2 * h) for e in basis])
    np.testing.assert_allclose(gradient, numeric_gradient, rtol=1e-6, atol=1e-6 * np.abs(gradient).max())
    rng = np.random.default_rng(0)
    for _ in range(5):
        a, b = rng.normal(size=size), rng.normal(size=size)
        numeric = (f(h * (a + b)) - f(h * (a - b)) - f(h * (b - a)) + f(-h * (a + b))) / (4 * h * h)
        assert a @ hessian @ b == pytest.approx(numeric, rel=1e-4, abs=1e-5 * np.abs(hessian).max())


@GROUPS
def test_refine_reaches_a_critical_point_and_recovers_exact_poses(group):
    """Noise-free: F → 0 and the poses are the truth up to the anchor's rigid motion."""
    graph, truth = loop_graph(8, n=15, loops=10, group=group)
    problem = sync_problem(graph)
    start = graph.poses @ group.exp(0.05 * np.random.default_rng(1).normal(size=(15, group.dim)))
    u, value, iterations = refine_poses(problem, poses_to_blocks(start), anchor=0)
    assert value < 1e-16
    d = problem.d
    poses = np.zeros_like(truth)
    poses[:, :d, :d], poses[:, :d, d], poses[:, d, d] = u[:, :, 1:], u[:, :, 0], 1.0
    aligned = truth[0] @ np.linalg.inv(poses[0]) @ poses
    np.testing.assert_allclose(aligned, truth, atol=1e-8)


@GROUPS
def test_refine_from_a_noisy_start_zeroes_the_gradient(group):
    graph, _ = loop_graph(9, n=15, loops=10, rotation_noise=0.05, translation_noise=0.1, group=group)
    problem = sync_problem(graph)
    u, value, _ = refine_poses(problem, poses_to_blocks(graph.poses), anchor=0)
    _, gradient, cost, _ = _dense_newton(problem, u)
    assert value == pytest.approx(cost, rel=1e-9)
    assert np.abs(gradient).max() < 1e-8 * max(cost, 1.0)
