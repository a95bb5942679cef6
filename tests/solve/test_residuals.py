"""Residuals and cost: equal to gtsam's BetweenFactorPose3 errors on every file, plus identities."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.model.graph import PoseGraph
from posegraph.io.g2o import read_g2o
from posegraph.lie import se3
from posegraph.solve.residuals import cost, edge_residuals
from tests.solve.gtsam_reference import gtsam_graph, perturbed_poses, read_shared_file, values_from_poses


def test_cost_equals_gtsam_error_on_every_shared_file(shared_g2o_file):
    graph = read_shared_file(shared_g2o_file)
    factors, values = gtsam_graph(shared_g2o_file, graph)
    expected = factors.error(values)
    assert cost(graph) == pytest.approx(expected, rel=1e-12)


def test_cost_equals_gtsam_error_on_pose3example(gtsam_example_file):
    path = gtsam_example_file("pose3example.txt")
    graph = read_g2o(path)
    factors, values = gtsam_graph(path)
    assert cost(graph) == pytest.approx(factors.error(values), rel=1e-12)


@pytest.mark.parametrize("name", ["tinyGrid3D", "parking-garage"])
def test_residuals_equal_gtsam_unwhitened_errors_at_random_poses(name, shared_dataset):
    path = shared_dataset(name)
    graph = read_g2o(path)
    factors, _ = gtsam_graph(path)
    rng = np.random.default_rng(11)
    poses = perturbed_poses(graph.poses, rng, rotation_scale=1.0)  # angles up to ~π and beyond
    values = values_from_poses(graph.ids, poses)
    ours = edge_residuals(poses, graph)
    count = min(factors.size(), 400)
    theirs = np.array([factors.at(k).unwhitenedError(values) for k in range(count)])
    np.testing.assert_allclose(ours[:count], theirs, rtol=0, atol=1e-9)
    assert cost(graph, poses) == pytest.approx(factors.error(values), rel=1e-11)


def make_graph(poses, edge_from, edge_to, measurements, information=None):
    m = len(edge_from)
    if information is None:
        information = np.tile(np.eye(6), (m, 1, 1))
    return PoseGraph(
        ids=np.arange(poses.shape[0]),
        poses=poses,
        edge_from=np.asarray(edge_from),
        edge_to=np.asarray(edge_to),
        measurements=measurements,
        information=information,
    )


def test_residual_is_zero_for_exact_measurements_and_log_of_the_discrepancy():
    rng = np.random.default_rng(2)
    poses = perturbed_poses(np.tile(np.eye(4), (5, 1, 1)), rng)
    edge_from, edge_to = np.array([0, 1, 2, 3, 4]), np.array([1, 2, 3, 4, 0])
    exact = np.linalg.inv(poses[edge_from]) @ poses[edge_to]
    graph = make_graph(poses, edge_from, edge_to, exact)
    np.testing.assert_allclose(edge_residuals(poses, graph), 0, atol=1e-12)
    assert cost(graph) < 1e-24
    # measurement off by Exp(ξ) on the right: Z = (Xi⁻¹Xj)·Exp(−ξ)  ⇒  e = Log(Exp(ξ)) = ξ
    xi = rng.normal(size=(5, 6)) * 0.3
    graph = make_graph(poses, edge_from, edge_to, exact @ se3.exp(-xi))
    np.testing.assert_allclose(edge_residuals(poses, graph), xi, atol=1e-12)


def test_cost_weights_residuals_by_the_information_in_omega_v_order():
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, 3] = [1.0, 0.0, 0.0]  # X_1 translated by 1 along x; Z = identity
    info = np.diag([1.0, 1.0, 1.0, 4.0, 0.0, 0.0])[None]  # rotation block first, then translation
    graph = make_graph(poses, [0], [1], np.eye(4)[None], info)
    np.testing.assert_allclose(edge_residuals(poses, graph), [[0, 0, 0, 1, 0, 0]], atol=1e-15)
    assert cost(graph) == pytest.approx(0.5 * 4.0)
    assert cost(graph, np.tile(np.eye(4), (2, 1, 1))) == 0.0


def test_cost_is_invariant_under_a_common_rigid_motion():
    rng = np.random.default_rng(4)
    poses = perturbed_poses(np.tile(np.eye(4), (6, 1, 1)), rng)
    edge_from, edge_to = np.array([0, 1, 2, 3, 4, 0]), np.array([1, 2, 3, 4, 5, 3])
    measurements = perturbed_poses(np.tile(np.eye(4), (6, 1, 1)), rng, 0.5, 0.5)
    a = rng.normal(size=(6, 6))
    graph = make_graph(poses, edge_from, edge_to, measurements, np.tile(a @ a.T, (6, 1, 1)))
    motion = perturbed_poses(np.eye(4)[None], rng)[0]
    assert cost(graph, motion @ poses) == pytest.approx(cost(graph), rel=1e-10)
