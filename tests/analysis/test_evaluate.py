"""ATE / RPE: alignment optimality, invariances, and cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from posegraph.errors import InputError
from posegraph.lie import se2, so2
from posegraph.analysis.evaluate import (
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


# --- 2D trajectories (SE(2), (n, 3, 3)) ------------------------------------------------------


def random_planar_poses(rng, n, spread=5.0):
    return se2.from_xytheta(np.c_[rng.normal(scale=spread, size=(n, 2)), rng.uniform(-np.pi, np.pi, n)])


def noisy(rng, poses, scale=0.05):
    """Each pose moved by a random right perturbation (translation and angle ~ N(0, scale²))."""
    return se2.compose(poses, se2.exp(rng.normal(scale=scale, size=(len(poses), 3))))


@pytest.mark.parametrize("theta", [0.0, 1e-12, 0.3, -2.0, np.pi - 1e-12, np.pi, -np.pi])
def test_rotation_angle_of_2d_rotations(theta):
    assert rotation_angle(so2.from_angle(theta)) == pytest.approx(abs(theta), rel=1e-15, abs=1e-16)


def test_planar_alignment_recovers_a_known_transform_and_is_optimal():
    rng = np.random.default_rng(11)
    points = rng.normal(scale=4.0, size=(40, 2))
    T = se2.from_xytheta([3.0, -7.0, 2.5])
    R, t = align_rigid(points, se2.act(T, points))
    assert R.shape == (2, 2) and t.shape == (2,)
    np.testing.assert_allclose(R, T[:2, :2], atol=1e-14)
    np.testing.assert_allclose(t, T[:2, 2], atol=1e-13)
    # with noise: no (θ, t) does better (generic least squares from the true transform)
    target = se2.act(T, points) + rng.normal(scale=0.3, size=points.shape)
    R, t = align_rigid(points, target)
    closed_form = np.sum((points @ R.T + t - target) ** 2)

    def residual(x):
        return (se2.act(se2.from_xytheta(x), points) - target).ravel()

    numeric = least_squares(residual, se2.to_xytheta(T), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert closed_form <= np.sum(numeric.fun**2) * (1 + 1e-12)
    np.testing.assert_allclose(R, so2.from_angle(numeric.x[2]), atol=1e-8)


def test_planar_alignment_matches_gtsams_pose2_align():
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(12)
    points = rng.normal(scale=4.0, size=(25, 2))
    target = se2.act(se2.from_xytheta([1.0, 2.0, -1.0]), points) + rng.normal(scale=0.5, size=points.shape)
    R, t = align_rigid(points, target)
    reference = gtsam.Pose2.Align(target.T, points.T)  # a = Align(a, b) · b
    np.testing.assert_allclose(R, reference.rotation().matrix(), atol=1e-13)
    np.testing.assert_allclose(t, reference.translation(), atol=1e-12)


def test_2d_trajectory_and_its_z0_embedding_give_the_same_figures():
    rng = np.random.default_rng(13)
    gt = random_planar_poses(rng, 40)
    est = se2.compose(se2.from_xytheta([4.0, -1.0, 0.7]), noisy(rng, gt))  # moved and noisy
    ids = np.arange(40)
    flat = evaluate(ids, est, ids, gt)
    embedded = evaluate(ids, se2.to_se3(est), ids, se2.to_se3(gt))
    mixed = evaluate(ids, est, ids, se2.to_se3(gt))  # a 2D estimate against a 3D reference
    assert flat.alignment.shape == (3, 3) and embedded.alignment.shape == (4, 4)
    assert flat.ate_translation.rmse > 0.01 and flat.rpe_rotation.rmse > 0.5  # the noise shows
    for other in (embedded, mixed):
        for field in ("ate_translation", "ate_rotation", "rpe_translation", "rpe_rotation"):
            a, b = getattr(flat, field), getattr(other, field)
            np.testing.assert_allclose([a.rmse, a.max, a.median], [b.rmse, b.max, b.median], rtol=1e-9, err_msg=field)
        np.testing.assert_allclose(other.alignment, se2.to_se3(flat.alignment), atol=1e-12)


def test_2d_ground_truth_moved_rigidly_has_zero_errors_and_the_move_is_recovered():
    rng = np.random.default_rng(14)
    gt = random_planar_poses(rng, 25)
    T = se2.from_xytheta([-3.0, 8.0, -2.9])
    ids = np.arange(25) + 5
    result = evaluate(ids, se2.compose(T, gt), ids, gt)
    assert max(result.ate_translation.max, result.rpe_translation.max) < 1e-12
    assert max(result.ate_rotation.max, result.rpe_rotation.max) < 1e-10
    np.testing.assert_allclose(result.alignment, se2.inverse(T), atol=1e-12)


def test_2d_rpe_and_ate_of_one_turned_pose():
    rng = np.random.default_rng(15)
    gt = random_planar_poses(rng, 8)
    est = gt.copy()
    est[3, :2, :2] = est[3, :2, :2] @ so2.from_angle(np.radians(-10.0))
    t_err, r_err, alignment = absolute_trajectory_error(est, gt)
    np.testing.assert_allclose(alignment, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(t_err, 0.0, atol=1e-12)
    np.testing.assert_allclose(r_err, np.where(np.arange(8) == 3, 10.0, 0.0), atol=1e-9)
    _, r_rel = relative_pose_error(est, gt)
    np.testing.assert_allclose(r_rel, np.where(np.isin(np.arange(7), [2, 3]), 10.0, 0.0), atol=1e-9)


def test_chain_odometry_of_2d_steps():
    rng = np.random.default_rng(16)
    poses = random_planar_poses(rng, 6)
    poses = se2.between(poses[0], poses)  # start at the identity
    ids_from, ids_to = np.array([0, 2, 1, 3, 5]), np.array([1, 3, 2, 4, 4])  # 5→4 written backwards
    ids, chained = chain_odometry(ids_from, ids_to, se2.between(poses[ids_from], poses[ids_to]))
    np.testing.assert_array_equal(ids, np.arange(6))
    np.testing.assert_allclose(chained, poses, atol=1e-12)


def test_sim3_trajectories_align_by_a_similarity_with_each_poses_scale_applied():
    from posegraph.analysis.evaluate import align_rigid, evaluate, is_similarity_trajectory
    from posegraph.lie import se3, sim3

    rng = np.random.default_rng(11)
    truth = se3.exp(np.concatenate([rng.normal(size=(30, 3)), 5 * rng.normal(size=(30, 3))], axis=1))
    similarity = sim3.exp(np.array([0.3, -0.2, 0.1, 4.0, -1.0, 2.0, np.log(2.5)]))
    # The estimate: the truth seen through a similarity, each pose carrying its own scale besides.
    estimate = (similarity @ truth) @ sim3.exp(np.concatenate([np.zeros((30, 6)), rng.normal(size=(30, 1))], axis=1))
    assert is_similarity_trajectory(estimate) and not is_similarity_trajectory(truth)
    c, R, t = align_rigid(estimate[:, :3, 3], truth[:, :3, 3], with_scale=True)
    assert c == pytest.approx(1 / 2.5, rel=1e-12)
    result = evaluate(np.arange(30), estimate, np.arange(30), truth)
    assert result.ate_translation.max < 1e-9 and result.ate_rotation.max < 1e-6
    assert result.rpe_translation.max < 1e-9
    rigid = evaluate(np.arange(30), estimate, np.arange(30), truth, with_scale=False)
    assert rigid.ate_translation.rmse > 1.0
