"""The geometry and colours the Rerun recordings draw (plain numpy: no Rerun needed)."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.analysis import rerun_scene as scene
from posegraph.lie import se2, se3, so3


def test_positions_embed_2d_poses_at_z_zero():
    planar = se2.from_xytheta(np.array([[1.0, 2.0, 0.3], [-4.0, 5.0, -1.0]]))
    np.testing.assert_array_equal(scene.positions(planar), [[1, 2, 0], [-4, 5, 0]])
    spatial = se3.exp(np.random.default_rng(0).standard_normal((3, 6)))
    np.testing.assert_allclose(scene.positions(spatial), spatial[:, :3, 3], rtol=1e-6)


def test_weight_colours_mark_outliers_below_one_half_and_fade_inliers():
    colours = scene.weight_colours(np.array([1.0, 0.75, 0.5, 0.49, 0.0]))
    assert tuple(colours[0]) == scene.INLIER_COLOUR
    assert tuple(colours[2]) == scene.INITIAL_COLOUR  # weight 0.5: faded all the way, still an inlier
    assert tuple(colours[3]) == tuple(colours[4]) == scene.OUTLIER_COLOUR
    assert colours[1, 1] == round((scene.INLIER_COLOUR[1] + scene.INITIAL_COLOUR[1]) / 2)


def test_chi2_colours_run_from_dark_to_yellow_on_chi2_per_dof():
    colours = scene.chi2_colours(np.array([0.0, 6.0, 600.0, 1e9]), dimension=6)
    assert tuple(colours[0, :3]) == (68, 1, 84) and tuple(colours[2, :3]) == tuple(colours[3, :3]) == (253, 231, 37)
    assert tuple(colours[1, :3]) == (50, 103, 139)  # χ²/d = 1: a third of the way from the 2nd to the 3rd stop


def test_ellipsoids_are_the_world_position_covariance():
    rng = np.random.default_rng(1)
    poses = se3.exp(rng.standard_normal((4, 6)))
    a = rng.standard_normal((4, 6, 6))
    covariances = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(6)
    centres, half_sizes, quaternions = scene.covariance_ellipsoids(poses, covariances, sigma=2.0)
    axes = so3.from_quaternion(quaternions.astype(np.float64))
    rebuilt = axes @ (np.asarray(half_sizes, np.float64)[..., None] ** 2 / 4 * np.eye(3)) @ np.swapaxes(axes, -1, -2)
    world = poses[:, :3, :3] @ covariances[:, 3:, 3:] @ np.swapaxes(poses[:, :3, :3], -1, -2)
    np.testing.assert_allclose(rebuilt, world, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(centres, poses[:, :3, 3], rtol=1e-6)


def test_ellipse_outlines_lie_at_sigma_mahalanobis_distance_in_the_plane():
    rng = np.random.default_rng(2)
    poses = se2.from_xytheta(rng.standard_normal((3, 3)))
    a = rng.standard_normal((3, 3, 3))
    covariances = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(3)
    outlines = scene.ellipse_outlines(poses, covariances, sigma=3.0).astype(np.float64)
    assert np.all(outlines[..., 2] == 0)
    rotation = poses[:, :2, :2]
    world = rotation @ covariances[:, :2, :2] @ np.swapaxes(rotation, -1, -2)
    offset = outlines[..., :2] - poses[:, None, :2, 2]
    distance = np.einsum("npi,nij,npj->np", offset, np.linalg.inv(world), offset)
    np.testing.assert_allclose(distance, 9.0, rtol=1e-4)


def test_selected_poses_are_spread_and_keep_the_last():
    assert scene.selected_poses(5, 200).tolist() == [0, 1, 2, 3, 4]
    chosen = scene.selected_poses(10_000, 200)
    assert len(chosen) == 200 and chosen[0] == 0 and chosen[-1] == 9999


@pytest.mark.parametrize("frames", [1, 10, 1000, 100_000])
def test_frame_budget_never_exceeds_its_bytes_and_takes_the_first_frames(frames):
    budget = scene.FrameBudget(budget=100 * 150, frame_bytes=150)  # room for 100 frames
    taken = [k for k in range(frames) if budget.take()]
    assert len(taken) <= 100
    assert taken[: min(frames, 50)] == list(range(min(frames, 50)))  # the first half: every frame
    if frames == 1000:
        assert len(taken) > 90 and taken[-1] > frames // 2  # spread on, not stopped at the start


def test_frame_budget_of_a_frame_larger_than_the_budget_takes_nothing():
    budget = scene.FrameBudget(budget=100, frame_bytes=1000)
    assert not any(budget.take() for _ in range(10))
