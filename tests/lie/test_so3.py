"""SO(3): identities at the edge-case angles, finite differences, quaternions, projection, batching.

Independent references: scipy's ``Rotation`` (rotation vectors, quaternions) and
``scipy.linalg.expm`` of the skew matrix; finite differences for every Jacobian.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from posegraph.lie import so3
from tests.lie.helpers import BATCH_SHAPES, EDGE_ANGLES, central_difference, rotation_vectors, unit_vectors

pytestmark = pytest.mark.filterwarnings("error")  # no RuntimeWarning (0/0, overflow) anywhere

I3 = np.eye(3)


def at_angle(angle, n=32, seed=0):
    return angle * unit_vectors(np.random.default_rng(seed), (n,))


def assert_rotation(R, atol=1e-14):
    assert np.abs(np.swapaxes(R, -1, -2) @ R - I3).max() <= atol
    assert np.abs(np.linalg.det(R) - 1.0).max() <= atol


# --- hat / vee -------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_hat_is_the_cross_product_and_vee_inverts_it(shape):
    rng = np.random.default_rng(1)
    w, p = rng.normal(size=shape + (3,)), rng.normal(size=shape + (3,))
    W = so3.hat(w)
    assert W.shape == shape + (3, 3)
    np.testing.assert_allclose((W @ p[..., None])[..., 0], np.cross(w, p), atol=1e-15)
    np.testing.assert_array_equal(W, -np.swapaxes(W, -1, -2))
    np.testing.assert_array_equal(so3.vee(W), w)


def test_bad_shapes_are_rejected():
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        so3.exp(np.zeros(4))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        so3.log(np.eye(4))
    with pytest.raises(ValueError, match="non-zero"):
        so3.from_quaternion([0.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="finite"):
        so3.from_quaternion([np.nan, 0.0, 0.0, 1.0])


# --- Exp / Log -------------------------------------------------------------------------------


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_matches_expm_and_scipy(angle):
    w = at_angle(angle)
    R = so3.exp(w)
    assert_rotation(R)
    np.testing.assert_allclose(R, expm(so3.hat(w)), atol=2e-15)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=2e-15)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_log_inverts_exp(angle):
    w = at_angle(angle)
    R = so3.exp(w)
    w_back = so3.log(R)
    theta = np.linalg.norm(w_back, axis=-1)
    assert np.all(theta <= np.pi * (1 + 2e-16 * 2))  # the angle is ≤ π; |w| may round up by an ulp
    np.testing.assert_allclose(theta, angle, rtol=0, atol=4e-15)
    np.testing.assert_allclose(so3.exp(w_back), R, atol=2e-15)  # Exp(Log R) = R
    if angle < np.pi:  # Log(Exp w) = w below π (at π both ±w are right)
        np.testing.assert_allclose(w_back, w, rtol=0, atol=2e-15 if angle < 3 else 1e-9)
    else:
        np.testing.assert_allclose(np.abs(np.sum(w_back * w, axis=-1)), angle**2, rtol=1e-15)


def test_log_of_tiny_rotations_keeps_full_relative_precision():
    # The skew part of R carries sin θ exactly, so tiny angles come back to ~1 ulp relative.
    axis = unit_vectors(np.random.default_rng(2), (8,))
    for angle in (1e-300, 1e-200, 1e-12, 3e-9, 1e-5):
        w = angle * axis
        np.testing.assert_allclose(so3.log(so3.exp(w)), w, rtol=1e-14, atol=0)


def test_log_beyond_pi_wraps_into_zero_to_pi():
    axis = unit_vectors(np.random.default_rng(3), (10,))
    for angle in (np.pi + 0.5, 2 * np.pi - 0.1, 5.0):
        w = so3.log(so3.exp(angle * axis))
        np.testing.assert_allclose(w, (angle - 2 * np.pi) * axis, atol=1e-14)


def test_log_tolerates_matrices_slightly_off_so3():
    rng = np.random.default_rng(4)
    w = rotation_vectors(rng, (200,))
    R = so3.exp(w)
    drifted = R + 1e-9 * rng.normal(size=R.shape)  # what long products of rotations look like
    w_drift = so3.log(drifted)
    assert np.all(np.isfinite(w_drift))
    # within the perturbation's size of the log of the nearest rotation
    w_nearest = so3.log(so3.project(drifted))
    near_pi = np.linalg.norm(w, axis=-1) > np.pi - 1e-3  # where ±w flips
    assert np.abs(w_drift - w_nearest)[~near_pi].max() < 1e-8
    np.testing.assert_allclose(so3.exp(w_drift), R, atol=1e-8)


# --- Jacobians -------------------------------------------------------------------------------


def _exp_perturbation(w):
    """δ ↦ Log(Exp(w)⁻¹ Exp(w + δ)): its Jacobian at 0 is Jr(w)."""
    return lambda x: so3.log(np.swapaxes(so3.exp(w), -1, -2)[..., None, :, :] @ so3.exp(x))


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_right_and_left_jacobians_by_finite_differences(angle):
    w = at_angle(angle, n=8)
    R = so3.exp(w)
    Rt = np.swapaxes(R, -1, -2)[:, None]
    # Jr: Exp(w + δ) = Exp(w) Exp(Jr δ);  Jl: Exp(w + δ) = Exp(Jl δ) Exp(w)
    fd_right = central_difference(lambda x: so3.log(Rt @ so3.exp(x)), w)
    fd_left = central_difference(lambda x: so3.log(so3.exp(x) @ Rt), w)
    np.testing.assert_allclose(so3.right_jacobian(w), fd_right, atol=1e-8)
    np.testing.assert_allclose(so3.left_jacobian(w), fd_left, atol=1e-8)


@pytest.mark.parametrize("angle", [a for a in EDGE_ANGLES if a < 3] + [np.pi - 1e-3])
def test_inverse_jacobians_by_finite_differences_of_log(angle):
    # Log(R Exp(δ)) ≈ Log(R) + Jr⁻¹ δ and Log(Exp(δ) R) ≈ Log(R) + Jl⁻¹ δ.  (At θ = π Log jumps,
    # so the differences stop short of it; test_mpmath_reference covers π itself.)
    w = at_angle(angle, n=8)
    R = so3.exp(w)[:, None]
    fd_right = central_difference(lambda d: so3.log(R @ so3.exp(d)), np.zeros_like(w), step=1e-7)
    fd_left = central_difference(lambda d: so3.log(so3.exp(d) @ R), np.zeros_like(w), step=1e-7)
    np.testing.assert_allclose(so3.right_jacobian_inverse(w), fd_right, atol=3e-7)
    np.testing.assert_allclose(so3.left_jacobian_inverse(w), fd_left, atol=3e-7)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_jacobian_identities(angle):
    w = at_angle(angle)
    Jr, Jl = so3.right_jacobian(w), so3.left_jacobian(w)
    Jr_inv, Jl_inv = so3.right_jacobian_inverse(w), so3.left_jacobian_inverse(w)
    np.testing.assert_allclose(Jl, so3.right_jacobian(-w), atol=1e-16)
    np.testing.assert_allclose(Jl, np.swapaxes(Jr, -1, -2), atol=1e-16)
    np.testing.assert_allclose(Jl, so3.exp(w) @ Jr, atol=1e-15)  # Jl = Ad(Exp w) Jr, Ad = R on SO(3)
    np.testing.assert_allclose(Jr @ Jr_inv, np.broadcast_to(I3, Jr.shape), atol=1e-15)
    np.testing.assert_allclose(Jl_inv @ Jl, np.broadcast_to(I3, Jr.shape), atol=1e-15)
    np.testing.assert_allclose(Jl_inv, np.swapaxes(Jr_inv, -1, -2), atol=1e-16)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_of_a_perturbed_tangent_is_a_right_perturbation(angle):
    # Exp(w + δ) ≈ Exp(w) Exp(Jr(w) δ) to second order in δ
    rng = np.random.default_rng(5)
    w = at_angle(angle)
    for size in (1e-4, 1e-5):
        delta = size * unit_vectors(rng, w.shape[:-1])
        lhs = so3.exp(w + delta)
        rhs = so3.exp(w) @ so3.exp((so3.right_jacobian(w) @ delta[..., None])[..., 0])
        assert np.abs(lhs - rhs).max() < 2 * size**2 + 1e-15


# --- quaternions -----------------------------------------------------------------------------


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_quaternions_agree_with_scipy_and_round_trip(angle):
    w = at_angle(angle)
    R = so3.exp(w)
    q = so3.to_quaternion(R)
    assert np.all(q[..., 3] >= 0.0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    ref = Rotation.from_rotvec(w).as_quat()  # scipy's order is also x, y, z, w
    ref = np.where(ref[..., 3:] < 0, -ref, ref)
    if angle < np.pi:
        np.testing.assert_allclose(q, ref, atol=2e-15)
    else:  # qw = 0: q and −q are both canonical
        np.testing.assert_allclose(np.abs(np.sum(q * ref, axis=-1)), 1.0, atol=1e-15)
    np.testing.assert_allclose(so3.from_quaternion(q), R, atol=2e-15)


def test_from_quaternion_normalises_and_ignores_the_sign():
    rng = np.random.default_rng(6)
    q = rng.normal(size=(50, 4))
    R = so3.from_quaternion(q)
    assert_rotation(R)
    np.testing.assert_allclose(R, so3.from_quaternion(-3.5 * q), atol=1e-15)
    np.testing.assert_allclose(R, Rotation.from_quat(q).as_matrix(), atol=1e-15)
    np.testing.assert_array_equal(so3.from_quaternion([0.0, 0.0, 0.0, 2.0]), I3)


# --- projection ------------------------------------------------------------------------------


def test_project_returns_the_nearest_rotation():
    rng = np.random.default_rng(7)
    R = so3.exp(rotation_vectors(rng, (100,)))
    np.testing.assert_allclose(so3.project(R), R, atol=1e-14)  # rotations are fixed points
    # R S with S symmetric positive definite projects back to R (polar decomposition)
    A = rng.normal(size=(100, 3, 3))
    S = A @ np.swapaxes(A, -1, -2) + 0.1 * I3
    np.testing.assert_allclose(so3.project(R @ S), R, atol=1e-10)
    noisy = R + 0.05 * rng.normal(size=R.shape)
    P = so3.project(noisy)
    assert_rotation(P)
    # nearer than the noise-free rotation (it is the nearest of all)
    assert np.all(np.linalg.norm(P - noisy, axis=(-2, -1)) <= np.linalg.norm(R - noisy, axis=(-2, -1)) + 1e-12)


def test_project_fixes_a_reflection_to_a_proper_rotation():
    # M = R0 diag(3, 2, −1) has det < 0; the nearest rotation flips the smallest singular direction
    R0 = so3.exp(np.array([0.3, -0.2, 0.5]))
    M = R0 @ np.diag([3.0, 2.0, -1.0])
    P = so3.project(M)
    assert_rotation(P)
    np.testing.assert_allclose(P, R0, atol=1e-15)
    batch = so3.project(np.stack([M, 2.0 * R0]))
    np.testing.assert_allclose(batch, np.stack([R0, R0]), atol=1e-15)


# --- batching --------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_every_function_takes_any_batch_shape(shape):
    rng = np.random.default_rng(8)
    w = rotation_vectors(rng, shape)
    flat = w.reshape(-1, 3)
    for f in (so3.exp, so3.right_jacobian, so3.left_jacobian, so3.right_jacobian_inverse, so3.left_jacobian_inverse, so3.hat):
        out = f(w)
        assert out.shape == shape + (3, 3)
        np.testing.assert_array_equal(out.reshape(-1, 3, 3), f(flat))
    R = so3.exp(w)
    assert so3.log(R).shape == shape + (3,)
    np.testing.assert_array_equal(so3.log(R).reshape(-1, 3), so3.log(R.reshape(-1, 3, 3)))
    assert so3.to_quaternion(R).shape == shape + (4,)
    assert so3.from_quaternion(so3.to_quaternion(R)).shape == shape + (3, 3)
    assert so3.project(R).shape == shape + (3, 3)
    assert so3.vee(so3.hat(w)).shape == shape + (3,)


def test_empty_batches_and_lists_work():
    assert so3.exp(np.zeros((0, 3))).shape == (0, 3, 3)
    assert so3.log(np.zeros((0, 3, 3))).shape == (0, 3)
    np.testing.assert_allclose(so3.exp([0.0, 0.0, np.pi / 2]), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=2e-16)


# --- properties ------------------------------------------------------------------------------

finite = st.floats(-4.0, 4.0, allow_nan=False, width=64)
vectors = arrays(np.float64, (3,), elements=finite)


@settings(max_examples=200, deadline=None)
@given(vectors, vectors)
def test_group_properties(a, b):
    Ra, Rb = so3.exp(a), so3.exp(b)
    assert_rotation(Ra)
    np.testing.assert_allclose(so3.exp(-a), Ra.T, atol=1e-15)  # inverse
    np.testing.assert_allclose(so3.exp(so3.log(Ra @ Rb)), Ra @ Rb, atol=1e-14)  # closure
    # Ad: R Exp(b) Rᵀ = Exp(R b)
    np.testing.assert_allclose(Ra @ Rb @ Ra.T, so3.exp(Ra @ b), atol=1e-14)
    theta = np.linalg.norm(so3.log(Ra))
    assert 0.0 <= theta <= np.pi * (1 + 4e-16)
    if np.linalg.norm(a) < np.pi - 1e-6:
        np.testing.assert_allclose(so3.log(Ra), a, atol=1e-13)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, (4,), elements=st.floats(-1.0, 1.0, allow_nan=False, width=64)))
def test_quaternion_round_trip_property(q):
    if np.linalg.norm(q) < 1e-6:
        return
    q_unit = q / np.linalg.norm(q) * (1.0 if q[3] >= 0 else -1.0)
    back = so3.to_quaternion(so3.from_quaternion(q))
    if abs(q_unit[3]) > 1e-12:
        np.testing.assert_allclose(back, q_unit, atol=1e-14)
    else:
        np.testing.assert_allclose(abs(back @ q_unit), 1.0, atol=1e-14)
