"""The solver takes every size and function from ``graph.group``: SO(3) through the same code."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.model.graph import PoseGraph
from posegraph.lie import se3, so3
from posegraph.lie.group import SE3, LieGroup
from posegraph.solve import SolverParams, optimize
from posegraph.solve.residuals import edge_jacobians

T = lambda x: np.swapaxes(x, -1, -2)  # noqa: E731

SO3 = LieGroup(
    name="SO3", dim=3, matrix_size=3, exp=so3.exp, log=so3.log, inverse=T, compose=np.matmul,
    between=lambda a, b: T(a) @ b, adjoint=lambda r: np.array(r, copy=True),  # Ad(R) = R
    right_jacobian=so3.right_jacobian, right_jacobian_inverse=so3.right_jacobian_inverse,
)  # fmt: skip


def rotation_graph(seed, n=25, loops=15):
    """Noisy relative rotations along a walk with loop closures, as an SO(3) graph."""
    rng = np.random.default_rng(seed)
    truth = so3.exp(rng.normal(scale=1.0, size=(n, 3)))
    pairs = [(k, k + 1) for k in range(n - 1)] + [tuple(rng.choice(n, 2, replace=False)) for _ in range(loops)]
    edge_from, edge_to = (np.array(side) for side in zip(*pairs))
    measurements = T(truth[edge_from]) @ truth[edge_to] @ so3.exp(rng.normal(scale=0.05, size=(len(pairs), 3)))
    information = np.tile(np.diag([50.0, 80.0, 120.0]), (len(pairs), 1, 1))
    start = truth @ so3.exp(rng.normal(scale=0.3, size=(n, 3)))
    return PoseGraph(np.arange(n), start, edge_from, edge_to, measurements, information, group=SO3)


def as_se3(graph):
    """The same graph in SE(3) with every translation zero and translation information 1."""
    lift = lambda r: se3.from_rotation_translation(r, np.zeros(r.shape[:-2] + (3,)))  # noqa: E731
    information = np.zeros((graph.num_edges, 6, 6))
    information[:, :3, :3] = graph.information
    information[:, 3:, 3:] = np.eye(3)
    return PoseGraph(graph.ids, lift(graph.poses), graph.edge_from, graph.edge_to, lift(graph.measurements), information)


def test_the_default_group_is_se3_built_from_its_module():
    assert (SE3.name, SE3.dim, SE3.matrix_size) == ("SE3", 6, 4)
    xi = np.random.default_rng(0).normal(size=(4, 6))
    np.testing.assert_array_equal(SE3.exp(xi), se3.exp(xi))
    np.testing.assert_array_equal(SE3.right_jacobian_inverse(xi), se3.right_jacobian_inverse(xi))
    np.testing.assert_array_equal(SE3.between(SE3.exp(xi), SE3.exp(-xi)), se3.between(se3.exp(xi), se3.exp(-xi)))


def test_the_group_calls_what_its_module_holds(monkeypatch):
    """A function replaced in the module (as the verification tests do) is what the group runs."""
    monkeypatch.setattr(se3, "exp", lambda xi: "replaced")
    assert SE3.exp(np.zeros(6)) == "replaced"


def test_residual_jacobians_of_another_group_match_finite_differences():
    graph = rotation_graph(1, n=6, loops=4)
    a_i, a_j = edge_jacobians(graph.poses, graph)
    assert a_i.shape == a_j.shape == (graph.num_edges, 3, 3)
    h = 1e-6
    for vertex_side, jacobian in ((graph.edge_from, a_i), (graph.edge_to, a_j)):
        for a in range(3):
            step = np.zeros(3)
            step[a] = h
            moved = lambda s: graph.poses[vertex_side] @ so3.exp(s)  # noqa: E731
            def residual(s):
                poses_i = moved(s) if vertex_side is graph.edge_from else graph.poses[graph.edge_from]
                poses_j = moved(s) if vertex_side is graph.edge_to else graph.poses[graph.edge_to]
                return so3.log(T(graph.measurements) @ T(poses_i) @ poses_j)
            numeric = (residual(step) - residual(-step)) / (2 * h)
            np.testing.assert_allclose(jacobian[..., a], numeric, atol=1e-7)


@pytest.mark.parametrize("linear_solver", ["scipy", "cholmod"])
@pytest.mark.parametrize("method", ["lm", "gn"])
def test_so3_graph_reaches_the_rotations_of_the_se3_graph_with_zero_translations(method, linear_solver):
    """With zero translations everywhere the SE(3) cost splits: its translation residuals stay zero and
    its rotations solve the SO(3) problem. Both runs go through the one solver: blocks of 3 and of 6."""
    from posegraph.solve.linear import cholmod_available

    if linear_solver == "cholmod" and not cholmod_available():
        pytest.skip("CHOLMOD (cvxopt) is not installed")
    graph = rotation_graph(2)
    tight = SolverParams(method=method, relative_tolerance=1e-13, absolute_tolerance=1e-15, linear_solver=linear_solver)
    rotations = optimize(graph, initial="file", params=tight)
    poses = optimize(as_se3(graph), initial="file", params=tight)
    assert rotations.converged and poses.converged
    assert rotations.final_cost < 0.05 * rotations.initial_cost
    assert rotations.final_cost == pytest.approx(poses.final_cost, rel=1e-9)
    np.testing.assert_allclose(poses.poses[:, :3, :3], rotations.poses, atol=1e-8)
    np.testing.assert_allclose(poses.poses[:, :3, 3], 0.0, atol=1e-12)
    np.testing.assert_array_equal(rotations.poses[0], graph.poses[0])  # the anchor holds the gauge


def test_initial_poses_must_be_matrices_of_the_graphs_group():
    graph = rotation_graph(3, n=5, loops=2)
    with pytest.raises(ValueError, match=r"\(5, 3, 3\)"):
        optimize(graph, initial=np.tile(np.eye(4), (5, 1, 1)))
