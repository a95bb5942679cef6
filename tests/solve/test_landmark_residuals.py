"""Landmark residuals and Jacobians (posegraph.solve.landmark_residuals): finite differences and gtsam."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.lie.group import SE2, SE3
from posegraph.model.landmarks import Observations, measurement_size
from posegraph.solve.landmark_residuals import landmark_jacobians, landmark_residuals, wrap_angle

CASES = [(SE2, "position"), (SE3, "position"), (SE2, "bearing"), (SE2, "bearing_range"), (SE2, "prior"), (SE3, "prior")]
IDS = [f"{g.name}-{k}" for g, k in CASES]


def random_family(group, kind: str, seed: int, offsets: bool, n: int = 5, L: int = 7, q: int = 40):
    """Random poses ``(n, k, k)``, points ``(L, s)`` and a family of ``q`` measurements of ``kind``."""
    rng = np.random.default_rng(seed)
    s, r = group.space_dim, measurement_size(kind, group.space_dim)
    poses = group.exp(rng.normal(scale=2.0, size=(n, group.dim)))
    points = rng.normal(scale=5.0, size=(L, s))
    pose = np.full(q, -1) if kind == "prior" else rng.integers(0, n, q)
    z = rng.normal(size=(q, r))
    if kind in ("bearing", "bearing_range"):
        z[:, 0] = rng.uniform(-np.pi, np.pi, q)
    if kind == "bearing_range":
        z[:, 1] = rng.uniform(1.0, 8.0, q)
    A = rng.normal(size=(q, r, r))
    information = A @ np.swapaxes(A, 1, 2) + np.eye(r)
    O = group.exp(rng.normal(size=(q, group.dim))) if offsets and kind == "position" else None
    family = Observations(kind, pose.astype(np.int64), rng.integers(0, L, q).astype(np.int64), z, information, O)
    return poses, points, family


def _difference(kind, plus, minus):
    d = plus - minus
    if kind in ("bearing", "bearing_range"):
        d[:, 0] = wrap_angle(d[:, 0])
    return d


@pytest.mark.parametrize("offsets", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("group,kind", CASES, ids=IDS)
def test_jacobians_match_central_differences(group, kind, seed, offsets):
    poses, points, family = random_family(group, kind, seed, offsets)
    e, J_pose, J_point = landmark_jacobians(group, poses, points, family)
    np.testing.assert_array_equal(e, landmark_residuals(group, poses, points, family))
    h = 1e-6
    if kind == "prior":
        assert J_pose is None
    else:
        assert J_pose.shape == (family.count, e.shape[1], group.dim)
        for j in range(group.dim):  # every pose perturbed by Exp(±h e_j): each row sees its own pose only
            step = group.exp(h * np.eye(group.dim)[j])
            plus = landmark_residuals(group, poses @ step, points, family)
            minus = landmark_residuals(group, poses @ np.linalg.inv(step), points, family)
            np.testing.assert_allclose(J_pose[:, :, j], _difference(kind, plus, minus) / (2 * h), atol=1e-6, rtol=1e-6)
    assert J_point.shape == (family.count, e.shape[1], group.space_dim)
    for j in range(group.space_dim):
        dp = h * np.eye(group.space_dim)[j]
        plus = landmark_residuals(group, poses, points + dp, family)
        minus = landmark_residuals(group, poses, points - dp, family)
        np.testing.assert_allclose(J_point[:, :, j], _difference(kind, plus, minus) / (2 * h), atol=1e-6, rtol=1e-6)


@pytest.mark.parametrize("group,kind", [(SE2, "bearing"), (SE2, "bearing_range")])
def test_angles_are_wrapped(group, kind):
    poses, points, family = random_family(group, kind, 3, False, q=200)
    e = landmark_residuals(group, poses, points, family)
    assert np.all(e[:, 0] >= -np.pi) and np.all(e[:, 0] < np.pi)
    assert np.all(wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi])) == -np.pi)


def test_three_dimensional_bearings_are_refused():
    poses, points, family = random_family(SE3, "position", 0, False)
    with pytest.raises(ValueError):
        landmark_residuals(SE3, poses, points, Observations("bearing", family.pose, family.landmark, family.measurements[:, :1], family.information[:, :1, :1]))


# gtsam
# -----

gtsam = pytest.importorskip("gtsam")


def _pose(group, matrix):
    if group is SE2:
        from posegraph.lie import se2

        return gtsam.Pose2(*se2.to_xytheta(matrix).tolist())
    return gtsam.Pose3(matrix)


def _offset(family, k, group):
    return np.eye(group.matrix_size) if family.offsets is None else family.offsets[k]


@pytest.mark.parametrize("offsets", [False, True])
@pytest.mark.parametrize("group", [SE2, SE3], ids=["SE2", "SE3"])
def test_position_matches_gtsam_transform_to(group, offsets):
    poses, points, family = random_family(group, "position", 4, offsets, q=15)
    e, J_pose, J_point = landmark_jacobians(group, poses, points, family)
    d, s = group.dim, group.space_dim
    for k in range(family.count):
        X, O = _pose(group, poses[family.pose[k]]), _pose(group, _offset(family, k, group))
        H_compose = np.zeros((d, d), order="F")
        sensor = X.compose(O, H_compose) if group is SE3 else X.compose(O)
        if group is SE2:  # Pose2.compose's H1 is not bound: Ad(O⁻¹), the same for any group
            H_compose = O.inverse().AdjointMap()
        H_pose, H_point = np.zeros((s, d), order="F"), np.zeros((s, s), order="F")
        y = sensor.transformTo(points[family.landmark[k]], H_pose, H_point)
        np.testing.assert_allclose(e[k], y - family.measurements[k], atol=1e-12)
        np.testing.assert_allclose(J_pose[k], H_pose @ H_compose, atol=1e-12)
        np.testing.assert_allclose(J_point[k], H_point, atol=1e-12)


def _pose_point_values(group, poses, points, family, k):
    values = gtsam.Values()
    values.insert(0, _pose(group, poses[family.pose[k]]))
    values.insert(1, points[family.landmark[k]])
    return values


def _factor_args(kind, z):
    return (gtsam.Rot2(z[0]),) if kind == "bearing" else (gtsam.Rot2(z[0]), z[1])


@pytest.mark.parametrize("kind", ["bearing", "bearing_range"])
def test_bearings_match_gtsam_factors(kind):
    """Same sign and order: gtsam's error is measured.localCoordinates(predicted) = [wrap(θ − z_θ), r − z_r]."""
    poses, points, family = random_family(SE2, kind, 5, False, q=30)
    e, J_pose, J_point = landmark_jacobians(SE2, poses, points, family)
    r = e.shape[1]
    unit = gtsam.noiseModel.Unit.Create(r)
    total_ours, total_gtsam = 0.0, 0.0
    for k in range(family.count):
        z = family.measurements[k]
        if kind == "bearing":
            factor = gtsam.BearingFactor2D(0, 1, gtsam.Rot2(z[0]), unit)
        else:
            factor = gtsam.BearingRangeFactor2D(0, 1, gtsam.Rot2(z[0]), z[1], unit)
        values = _pose_point_values(SE2, poses, points, family, k)
        error = factor.unwhitenedError(values)
        np.testing.assert_allclose(e[k], error, atol=1e-12)
        A, b = factor.linearize(values).jacobian()  # unit noise: A = [∂e/∂pose, ∂e/∂point], b = −e
        np.testing.assert_allclose(A, np.concatenate([J_pose[k], J_point[k]], axis=1), atol=1e-10)
        noise = gtsam.noiseModel.Gaussian.Information(family.information[k])
        weighted = type(factor)(0, 1, *_factor_args(kind, z), noise)
        total_gtsam += weighted.error(values)
        total_ours += 0.5 * e[k] @ family.information[k] @ e[k]
    assert total_ours == pytest.approx(total_gtsam, rel=1e-12)


@pytest.mark.parametrize("group", [SE2, SE3], ids=["SE2", "SE3"])
def test_prior_matches_gtsam(group):
    poses, points, family = random_family(group, "prior", 6, False, q=10)
    e = landmark_residuals(group, poses, points, family)
    cls = gtsam.PriorFactorPoint2 if group is SE2 else gtsam.PriorFactorPoint3
    for k in range(family.count):
        factor = cls(1, family.measurements[k], gtsam.noiseModel.Gaussian.Information(family.information[k]))
        values = gtsam.Values()
        values.insert(1, points[family.landmark[k]])
        np.testing.assert_allclose(e[k], factor.unwhitenedError(values), atol=1e-12)
        assert 0.5 * e[k] @ family.information[k] @ e[k] == pytest.approx(factor.error(values), rel=1e-12)
