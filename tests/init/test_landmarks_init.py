"""Initial landmark positions given the poses (posegraph.init.landmarks), on datasets.synthetic.landmark_graph."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.init.landmarks import initialize_landmarks
from posegraph.lie.group import SE2, SE3
from posegraph.model.landmarks import Observations

KINDS_2D = [("position",), ("bearing",), ("bearing_range",), ("prior",), ("position", "bearing", "bearing_range", "prior"), ("bearing", "prior")]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kinds", KINDS_2D, ids="+".join)
def test_noise_free_2d_recovers_the_points(kinds, seed):
    graph, truth, points = landmark_graph(SE2, 12, 10, kinds, noise=0.0, seed=seed, offsets=True)
    estimate, undetermined = initialize_landmarks(graph, truth)
    assert not undetermined.any()
    np.testing.assert_allclose(estimate, points, atol=1e-9, rtol=0)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("kinds", [("position",), ("prior",), ("position", "prior")], ids="+".join)
def test_noise_free_3d_with_offsets_recovers_the_points(kinds, seed):
    graph, truth, points = landmark_graph(SE3, 12, 10, kinds, noise=0.0, seed=seed, offsets=True)
    assert "prior" in kinds or graph.landmarks.observations[0].offsets is not None
    estimate, undetermined = initialize_landmarks(graph, truth)
    assert not undetermined.any()
    np.testing.assert_allclose(estimate, points, atol=1e-9, rtol=0)


def test_noisy_positions_are_the_weighted_average():
    """Two position measurements with different Ω: the information-weighted mean of their world points."""
    graph, truth, _ = landmark_graph(SE2, 4, 1, ("position",), noise=0.1, seed=3, per_landmark=2)
    family = graph.landmarks.observations[0]
    information = np.array([[[4.0, 1.0], [1.0, 2.0]], [[1.0, -0.5], [-0.5, 3.0]]])
    graph = replace(graph, landmarks=replace(graph.landmarks, observations=(replace(family, information=information),)))
    R, t = truth[family.pose, :2, :2], truth[family.pose, :2, 2]
    world = t + np.einsum("qij,qj->qi", R, family.measurements)
    W = R @ information @ np.swapaxes(R, 1, 2)
    expected = np.linalg.solve(W.sum(0), np.einsum("qij,qj->i", W, world))
    estimate, undetermined = initialize_landmarks(graph, truth)
    np.testing.assert_allclose(estimate[0], expected, atol=1e-12)
    assert not undetermined[0]


def _with_bearings(graph, pose, landmark, z):
    family = Observations("bearing", np.asarray(pose, np.int64), np.asarray(landmark, np.int64), np.asarray(z, float)[:, None], np.ones((len(pose), 1, 1)))
    return replace(graph, landmarks=replace(graph.landmarks, observations=(family,)))


def test_single_bearing_parallel_rays_and_unseen_landmarks_are_flagged():
    graph, truth, points = landmark_graph(SE2, 6, 4, ("bearing",), noise=0.0, seed=4)
    # landmark 0: one bearing; 1: two rays along the same line (poses 0 and 1 both looking along +x of a
    # common frame); 2: two good rays; 3: no measurement.
    truth = truth.copy()
    truth[1] = truth[0].copy()
    truth[1][:2, 2] += truth[0][:2, 0] * 2.0  # pose 1 two metres ahead of pose 0, same heading
    def bearing(i, p):
        local = np.linalg.solve(truth[i], np.append(p, 1.0))[:2]
        return np.arctan2(local[1], local[0])
    along = truth[0][:2, 2] + 5.0 * truth[0][:2, 0]
    pose, landmark = [2, 0, 1, 3, 4], [0, 1, 1, 2, 2]
    target = {0: points[0], 1: along, 2: points[2]}
    z = [bearing(i, target[l]) for i, l in zip(pose, landmark)]
    graph = _with_bearings(graph, pose, landmark, z)
    estimate, undetermined = initialize_landmarks(graph, truth)
    assert undetermined.tolist() == [True, True, False, True]
    assert np.all(np.isfinite(estimate))
    np.testing.assert_allclose(estimate[2], points[2], atol=1e-9)
    ray = truth[2][:2, 2] + truth[2][:2, :2] @ [np.cos(z[0]), np.sin(z[0])]  # unit range along the single ray
    np.testing.assert_allclose(estimate[0], ray, atol=1e-12)
    np.testing.assert_array_equal(estimate[3], graph.landmarks.positions[3])  # unseen: its given position


def test_fixed_landmarks_keep_their_positions():
    graph, truth, points = landmark_graph(SE2, 8, 5, ("position", "bearing"), noise=0.0, seed=5)
    fixed = np.array([True, False, True, False, False])
    graph = replace(graph, landmarks=replace(graph.landmarks, fixed=fixed))
    estimate, undetermined = initialize_landmarks(graph, truth)
    np.testing.assert_array_equal(estimate[fixed], graph.landmarks.positions[fixed])
    np.testing.assert_allclose(estimate[~fixed], points[~fixed], atol=1e-9)
    assert not undetermined.any()


def test_graph_without_landmarks():
    graph, truth, _ = landmark_graph(SE3, 3, 1, (), noise=0.0, seed=0)
    points, undetermined = initialize_landmarks(replace(graph, landmarks=None), truth)
    assert points.shape == (0, 3) and undetermined.shape == (0,)
