"""Priors (unary edges): residuals and Jacobians against gtsam's factors and finite differences,
the normal-equation blocks, the gauge they fix and the optimum they lead to."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from posegraph.model.graph import PoseGraph, component_anchors, held_vertices
from posegraph.lie import se2, se3
from posegraph.lie.group import SE2, SE3
from posegraph.model.priors import Priors
from posegraph.robust.losses import make_loss
from posegraph.solve.objective import Objective
from posegraph.solve.optimizer import optimize
from posegraph.solve.params import SolverParams
from posegraph.solve.residuals import cost
from posegraph.solve.unary import linearize_priors, prior_errors, prior_jacobians

gtsam = pytest.importorskip("gtsam")


def random_spd(rng, size, count):
    a = rng.normal(size=(count, size, size))
    return a @ np.swapaxes(a, -1, -2) + size * np.eye(size)


def random_poses(rng, group, count, scale=1.0):
    return group.exp(rng.normal(scale=scale, size=(count, group.dim)))


def chain_graph(rng, group, n=6, priors=None, fixed=None):
    """A noisy chain with loop closures: ``n`` vertices, poses random."""
    poses = random_poses(rng, group, n)
    i = np.r_[np.arange(n - 1), 0, 1]
    j = np.r_[np.arange(1, n), n - 1, n - 2]
    measured = group.between(poses[i], poses[j]) @ group.exp(rng.normal(scale=0.05, size=(len(i), group.dim)))
    return PoseGraph(
        ids=np.arange(n) * 10, poses=poses, edge_from=i, edge_to=j, measurements=measured,
        information=random_spd(rng, group.dim, len(i)), group=group, priors=priors, fixed=fixed,
    )  # fmt: skip


def make_priors(rng, group, n, offsets=True):
    """Two pose priors (one with an offset in 3D) and three position priors on vertices of ``n``."""
    k, d, r = group.matrix_size, group.dim, group.space_dim
    pose_offsets = np.broadcast_to(np.eye(k), (2, k, k)).copy()
    if offsets and group is SE3:
        pose_offsets[1] = random_poses(rng, group, 1)[0]
    return Priors(
        pose_vertex=np.array([1, n - 1]), pose_measurements=random_poses(rng, group, 2),
        pose_offsets=pose_offsets, pose_information=random_spd(rng, d, 2),
        position_vertex=np.array([0, 2, 3]), position_measurements=rng.normal(size=(3, r)),
        position_information=random_spd(rng, r, 3),
    )  # fmt: skip


GROUPS = [pytest.param(SE3, id="SE3"), pytest.param(SE2, id="SE2")]


def gtsam_pose(group, matrix):
    return gtsam.Pose3(matrix) if group is SE3 else gtsam.Pose2(*se2.to_xytheta(matrix))


@pytest.mark.parametrize("group", GROUPS)
def test_residuals_equal_gtsam_prior_factors(group):
    """Pose priors without offset: ``PriorFactorPose3/2``; position priors: ``GPSFactor`` / ``PoseTranslationPrior2D``."""
    rng = np.random.default_rng(1)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6, offsets=False))
    priors, errors = graph.priors, prior_errors(graph.poses, graph)
    pose_factor = gtsam.PriorFactorPose3 if group is SE3 else gtsam.PriorFactorPose2
    position_factor = gtsam.GPSFactor if group is SE3 else gtsam.PoseTranslationPrior2D
    values = gtsam.Values()
    for k, pose in enumerate(graph.poses):
        values.insert(k, gtsam_pose(group, pose))
    for e, (k, Z, omega) in enumerate(zip(priors.pose_vertex, priors.pose_measurements, priors.pose_information)):
        factor = pose_factor(int(k), gtsam_pose(group, Z), gtsam.noiseModel.Gaussian.Information(omega))
        np.testing.assert_allclose(errors.pose[e], factor.unwhitenedError(values), atol=1e-12)
    for e, (k, z, omega) in enumerate(zip(priors.position_vertex, priors.position_measurements,
                                          priors.position_information)):
        factor = position_factor(int(k), z, gtsam.noiseModel.Gaussian.Information(omega))
        np.testing.assert_allclose(errors.position[e], factor.unwhitenedError(values), atol=1e-12)


def test_offset_pose_prior_residual_is_log_of_z_inverse_x_o():
    """``EDGE_SE3_PRIOR`` with an offset: ``Log(Z⁻¹ X O)``, computed with gtsam's Pose3."""
    rng = np.random.default_rng(2)
    graph = chain_graph(rng, SE3, priors=make_priors(rng, SE3, 6))
    priors = graph.priors
    X, Z, O = graph.poses[priors.pose_vertex[1]], priors.pose_measurements[1], priors.pose_offsets[1]
    want = gtsam.Pose3.Logmap(gtsam.Pose3(Z).between(gtsam.Pose3(X).compose(gtsam.Pose3(O))))
    assert not np.allclose(O, np.eye(4))
    np.testing.assert_allclose(prior_errors(graph.poses, graph).pose[1], want, atol=1e-12)


@pytest.mark.parametrize("group", GROUPS)
def test_jacobians_match_central_differences(group):
    rng = np.random.default_rng(3)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6))
    errors = prior_errors(graph.poses, graph)
    jacobian_pose, jacobian_position = prior_jacobians(graph.poses, graph, errors)
    h = 1e-6
    for axis in range(group.dim):
        delta = np.zeros((graph.num_vertices, group.dim))
        delta[:, axis] = h
        plus = prior_errors(graph.poses @ group.exp(delta), graph)
        minus = prior_errors(graph.poses @ group.exp(-delta), graph)
        np.testing.assert_allclose((plus.pose - minus.pose) / (2 * h), jacobian_pose[:, :, axis], atol=1e-7)
        np.testing.assert_allclose((plus.position - minus.position) / (2 * h), jacobian_position[:, :, axis], atol=1e-7)


@pytest.mark.parametrize("group", GROUPS)
def test_normal_equation_blocks_equal_gtsam_linearisation(group):
    """``JᵀΩJ`` and ``JᵀΩe`` of every prior equal gtsam's whitened ``AᵀA`` and ``−Aᵀb``."""
    from posegraph.crosscheck.gtsam_bridge import poses_to_values, prior_factors

    rng = np.random.default_rng(4)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6))
    blocks = linearize_priors(graph.poses, graph, prior_errors(graph.poses, graph))
    factors, values = prior_factors(graph), poses_to_values(graph.ids, graph.poses)
    assert factors.size() == len(graph.priors)
    for k in range(factors.size()):
        a, b = factors.at(k).linearize(values).jacobian()
        np.testing.assert_allclose(blocks.hessian[k], a.T @ a, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(blocks.gradient[k], -a.T @ b, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("group", GROUPS)
def test_cost_equals_gtsam_graph_error(group):
    from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam, poses_to_values

    rng = np.random.default_rng(5)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6))
    want = graph_to_gtsam(graph).error(poses_to_values(graph.ids, graph.poses))
    assert cost(graph) == pytest.approx(want, rel=1e-12)
    assert cost(graph) > cost(replace(graph, priors=None))


@pytest.mark.parametrize("group", GROUPS)
def test_priors_replace_the_anchor_of_the_component_they_reach(group):
    rng = np.random.default_rng(6)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6))
    assert component_anchors(graph).size == 0 and not held_vertices(graph).any()
    fixed = np.zeros(6, dtype=bool)
    fixed[4] = True
    assert np.flatnonzero(held_vertices(replace(graph, fixed=fixed))).tolist() == [4]
    # a second component that no prior reaches keeps its anchor (its smallest id)
    two = chain_graph(rng, group, n=4)
    joined = PoseGraph(
        ids=np.r_[graph.ids, 100 + two.ids], poses=np.concatenate([graph.poses, two.poses]),
        edge_from=np.r_[graph.edge_from, 6 + two.edge_from], edge_to=np.r_[graph.edge_to, 6 + two.edge_to],
        measurements=np.concatenate([graph.measurements, two.measurements]),
        information=np.concatenate([graph.information, two.information]), group=group, priors=graph.priors,
    )  # fmt: skip
    assert component_anchors(joined).tolist() == [6]


@pytest.mark.parametrize("group", GROUPS)
def test_graph_anchored_only_by_priors_reaches_gtsam_optimum(group):
    """No vertex held: the optimum is where the priors put the graph, as gtsam's LM on the same factors finds."""
    from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam, poses_to_values, values_to_poses

    rng = np.random.default_rng(7)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6))
    params = SolverParams(relative_tolerance=1e-14, absolute_tolerance=1e-14)
    ours = optimize(graph, "chordal", params)
    factors = graph_to_gtsam(graph)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setRelativeErrorTol(1e-14)
    lm.setAbsoluteErrorTol(1e-14)
    theirs = gtsam.LevenbergMarquardtOptimizer(factors, poses_to_values(graph.ids, ours.poses), lm).optimize()
    assert ours.final_cost == pytest.approx(factors.error(theirs), rel=1e-9)
    np.testing.assert_allclose(ours.poses, values_to_poses(theirs, graph.ids), atol=1e-6)
    # moving the start rigidly does not move the answer: the priors, not a held vertex, fix the gauge
    moved = optimize(graph, group.exp(rng.normal(size=group.dim)) @ ours.poses, params)
    np.testing.assert_allclose(moved.poses, ours.poses, atol=1e-6)


@pytest.mark.parametrize("group", GROUPS)
def test_chordal_start_lands_where_the_priors_say(group):
    rng = np.random.default_rng(8)
    n = 6
    poses = random_poses(rng, group, n)
    truth_world = group.exp(rng.normal(size=group.dim) * 3)
    r = group.space_dim
    priors = Priors(
        pose_vertex=np.array([2]), pose_measurements=truth_world @ poses[2:3], pose_offsets=np.eye(r + 1)[None],
        pose_information=np.eye(group.dim)[None], position_vertex=np.zeros(0, np.int64),
        position_measurements=np.zeros((0, r)), position_information=np.zeros((0, r, r)),
    )  # fmt: skip
    graph = chain_graph(rng, group, n, priors=priors)
    exact = replace(graph, measurements=group.between(poses[graph.edge_from], poses[graph.edge_to]))
    from posegraph.init import initialize

    start = initialize(exact, "chordal")
    np.testing.assert_allclose(start, truth_world @ poses, atol=1e-8)
    start = initialize(exact, "odometry")
    np.testing.assert_allclose(start, truth_world @ poses, atol=1e-8)


def test_robust_loss_downweights_a_wrong_prior():
    """A GPS fix 100 m off is an outlier like a wrong loop closure: Cauchy gives it a small weight."""
    rng = np.random.default_rng(9)
    priors = make_priors(rng, SE3, 6, offsets=False)
    graph = chain_graph(rng, SE3, priors=priors)
    start = optimize(graph, "chordal").poses
    wrong = priors.position_measurements.copy()
    wrong[0] += 100.0
    bad = replace(graph, priors=replace(priors, position_measurements=wrong))
    evaluation = Objective(bad, make_loss("cauchy", 1.0)).evaluate(start)
    assert evaluation.prior_weights.shape == (len(priors),)
    assert evaluation.prior_weights[2] < 1e-3 < evaluation.prior_weights[[0, 1, 3, 4]].min()
    assert evaluation.cost < Objective(bad).evaluate(start).cost


@pytest.mark.parametrize("group", GROUPS)
def test_marginal_covariances_equal_gtsam_with_priors_only(group):
    """No vertex held: the priors make H invertible, and the marginals are gtsam's ``Marginals``."""
    from posegraph.analysis.covariance import marginal_covariances
    from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam, poses_to_values

    rng = np.random.default_rng(10)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6))
    poses = optimize(graph, "chordal").poses
    ours = marginal_covariances(graph, poses)
    marginals = gtsam.Marginals(graph_to_gtsam(graph), poses_to_values(graph.ids, poses))
    for k, key in enumerate(graph.ids.tolist()):
        np.testing.assert_allclose(ours[k], marginals.marginalCovariance(key), rtol=1e-6, atol=1e-10)
