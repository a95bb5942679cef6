"""ATE / RPE: alignment optimality, invariances, and cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from posegraph.errors import InputError
from posegraph.evaluate import (
    absolute_trajectory_error,
    align_rigid,
    chain_odometry,
    error_stats,
    evaluate,
    relative_pose_error,
    rotation_angle,
)


def random_poses(rng, n, spread=5.0):
    poses = np.zeros((n, 4, 4))
    poses[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    poses[:, :3, 3] = rng.normal(scale=spread, size=(n, 3))
    poses[:, 3, 3] = 1.0
    return poses


def random_transform(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.normal(scale=10.0, size=3)
    return T


def test_error_stats_match_hand_computed_values():
    stats = error_stats(np.array([3.0, 4.0, 0.0, 1.0]))
    assert stats.rmse == pytest.approx(np.sqrt((9 + 16 + 0 + 1) / 4))
    assert stats.mean == pytest.approx(2.0)
    assert stats.median == pytest.approx(2.0)
    assert stats.std == pytest.approx(np.sqrt(((1 + 4 + 4 + 1) / 4)))
    assert (stats.min, stats.max, stats.sse, stats.count) == (0.0, 4.0, 26.0, 4)


@pytest.mark.parametrize("theta", [0.0, 1e-12, 1e-7, 0.3, 2.0, np.pi - 1e-7, np.pi - 1e-12, np.pi])
def test_rotation_angle_is_accurate_near_zero_and_pi(theta):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = Rotation.from_rotvec(theta * axis).as_matrix()
    assert rotation_angle(R) == pytest.approx(theta, rel=1e-12, abs=1e-15)


def test_rotation_angle_batches():
    rng = np.random.default_rng(0)
    rotvecs = Rotation.random(12, random_state=rng).as_rotvec().reshape(3, 4, 3)
    R = Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_matrix().reshape(3, 4, 3, 3)
    np.testing.assert_allclose(rotation_angle(R), np.linalg.norm(rotvecs, axis=-1), rtol=1e-12)


def test_align_recovers_a_known_rigid_transform():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(50, 3))
    T = random_transform(rng)
    moved = points @ T[:3, :3].T + T[:3, 3]
    R, t = align_rigid(points, moved)
    np.testing.assert_allclose(R, T[:3, :3], atol=1e-12)
    np.testing.assert_allclose(t, T[:3, 3], atol=1e-11)


def test_align_returns_a_rotation_for_mirrored_points():
    # Points mirrored through a plane: the best orthogonal map is a reflection; the answer must not be.
    rng = np.random.default_rng(2)
    points = rng.normal(size=(30, 3)) * [5.0, 3.0, 1.0]
    mirrored = points * [1.0, 1.0, -1.0]
    R, _ = align_rigid(points, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_alignment_is_the_least_squares_optimum():
    """Umeyama's closed form against a generic least-squares solve of the same problem."""
    rng = np.random.default_rng(3)
    points = rng.normal(scale=4.0, size=(40, 3))
    T = random_transform(rng)
    target = points @ T[:3, :3].T + T[:3, 3] + rng.normal(scale=0.3, size=points.shape)
    R, t = align_rigid(points, target)
    closed_form = np.sum((points @ R.T + t - target) ** 2)

    def residual(x):
        return (points @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:] - target).ravel()

    x0 = np.r_[Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]]
    numeric = least_squares(residual, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert closed_form <= np.sum(numeric.fun**2) * (1 + 1e-10)
    assert closed_form == pytest.approx(np.sum(numeric.fun**2), rel=1e-9)


def test_ground_truth_moved_rigidly_has_zero_errors():
    rng = np.random.default_rng(4)
    gt = random_poses(rng, 30)
    T = random_transform(rng)
    ids = np.arange(100, 130)
    result = evaluate(ids, T @ gt, ids, gt)
    assert result.ate_translation.max < 1e-9
    assert result.ate_rotation.max < 1e-6
    assert result.rpe_translation.max < 1e-9
    assert result.rpe_rotation.max < 1e-6
    np.testing.assert_allclose(result.alignment @ T, np.eye(4), atol=1e-10)


def test_without_alignment_ate_is_the_offset():
    rng = np.random.default_rng(5)
    gt = random_poses(rng, 10)
    shifted = gt.copy()
    shifted[:, :3, 3] += [3.0, 4.0, 0.0]
    ids = np.arange(10)
    result = evaluate(ids, shifted, ids, gt, align=False)
    np.testing.assert_allclose(result.ate_translation.rmse, 5.0, rtol=1e-12)
    assert result.rpe_translation.max < 1e-12  # RPE ignores a global offset
    assert evaluate(ids, shifted, ids, gt).ate_translation.max < 1e-12


def test_rpe_of_one_displaced_pose():
    """Moving pose k by d (world frame) changes exactly the steps k-1→k and k→k+1, each by |d|."""
    rng = np.random.default_rng(6)
    gt = random_poses(rng, 12)
    est = gt.copy()
    d = np.array([0.3, -0.1, 0.2])
    est[5, :3, 3] += d
    t_err, r_err = relative_pose_error(est, gt)
    expected = np.zeros(11)
    expected[[4, 5]] = np.linalg.norm(d)
    np.testing.assert_allclose(t_err, expected, atol=1e-12)
    np.testing.assert_allclose(r_err, 0.0, atol=1e-6)


def test_ate_rotation_of_one_turned_pose():
    rng = np.random.default_rng(7)
    gt = random_poses(rng, 8)
    est = gt.copy()
    est[3, :3, :3] = est[3, :3, :3] @ Rotation.from_rotvec([0.0, 0.0, np.radians(10.0)]).as_matrix()
    t_err, r_err, alignment = absolute_trajectory_error(est, gt)
    np.testing.assert_allclose(alignment, np.eye(4), atol=1e-12)  # positions unchanged
    np.testing.assert_allclose(t_err, 0.0, atol=1e-12)
    expected = np.zeros(8)
    expected[3] = 10.0
    np.testing.assert_allclose(r_err, expected, atol=1e-9)


def test_matching_by_id_ignores_order_and_extra_vertices():
    rng = np.random.default_rng(8)
    gt = random_poses(rng, 20)
    est = gt @ random_transform(rng)  # per-pose body offset: non-zero errors
    ids = np.arange(20) * 3
    reference = evaluate(ids, est, ids, gt)
    perm = rng.permutation(20)
    extra = random_poses(rng, 4)
    shuffled = evaluate(
        np.r_[ids[perm], [1000, 1001, 1002, 1003]], np.concatenate([est[perm], extra]), ids, gt
    )
    assert shuffled.num_matched == 20 and shuffled.num_estimate == 24
    assert shuffled.ate_translation.rmse == pytest.approx(reference.ate_translation.rmse, rel=1e-12)
    assert shuffled.rpe_rotation.rmse == pytest.approx(reference.rpe_rotation.rmse, rel=1e-12)


def test_too_few_common_ids_is_an_input_error():
    rng = np.random.default_rng(9)
    poses = random_poses(rng, 4)
    with pytest.raises(InputError, match="2 vertex id"):
        evaluate(np.arange(4), poses, np.arange(2, 6), poses, source="est.g2o")


def test_chain_odometry_rebuilds_a_trajectory_from_its_steps():
    rng = np.random.default_rng(10)
    poses = random_poses(rng, 6)
    poses = np.linalg.inv(poses[0]) @ poses  # start at the identity, as the chain does
    inverse = np.linalg.inv
    ids_from = np.array([0, 2, 1, 3, 5, 0])  # edge 5→4 is written backwards; 0→3 is a loop closure
    ids_to = np.array([1, 3, 2, 4, 4, 3])
    Z = np.array([inverse(poses[i]) @ poses[j] for i, j in zip(ids_from, ids_to)])
    ids, chained = chain_odometry(ids_from, ids_to, Z)
    np.testing.assert_array_equal(ids, np.arange(6))
    np.testing.assert_allclose(chained, poses, atol=1e-12)
    with pytest.raises(InputError, match="from vertex 2 to 3"):
        chain_odometry(np.array([0, 1, 3]), np.array([1, 2, 4]), Z[:3])
