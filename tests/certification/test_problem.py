"""SE-Sync's problem: κ and τ as its reader computes them, M, F and Q against dense definitions."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.certification.local import translations_given_rotations
from posegraph.certification.problem import (
    component_problems, data_matrix_blocks, edge_residuals, euclidean_gradient, isotropic_precisions, objective,
    sync_problem,
)
from posegraph.errors import GraphError
from posegraph.lie.group import SE2, SE3
from posegraph.solve.sparsity import analyze_pattern, hessian_values
from tests.certification.dense import interleave, reduced_data_matrix, sesync_data_matrix
from tests.certification.graphs import loop_graph
from tests.init.synthetic import information_matrices


def test_precisions_as_sesync_reader_3d():
    """κ = 3/(2 tr(Ω_RR⁻¹)) from g2o's last 3×3 block, τ = 3/tr(Ω_tt⁻¹) from its first (ours is [ω; v])."""
    rng = np.random.default_rng(1)
    g2o_order = information_matrices(rng, 5, 0.5, 50.0)  # [t; r] as the file holds it
    ours = g2o_order[:, [3, 4, 5, 0, 1, 2]][:, :, [3, 4, 5, 0, 1, 2]]
    kappa, tau = isotropic_precisions(ours, SE3)
    for k in range(5):
        assert kappa[k] == pytest.approx(3 / (2 * np.trace(np.linalg.inv(g2o_order[k, 3:, 3:]))), rel=1e-14)
        assert tau[k] == pytest.approx(3 / np.trace(np.linalg.inv(g2o_order[k, :3, :3])), rel=1e-14)


def test_precisions_as_sesync_reader_2d():
    """2D: κ = I33 itself (not an inverse), τ = 2/tr(Ω_tt⁻¹)."""
    rng = np.random.default_rng(2)
    info = information_matrices(rng, 4, 0.5, 50.0, size=3)  # [x, y, θ], as g2o's EDGE_SE2
    kappa, tau = isotropic_precisions(info, SE2)
    np.testing.assert_array_equal(kappa, info[:, 2, 2])
    np.testing.assert_allclose(tau, 2 / np.trace(np.linalg.inv(info[:, :2, :2]), axis1=1, axis2=2), rtol=1e-14)


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
def test_data_matrix_against_dense_definition(group):
    """The block-sparse M, permuted to SE-Sync's layout, equals eq. 16 built entry by entry."""
    graph, _ = loop_graph(3, n=7, loops=5, rotation_noise=0.3, translation_noise=0.2, group=group)
    problem = sync_problem(graph)
    n, d = problem.num_poses, problem.d
    pattern = analyze_pattern(n, problem.edge_from, problem.edge_to, np.zeros(n, bool), d + 1)
    lower = np.zeros((pattern.dimension,) * 2)
    lower[pattern.indices, pattern.entry_columns] = hessian_values(pattern, data_matrix_blocks(problem))
    ours = lower + np.tril(lower, -1).T
    perm = interleave(n, d)
    np.testing.assert_allclose(ours, sesync_data_matrix(problem)[np.ix_(perm, perm)], atol=1e-12)


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
def test_objective_is_the_sum_of_edge_terms_and_trace_form(group):
    """F = Σ κ‖R_j − R_i R̃‖² + τ‖t_j − t_i − R_i t̃‖² = tr(X M Xᵀ), and ∇F = 2 X M."""
    graph, truth = loop_graph(4, n=6, loops=4, rotation_noise=0.4, translation_noise=0.3, group=group)
    problem = sync_problem(graph)
    d, n = problem.d, problem.num_poses
    poses = graph.poses
    rot, tra = poses[:, :d, :d], poses[:, :d, d]
    i, j = problem.edge_from, problem.edge_to
    direct = np.sum(problem.kappa * np.sum((rot[j] - rot[i] @ problem.rotations) ** 2, axis=(1, 2)))
    direct += np.sum(problem.tau * np.sum((tra[j] - tra[i] - (rot[i] @ problem.translations[:, :, None])[:, :, 0]) ** 2, axis=1))
    u = np.concatenate([tra[:, :, None], rot], axis=2)
    x = np.concatenate([tra.T, np.concatenate(list(rot), axis=1)], axis=1)  # SE-Sync's X = [t | R]
    m = sesync_data_matrix(problem)
    assert objective(problem, u) == pytest.approx(direct, rel=1e-12)
    assert objective(problem, u) == pytest.approx(np.trace(x @ m @ x.T), rel=1e-12)
    gradient = 2 * x @ m
    perm = interleave(n, d)
    ours = np.swapaxes(euclidean_gradient(problem, u), 0, 1).reshape(d, -1)
    np.testing.assert_allclose(ours, gradient[:, perm], atol=1e-9 * np.abs(gradient).max())
    assert edge_residuals(problem, u).shape == (problem.num_edges, d, d + 1)


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
def test_reduced_matrix_is_the_minimum_over_translations(group):
    """``tr(R Q Rᵀ) = min_t F(t, R)``, attained by SE-Sync's recovered translations."""
    graph, _ = loop_graph(5, n=8, loops=6, rotation_noise=0.2, translation_noise=0.3, group=group)
    problem = sync_problem(graph)
    d = problem.d
    rotations = graph.poses[:, :d, :d]
    translations = translations_given_rotations(problem, rotations, anchor=2)
    assert np.allclose(translations[2], 0.0)
    u = np.concatenate([translations[:, :, None], rotations], axis=2)
    y = np.concatenate(list(rotations), axis=1)
    assert objective(problem, u) == pytest.approx(np.trace(y @ reduced_data_matrix(problem) @ y.T), rel=1e-9)
    moved = u.copy()
    moved[:, :, 0] += np.random.default_rng(0).normal(scale=0.01, size=(problem.num_poses, d))
    assert objective(problem, moved) > objective(problem, u)


def test_components_split_into_their_own_problems_and_singular_information_is_refused():
    """Cutting the chain 2 → 3 gives two problems whose F add up to the whole's."""
    graph, _ = loop_graph(6, n=6, loops=0)
    keep = graph.edge_from != 2  # cut the chain 2 → 3
    import dataclasses

    cut = dataclasses.replace(graph, edge_from=graph.edge_from[keep], edge_to=graph.edge_to[keep],
                              measurements=graph.measurements[keep], information=graph.information[keep])
    problem = sync_problem(cut)
    parts = component_problems(problem)
    assert [list(v) for v, _ in parts] == [[0, 1, 2], [3, 4, 5]]
    u = np.concatenate([graph.poses[:, :3, 3:], graph.poses[:, :3, :3]], axis=2)
    assert sum(objective(sub, u[v]) for v, sub in parts) == pytest.approx(objective(problem, u), rel=1e-12)
    information = graph.information.copy()
    information[1, 3:, 3:] = 0.0
    with pytest.raises(GraphError, match="κ and τ"):
        sync_problem(dataclasses.replace(graph, information=information))


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
def test_pose_priors_are_edges_from_a_world_vertex(group):
    """A pose prior ``Z ≈ X O`` (an offset in 3D) is the edge world → k measuring ``Z O⁻¹`` with information
    ``Ad_{O⁻¹}ᵀ Ω Ad_{O⁻¹}``: the same g2o cost as the prior, for any poses."""
    import dataclasses

    from posegraph.certification.certificate import isotropic_graph
    from posegraph.model.graph import PoseGraph
    from posegraph.solve.residuals import cost
    from posegraph.solve.unary import prior_cost
    from tests.solve.test_unary import chain_graph, make_priors

    rng = np.random.default_rng(7)
    priors = make_priors(rng, group, 6)
    priors = dataclasses.replace(priors, position_vertex=priors.position_vertex[:0],
                                 position_measurements=priors.position_measurements[:0],
                                 position_information=priors.position_information[:0])  # fmt: skip
    graph = chain_graph(rng, group, priors=priors)
    problem = sync_problem(graph)
    assert problem.num_poses == 7 and problem.num_edges == graph.num_edges + 2
    world = np.r_[graph.poses, np.eye(group.matrix_size)[None]]
    edges = slice(graph.num_edges, None)
    undo = group.adjoint(group.inverse(priors.pose_offsets))
    as_edges = PoseGraph(ids=np.arange(7), poses=world, edge_from=problem.edge_from[edges],
                         edge_to=problem.edge_to[edges], measurements=priors.pose_measurements @ group.inverse(priors.pose_offsets),
                         information=np.swapaxes(undo, 1, 2) @ priors.pose_information @ undo, group=group)  # fmt: skip
    assert cost(as_edges, world) == pytest.approx(prior_cost(graph.poses, graph), rel=1e-10)
    assert isotropic_graph(graph).priors is None


def test_a_similarity_graph_or_one_with_position_priors_is_refused_not_certified():
    """SE-Sync's problem has no scale and no terms for a position alone: certifying such a graph would
    certify another problem."""
    from datasets.synthetic import monocular
    from tests.solve.test_unary import chain_graph, make_priors

    with pytest.raises(GraphError, match="SE\\(2\\) and SE\\(3\\)"):
        sync_problem(monocular(laps=2, nodes_per_lap=20).graph)
    rng = np.random.default_rng(5)
    with pytest.raises(GraphError, match="position priors"):
        sync_problem(chain_graph(rng, SE3, priors=make_priors(rng, SE3, 6)))
    sync_problem(chain_graph(rng, SE3))  # the same chain without priors is SE-Sync's problem


def test_a_landmark_graph_is_refused_in_one_line():
    from datasets.synthetic import landmark_graph
    from posegraph.errors import GraphError
    from posegraph.lie.group import SE2
    from posegraph.certification.problem import sync_problem

    graph, _, _ = landmark_graph(SE2, 5, 3, ("position",), noise=0.01, seed=0)
    with pytest.raises(GraphError, match="3 landmarks, which SE-Sync's problem has no variables for") as caught:
        sync_problem(graph)
    assert "\n" not in str(caught.value)
