"""Per-edge weights in the linearisation and the pluggable loss of the solver's cost."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.solve import SolverParams, optimize
from posegraph.solve.linearize import linearize
from posegraph.solve.objective import Objective
from posegraph.solve.residuals import cost, edge_residuals
from tests.solve.test_jacobians_gtsam import random_edges
from tests.solve.test_optimizer import synthetic_graph


class Cauchy:
    """``ρ(s) = c² log(1 + s/c²)``: a robust loss for the tests (the project's own live elsewhere)."""

    def __init__(self, c):
        self.c2 = c * c

    def rho(self, s):
        return self.c2 * np.log1p(s / self.c2)

    def weight(self, s):
        return 1.0 / (1.0 + s / self.c2)


class LeastSquares:
    def rho(self, s):
        return s

    def weight(self, s):
        return np.ones_like(s)


def test_unit_weights_give_bit_identical_blocks():
    graph = random_edges(np.random.default_rng(4), n=10, m=50, rotation_scale=1.0)
    plain = linearize(graph.poses, graph)
    weighted = linearize(graph.poses, graph, weights=np.ones(graph.num_edges))
    np.testing.assert_array_equal(weighted.gradient, plain.gradient)
    for got, want in zip(weighted.hessian_blocks, plain.hessian_blocks):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("loss", [None, Cauchy(0.5)], ids=["plain", "cauchy"])
def test_linearising_an_evaluation_reuses_its_weighted_residuals_exactly(loss):
    """The evaluation keeps ``Ω e``; the linearisation from it equals the one that computes it again."""
    graph = random_edges(np.random.default_rng(5), n=10, m=50, rotation_scale=1.0)
    objective = Objective(graph, loss)
    evaluation = objective.evaluate(graph.poses)
    expected = (graph.information @ evaluation.residuals[..., None])[..., 0]
    np.testing.assert_allclose(evaluation.weighted_residuals, expected, rtol=1e-13, atol=1e-13)
    fused = objective.linearize(graph.poses, evaluation)
    again = linearize(graph.poses, graph, errors=(evaluation.relative, evaluation.residuals), weights=evaluation.weights)
    assert np.array_equal(fused.gradient, again.gradient) and fused.cost == again.cost


def test_weights_scale_each_edges_blocks():
    rng = np.random.default_rng(5)
    graph = random_edges(rng, n=10, m=50, rotation_scale=1.0)
    w = rng.uniform(0.0, 3.0, graph.num_edges)
    plain = linearize(graph.poses, graph)
    weighted = linearize(graph.poses, graph, weights=w)
    def close(got, want):  # the products round differently, to ~1e-15 of the largest entry
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13 * np.abs(want).max())

    close(weighted.gradient, w[:, None, None] * plain.gradient)
    for got, want in zip(weighted.hessian_blocks, plain.hessian_blocks):
        close(got, w[:, None, None] * want)
    with pytest.raises(ValueError, match="weights must have shape"):
        linearize(graph.poses, graph, weights=np.ones(3))


def test_robust_gradient_is_the_derivative_of_half_the_summed_loss():
    """With IRLS weights ρ'(s) the gradient blocks, summed per vertex, equal the central
    differences of ½ Σ ρ(s) under right perturbations X_k · Exp(h·e_a)."""
    graph = random_edges(np.random.default_rng(6), n=5, m=12, rotation_scale=0.7)
    objective = Objective(graph, Cauchy(0.5))
    evaluation = objective.evaluate(graph.poses)
    blocks = objective.linearize(graph.poses, evaluation)
    d = graph.group.dim
    gradient = np.zeros((graph.num_vertices, d))
    np.add.at(gradient, graph.edge_from, blocks.gradient[:, 0])
    np.add.at(gradient, graph.edge_to, blocks.gradient[:, 1])
    h = 1e-6
    for k in range(graph.num_vertices):
        for a in range(d):
            step = np.zeros(d)
            step[a] = h
            up, down = graph.poses.copy(), graph.poses.copy()
            up[k] = up[k] @ graph.group.exp(step)
            down[k] = down[k] @ graph.group.exp(-step)
            numeric = (objective.evaluate(up).cost - objective.evaluate(down).cost) / (2 * h)
            assert gradient[k, a] == pytest.approx(numeric, rel=1e-6, abs=1e-6)


def test_without_a_loss_the_objective_is_the_graphs_cost():
    graph = synthetic_graph(2)
    evaluation = Objective(graph).evaluate(graph.poses)
    assert evaluation.cost == cost(graph, graph.poses) and evaluation.weights is None
    np.testing.assert_array_equal(evaluation.residuals, edge_residuals(graph.poses, graph))


def test_a_loss_plugs_into_the_solver_and_the_least_squares_loss_changes_nothing():
    graph = synthetic_graph(4)
    plain = optimize(graph, initial="file")
    same = optimize(graph, initial="file", params=SolverParams(loss=LeastSquares()))
    assert same.final_cost == pytest.approx(plain.final_cost, rel=1e-12)
    assert [r.attempts for r in same.records] == [r.attempts for r in plain.records]
    np.testing.assert_allclose(same.poses, plain.poses, atol=1e-10)


def test_a_robust_loss_discounts_an_outlier():
    """One loop closure replaced by a wild measurement: least squares bends the whole graph towards
    it, the Cauchy loss (cost never increasing over the iterations) leaves it nearly unmet."""
    graph = synthetic_graph(5, noise=0.01)
    measurements = graph.measurements.copy()
    outlier = graph.num_edges - 1
    measurements[outlier] = measurements[outlier] @ graph.group.exp(np.array([1.0, -0.5, 0.8, 3.0, -2.0, 4.0]))
    bad = type(graph)(graph.ids, graph.poses, graph.edge_from, graph.edge_to, measurements, graph.information)
    loss = Cauchy(3.0)
    robust = optimize(bad, initial="file", params=SolverParams(loss=loss))
    plain = optimize(bad, initial="file")
    assert robust.converged
    costs = [robust.initial_cost] + [r.cost for r in robust.records]
    assert all(b <= a for a, b in zip(costs, costs[1:]))
    inliers = np.arange(bad.num_edges) != outlier
    def inlier_error(poses):
        e = edge_residuals(poses, bad)[inliers]
        return float(np.einsum("mi,mij,mj->", e, bad.information[inliers], e))
    assert inlier_error(robust.poses) < 0.1 * inlier_error(plain.poses)
    with pytest.raises(ValueError, match="loss must have"):
        SolverParams(loss=object())
