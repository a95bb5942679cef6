"""SE(3): identities at the edge-case angles, finite differences for every Jacobian, batching, axioms.

Independent references: ``scipy.linalg.expm`` of ``hat(ξ)`` and of ``ad(ξ)``, Solà's matrix
formula for the Q block (products of skew matrices, not the entrywise form the module uses), and
central finite differences.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.linalg import expm

from posegraph.lie import se3, so3
from tests.lie.helpers import BATCH_SHAPES, EDGE_ANGLES, central_difference, poses, tangents, tangents_at_angle

pytestmark = pytest.mark.filterwarnings("error")  # no RuntimeWarning (0/0, overflow) anywhere

I6 = np.eye(6)


def batched_expm(A):
    return np.stack([expm(a) for a in A.reshape(-1, *A.shape[-2:])]).reshape(A.shape)


def at_angle(angle, n=16, seed=0):
    return tangents_at_angle(np.random.default_rng(seed), angle, n)


def sola_q(w, v):
    """Q(ρ = v, θ = w) of Solà (2018), eq. 180, from products of skew matrices (one tangent)."""
    theta = np.linalg.norm(w)
    W, V = so3.hat(w), so3.hat(v)
    if theta < 1e-3:  # its own series: leading terms of the three coefficients
        t2 = theta * theta
        c1, c2, c3 = 1 / 6 - t2 / 120, 1 / 24 - t2 / 720, 1 / 120 - t2 / 2520
    else:
        c1 = (theta - np.sin(theta)) / theta**3
        c2 = (1 - theta**2 / 2 - np.cos(theta)) / theta**4
        c3 = 0.5 * (c2 - 3 * (theta - np.sin(theta) - theta**3 / 6) / theta**5)
        c2, c3 = -c2, -c3
    return (
        0.5 * V
        + c1 * (W @ V + V @ W + W @ V @ W)
        + c2 * (W @ W @ V + V @ W @ W - 3 * W @ V @ W)
        + c3 * (W @ V @ W @ W + W @ W @ V @ W)
    )


# --- hat / vee / Exp / Log -------------------------------------------------------------------


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_hat_vee_and_exp_as_a_matrix_exponential(shape):
    xi = tangents(np.random.default_rng(1), shape)
    X = se3.hat(xi)
    assert X.shape == shape + (4, 4)
    np.testing.assert_array_equal(se3.vee(X), xi)
    np.testing.assert_allclose(se3.exp(xi), batched_expm(X), atol=1e-13)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_log_round_trip(angle):
    xi = at_angle(angle)
    T = se3.exp(xi)
    np.testing.assert_allclose(T, batched_expm(se3.hat(xi)), atol=1e-13)
    np.testing.assert_array_equal(T[:, 3], np.broadcast_to([0, 0, 0, 1.0], (len(xi), 4)))
    back = se3.log(T)
    np.testing.assert_allclose(se3.exp(back), T, atol=4e-15)  # Exp(Log T) = T
    if angle < np.pi:
        # Log(Exp ξ) = ξ; near π the rotation part is ill-conditioned (|dv/dR| ~ 1/(π − θ))
        np.testing.assert_allclose(back, xi, atol=2e-15 if angle < 3 else 2e-9)


def test_log_ignores_the_bottom_row_and_tolerates_drift():
    rng = np.random.default_rng(2)
    T = poses(rng, (100,), max_angle=3.0)
    drifted = T + 1e-10 * rng.normal(size=T.shape)
    np.testing.assert_allclose(se3.log(drifted), se3.log(T), atol=1e-8)


# --- adjoints --------------------------------------------------------------------------------


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_adjoint_is_expm_of_small_adjoint(angle):
    xi = at_angle(angle)
    np.testing.assert_allclose(se3.adjoint(se3.exp(xi)), batched_expm(se3.ad(xi)), atol=1e-13)


def test_adjoint_moves_perturbations_across_the_pose_and_ad_is_the_bracket():
    rng = np.random.default_rng(3)
    T, delta, eta = poses(rng, (20,)), tangents(rng, (20,)), tangents(rng, (20,))
    # T Exp(δ) T⁻¹ = Exp(Ad(T) δ)
    lhs = se3.compose(se3.compose(T, se3.exp(delta)), se3.inverse(T))
    np.testing.assert_allclose(lhs, se3.exp((se3.adjoint(T) @ delta[..., None])[..., 0]), atol=1e-12)
    # ad(ξ) η = vee([hat ξ, hat η])
    A, B = se3.hat(delta), se3.hat(eta)
    np.testing.assert_allclose((se3.ad(delta) @ eta[..., None])[..., 0], se3.vee(A @ B - B @ A), atol=1e-13)
    # Ad is a homomorphism: Ad(a b) = Ad(a) Ad(b), Ad(T⁻¹) = Ad(T)⁻¹
    U = poses(rng, (20,))
    np.testing.assert_allclose(se3.adjoint(se3.compose(T, U)), se3.adjoint(T) @ se3.adjoint(U), atol=1e-12)
    np.testing.assert_allclose(se3.adjoint(se3.inverse(T)) @ se3.adjoint(T), np.broadcast_to(I6, (20, 6, 6)), atol=1e-13)


# --- Jacobians of Exp and Log ----------------------------------------------------------------


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_jacobian_identities(angle):
    xi = at_angle(angle)
    Jr, Jl = se3.right_jacobian(xi), se3.left_jacobian(xi)
    Jr_inv, Jl_inv = se3.right_jacobian_inverse(xi), se3.left_jacobian_inverse(xi)
    eye = np.broadcast_to(I6, Jr.shape)
    np.testing.assert_allclose(Jl, se3.adjoint(se3.exp(xi)) @ Jr, atol=1e-14)  # Jl = Ad(Exp ξ) Jr
    np.testing.assert_allclose(Jl, se3.right_jacobian(-xi), atol=1e-15)  # Jr(−ξ) = Jl(ξ)
    np.testing.assert_allclose(Jl_inv, se3.right_jacobian_inverse(-xi), atol=1e-15)
    np.testing.assert_allclose(Jr @ Jr_inv, eye, atol=1e-14)
    np.testing.assert_allclose(Jr_inv @ Jr, eye, atol=1e-14)
    np.testing.assert_allclose(Jl @ Jl_inv, eye, atol=1e-14)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_lower_blocks_equal_solas_q_formulas(angle):
    # Jl = [[Jl(ω), 0], [Q(v, ω), Jl(ω)]], Jr: Q(−v, −ω), Jr⁻¹: −Jr⁻¹(ω) Q(−v, −ω) Jr⁻¹(ω)
    xi = at_angle(angle, n=8)
    for x, Jl, Jr, Jr_inv in zip(xi, se3.left_jacobian(xi), se3.right_jacobian(xi), se3.right_jacobian_inverse(xi)):
        w, v = x[:3], x[3:]
        Ql, Qr = sola_q(w, v), sola_q(-w, -v)
        np.testing.assert_allclose(Jl[3:, :3], Ql, atol=2e-14)
        np.testing.assert_allclose(Jr[3:, :3], Qr, atol=2e-14)
        Jr3_inv = so3.right_jacobian_inverse(w)
        np.testing.assert_allclose(Jr_inv[3:, :3], -Jr3_inv @ Qr @ Jr3_inv, atol=5e-14)
        np.testing.assert_array_equal(Jr[:3, 3:], 0.0)
        np.testing.assert_allclose(Jr[:3, :3], so3.right_jacobian(w), atol=1e-16)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_jacobians_by_finite_differences(angle):
    xi = at_angle(angle, n=8)
    T = se3.exp(xi)
    T_inv = se3.inverse(T)[:, None]
    # Exp(ξ + δ) = Exp(ξ) Exp(Jr δ) = Exp(Jl δ) Exp(ξ)
    fd_right = central_difference(lambda x: se3.log(se3.compose(T_inv, se3.exp(x))), xi)
    fd_left = central_difference(lambda x: se3.log(se3.compose(se3.exp(x), T_inv)), xi)
    np.testing.assert_allclose(se3.right_jacobian(xi), fd_right, atol=2e-8)
    np.testing.assert_allclose(se3.left_jacobian(xi), fd_left, atol=2e-8)


@pytest.mark.parametrize("angle", [a for a in EDGE_ANGLES if a < 3] + [np.pi - 1e-3])
def test_log_jacobians_by_finite_differences(angle):
    # Log(X Exp(δ)) ≈ Log X + Jr⁻¹ δ, Log(Exp(δ) X) ≈ Log X + Jl⁻¹ δ  (Log jumps at π: stop short)
    xi = at_angle(angle, n=8)
    X = se3.exp(xi)[:, None]
    zero = np.zeros_like(xi)
    fd_right = central_difference(lambda d: se3.log(se3.compose(X, se3.exp(d))), zero, step=1e-7)
    fd_left = central_difference(lambda d: se3.log(se3.compose(se3.exp(d), X)), zero, step=1e-7)
    np.testing.assert_allclose(se3.right_jacobian_inverse(xi), fd_right, atol=5e-7)
    np.testing.assert_allclose(se3.left_jacobian_inverse(xi), fd_left, atol=5e-7)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_of_a_perturbed_tangent_is_a_right_perturbation(angle):
    rng = np.random.default_rng(4)
    xi = at_angle(angle)
    for size in (1e-4, 1e-5):
        delta = size * rng.normal(size=xi.shape) / np.sqrt(6)
        lhs = se3.exp(xi + delta)
        rhs = se3.compose(se3.exp(xi), se3.exp((se3.right_jacobian(xi) @ delta[..., None])[..., 0]))
        assert np.abs(lhs - rhs).max() < 20 * size**2 + 1e-14


# --- Jacobians of the group operations -------------------------------------------------------


def _right_perturbed(T, delta):
    """T ⊕ δ = T Exp(δ), batched over δ's extra axis."""
    return se3.compose(T[..., None, :, :], se3.exp(delta))


def _minus(Y, Y0):
    """Y ⊖ Y0 = Log(Y0⁻¹ Y), with Y0 broadcast over Y's perturbation axis."""
    return se3.log(se3.between(Y0[:, None], Y))


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_compose_inverse_between_jacobians_by_finite_differences(angle):
    a = se3.exp(at_angle(angle, n=6, seed=1))
    b = se3.exp(at_angle(angle, n=6, seed=2))
    zero = np.zeros((6, 6))
    A, B = a[:, None], b[:, None]  # broadcast against the perturbation axis

    def fd(f, base):
        return central_difference(lambda d: _minus(f(d), base), zero)

    J_a, J_b = se3.compose_jacobians(a, b)
    ab = se3.compose(a, b)
    np.testing.assert_allclose(J_a, fd(lambda d: se3.compose(_right_perturbed(a, d), B), ab), atol=2e-8)
    np.testing.assert_allclose(J_b, fd(lambda d: se3.compose(A, _right_perturbed(b, d)), ab), atol=2e-8)

    J_inv = se3.inverse_jacobian(a)
    np.testing.assert_allclose(J_inv, fd(lambda d: se3.inverse(_right_perturbed(a, d)), se3.inverse(a)), atol=2e-8)

    J_a, J_b = se3.between_jacobians(a, b)
    a_to_b = se3.between(a, b)
    np.testing.assert_allclose(J_a, fd(lambda d: se3.between(_right_perturbed(a, d), B), a_to_b), atol=2e-8)
    np.testing.assert_allclose(J_b, fd(lambda d: se3.between(A, _right_perturbed(b, d)), a_to_b), atol=2e-8)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_act_jacobians_by_finite_differences(angle):
    rng = np.random.default_rng(6)
    T = se3.exp(at_angle(angle, n=6))
    p = 3.0 * rng.normal(size=(6, 3))
    J_T, J_p = se3.act_jacobians(T, p)
    assert J_T.shape == (6, 3, 6) and J_p.shape == (6, 3, 3)
    fd_T = central_difference(lambda d: se3.act(_right_perturbed(T, d), p[:, None]), np.zeros((6, 6)))
    fd_p = central_difference(lambda q: se3.act(T[:, None], q), p)
    np.testing.assert_allclose(J_T, fd_T, atol=2e-8)
    np.testing.assert_allclose(J_p, fd_p, atol=2e-8)


# --- batching and broadcasting ---------------------------------------------------------------


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_every_function_takes_any_batch_shape(shape):
    rng = np.random.default_rng(7)
    xi = tangents(rng, shape)
    flat = xi.reshape(-1, 6)
    for f in (se3.right_jacobian, se3.right_jacobian_inverse, se3.left_jacobian, se3.left_jacobian_inverse, se3.ad):
        out = f(xi)
        assert out.shape == shape + (6, 6)
        np.testing.assert_array_equal(out.reshape(-1, 6, 6), f(flat))
    T = se3.exp(xi)
    assert T.shape == shape + (4, 4)
    np.testing.assert_array_equal(T.reshape(-1, 4, 4), se3.exp(flat))
    np.testing.assert_array_equal(se3.log(T).reshape(-1, 6), se3.log(T.reshape(-1, 4, 4)))
    assert se3.adjoint(T).shape == shape + (6, 6)
    assert se3.inverse_jacobian(T).shape == shape + (6, 6)
    assert se3.inverse(T).shape == shape + (4, 4)
    U = poses(rng, shape)
    for f in (se3.compose, se3.between):
        assert f(T, U).shape == shape + (4, 4)
    for f in (se3.compose_jacobians, se3.between_jacobians):
        J_a, J_b = f(T, U)
        assert J_a.shape == J_b.shape == shape + (6, 6)
    p = rng.normal(size=shape + (3,))
    assert se3.act(T, p).shape == shape + (3,)
    J_T, J_p = se3.act_jacobians(T, p)
    assert J_T.shape == shape + (3, 6) and J_p.shape == shape + (3, 3)
    np.testing.assert_array_equal(se3.from_rotation_translation(se3.rotation(T), se3.translation(T)), T)


def test_two_argument_functions_broadcast_batch_shapes():
    rng = np.random.default_rng(8)
    a, b = poses(rng, (3, 1)), poses(rng, (4,))
    out = se3.compose(a, b)
    assert out.shape == (3, 4, 4, 4)
    np.testing.assert_allclose(out[2, 3], a[2, 0] @ b[3], atol=1e-14)
    np.testing.assert_allclose(se3.between(a, b)[1, 2], np.linalg.inv(a[1, 0]) @ b[2], atol=1e-13)
    J_a, J_b = se3.between_jacobians(a, b)
    assert J_a.shape == J_b.shape == (3, 4, 6, 6)
    p = rng.normal(size=(5, 3))
    assert se3.act(b[0], p).shape == (5, 3)
    np.testing.assert_allclose(se3.act(b[0], p), p @ b[0, :3, :3].T + b[0, :3, 3], atol=1e-14)


def test_bad_shapes_are_rejected():
    with pytest.raises(ValueError, match=r"\(\.\.\., 6\)"):
        se3.exp(np.zeros(3))
    with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
        se3.log(np.eye(3))


# --- group axioms (hypothesis) ---------------------------------------------------------------

tangent = arrays(np.float64, (6,), elements=st.floats(-4.0, 4.0, allow_nan=False, width=64))
point = arrays(np.float64, (3,), elements=st.floats(-10.0, 10.0, allow_nan=False, width=64))


@settings(max_examples=150, deadline=None)
@given(tangent, tangent, tangent, point)
def test_group_axioms(x, y, z, p):
    a, b, c = se3.exp(x), se3.exp(y), se3.exp(z)
    eye = np.eye(4)
    np.testing.assert_allclose(se3.compose(se3.compose(a, b), c), se3.compose(a, se3.compose(b, c)), atol=1e-11)
    np.testing.assert_allclose(se3.compose(a, eye), a, atol=0)
    np.testing.assert_allclose(se3.compose(a, se3.inverse(a)), eye, atol=1e-13)
    np.testing.assert_allclose(se3.compose(se3.inverse(a), a), eye, atol=1e-13)
    np.testing.assert_allclose(se3.inverse(a), se3.exp(-x), atol=1e-13)
    np.testing.assert_allclose(se3.between(a, b), se3.compose(se3.inverse(a), b), atol=1e-13)
    np.testing.assert_allclose(se3.act(se3.compose(a, b), p), se3.act(a, se3.act(b, p)), atol=1e-11)
    np.testing.assert_allclose(se3.exp(se3.log(se3.compose(a, b))), se3.compose(a, b), atol=1e-12)
    # one-parameter subgroup: Exp(sξ) Exp(tξ) = Exp((s + t)ξ)
    np.testing.assert_allclose(se3.compose(se3.exp(0.3 * x), se3.exp(0.7 * x)), a, atol=1e-12)


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_large_batch_layout_gives_identical_results(shape, monkeypatch):
    # Outputs above so3._DIRECT_WRITE_BYTES are assembled through a component-major buffer; force
    # that path on small inputs and compare bit for bit with the direct one.
    rng = np.random.default_rng(9)
    xi = tangents(rng, shape)
    T, U = se3.exp(xi), poses(rng, shape)
    p = rng.normal(size=shape + (3,))
    calls = {
        "exp": lambda: se3.exp(xi),
        "Jr": lambda: se3.right_jacobian(xi),
        "Jr_inv": lambda: se3.right_jacobian_inverse(xi),
        "Ad": lambda: se3.adjoint(T),
        "between": lambda: se3.between(T, U),
        "act_J": lambda: se3.act_jacobians(T, p)[0],
        "so3_exp": lambda: so3.exp(xi[..., :3]),
        "quaternion": lambda: so3.from_quaternion(so3.to_quaternion(T[..., :3, :3])),
    }
    direct = {k: f() for k, f in calls.items()}
    monkeypatch.setattr(so3, "_DIRECT_WRITE_BYTES", 0)
    for k, f in calls.items():
        np.testing.assert_array_equal(f(), direct[k], err_msg=k)
