"""SO(2): Exp/Log against the matrix exponential and angle arithmetic, wrapping, projection, batching.

Independent references: ``scipy.linalg.expm`` of the skew matrix, ``numpy.cos``/``sin`` of the
angle, and finite differences for the (trivial) Jacobians.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm

from posegraph.lie import so2
from tests.lie.helpers import BATCH_SHAPES, EDGE_ANGLES, central_difference

pytestmark = pytest.mark.filterwarnings("error")

SIGNED_ANGLES = sorted({s * a for a in EDGE_ANGLES for s in (1.0, -1.0)})


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_hat_vee_exp_and_log_on_any_batch_shape(shape):
    w = np.random.default_rng(1).uniform(-np.pi, np.pi, size=shape + (1,))
    W = so2.hat(w)
    assert W.shape == shape + (2, 2)
    np.testing.assert_array_equal(W, -np.swapaxes(W, -1, -2))
    np.testing.assert_array_equal(so2.vee(W), w)
    R = so2.exp(w)
    assert R.shape == shape + (2, 2)
    np.testing.assert_allclose(R, np.stack([expm(x) for x in W.reshape(-1, 2, 2)]).reshape(R.shape), atol=1e-15)
    np.testing.assert_allclose(so2.log(R), w, atol=1e-15)
    for f in (so2.right_jacobian, so2.right_jacobian_inverse, so2.left_jacobian, so2.left_jacobian_inverse):
        np.testing.assert_array_equal(f(w), np.ones(shape + (1, 1)))


@pytest.mark.parametrize("angle", SIGNED_ANGLES)
def test_exp_log_at_the_edge_angles(angle):
    R = so2.exp([angle])
    np.testing.assert_allclose(R, [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]], atol=0)
    assert abs(np.linalg.det(R) - 1.0) <= 2e-16
    back = so2.log(R)[0]
    if abs(angle) < np.pi:
        assert back == pytest.approx(angle, abs=4e-16, rel=2e-16)
    else:  # ±π are the same rotation; atan2 returns one of them
        assert abs(back) == pytest.approx(np.pi, abs=4e-16)


def test_log_wraps_into_minus_pi_to_pi_and_tolerates_drift():
    rng = np.random.default_rng(2)
    theta = rng.uniform(-20.0, 20.0, size=500)
    wrapped = so2.to_angle(so2.from_angle(theta))
    assert np.all(np.abs(wrapped) <= np.pi)
    np.testing.assert_allclose(np.cos(wrapped - theta), 1.0, atol=1e-15)
    R = so2.from_angle(theta)
    drifted = R + 1e-9 * rng.normal(size=R.shape)
    np.testing.assert_allclose(so2.to_angle(drifted), wrapped, atol=3e-9)


def test_project_gives_the_nearest_rotation():
    rng = np.random.default_rng(3)
    M = rng.normal(size=(200, 2, 2))
    R = so2.project(M)
    np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, np.broadcast_to(np.eye(2), R.shape), atol=1e-15)
    # nearest in Frobenius norm: no rotation on a fine grid of angles comes closer
    grid = so2.from_angle(np.linspace(-np.pi, np.pi, 3601))
    best = np.linalg.norm(M[:, None] - grid[None], axis=(-2, -1)).min(axis=1)
    assert np.all(np.linalg.norm(M - R, axis=(-2, -1)) <= best + 1e-12)
    np.testing.assert_array_equal(so2.project(so2.from_angle(0.7)), so2.from_angle(0.7))


def test_jacobians_by_finite_differences():
    w = np.random.default_rng(4).uniform(-3.0, 3.0, size=(10, 1))
    R_inv = np.swapaxes(so2.exp(w), -1, -2)[:, None]
    fd = central_difference(lambda x: so2.log(R_inv @ so2.exp(x)), w)
    np.testing.assert_allclose(so2.right_jacobian(w), fd, atol=1e-9)


def test_bad_shapes_are_rejected():
    with pytest.raises(ValueError, match=r"\(\.\.\., 1\)"):
        so2.exp(np.zeros(2))
    with pytest.raises(ValueError, match=r"\(\.\.\., 2, 2\)"):
        so2.log(np.eye(3))


@settings(max_examples=200, deadline=None)
@given(st.floats(-10.0, 10.0), st.floats(-10.0, 10.0))
def test_products_add_angles(a, b):
    np.testing.assert_allclose(so2.from_angle(a) @ so2.from_angle(b), so2.from_angle(a + b), atol=1e-14)
    np.testing.assert_allclose(so2.exp([a]).T, so2.exp([-a]), atol=0)
