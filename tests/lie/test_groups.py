"""SE(3) and SE(2), one test per property: identities at the edge-case angles, finite differences for
every Jacobian, batching, broadcasting, group axioms.

Every test runs over both groups (``group`` is a :class:`tests.lie.helpers.GroupCase`).
Independent references: ``scipy.linalg.expm`` of ``hat(ξ)`` and of ``ad(ξ)``, and central finite
differences.  Group-specific checks live in test_se3.py (Solà's Q block) and test_se2.py (the
embedding into SE(3), Solà's closed forms, conversions).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.linalg import expm

from posegraph.lie import so3
from tests.lie.helpers import BATCH_SHAPES, EDGE_ANGLES, GROUP_CASES, central_difference

pytestmark = pytest.mark.filterwarnings("error")  # no RuntimeWarning (0/0, overflow) anywhere


@pytest.fixture(params=GROUP_CASES, ids=lambda case: case.name)
def group(request):
    return request.param


def batched_expm(A):
    return np.stack([expm(a) for a in A.reshape(-1, *A.shape[-2:])]).reshape(A.shape)


def apply(M, x):
    """``M @ x`` for batches of matrices and vectors."""
    return (M @ x[..., None])[..., 0]


# --- hat / vee / Exp / Log -------------------------------------------------------------------


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_hat_vee_and_exp_as_a_matrix_exponential(group, shape):
    G, k = group.module, group.matrix_size
    xi = group.random_tangents(np.random.default_rng(1), shape)
    X = G.hat(xi)
    assert X.shape == shape + (k, k)
    np.testing.assert_array_equal(G.vee(X), xi)
    np.testing.assert_allclose(G.exp(xi), batched_expm(X), atol=1e-13)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_log_round_trip(group, angle):
    G, k = group.module, group.matrix_size
    xi = group.at_angle(angle)
    T = G.exp(xi)
    np.testing.assert_allclose(T, batched_expm(G.hat(xi)), atol=1e-13)
    np.testing.assert_array_equal(T[:, k - 1], np.broadcast_to(np.eye(k)[k - 1], (len(xi), k)))
    back = G.log(T)
    np.testing.assert_allclose(G.exp(back), T, atol=4e-15)  # Exp(Log T) = T
    if angle < np.pi:
        # Log(Exp ξ) = ξ; near π the rotation part is ill-conditioned (|dv/dR| ~ 1/(π − θ))
        np.testing.assert_allclose(back, xi, atol=2e-15 if angle < 3 else 2e-9)


def test_log_ignores_the_bottom_row_and_tolerates_drift(group):
    rng = np.random.default_rng(2)
    T = group.poses(rng, (100,), max_angle=3.0)
    drifted = T + 1e-10 * rng.normal(size=T.shape)
    np.testing.assert_allclose(group.module.log(drifted), group.module.log(T), atol=1e-8)


# --- adjoints --------------------------------------------------------------------------------


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_adjoint_is_expm_of_small_adjoint(group, angle):
    G = group.module
    xi = group.at_angle(angle)
    np.testing.assert_allclose(G.adjoint(G.exp(xi)), batched_expm(G.ad(xi)), atol=1e-13)


def test_adjoint_moves_perturbations_across_the_pose_and_ad_is_the_bracket(group):
    G, n = group.module, 20
    rng = np.random.default_rng(3)
    T, delta, eta = group.poses(rng, (n,)), group.random_tangents(rng, (n,)), group.random_tangents(rng, (n,))
    # T Exp(δ) T⁻¹ = Exp(Ad(T) δ)
    lhs = G.compose(G.compose(T, G.exp(delta)), G.inverse(T))
    np.testing.assert_allclose(lhs, G.exp(apply(G.adjoint(T), delta)), atol=1e-12)
    # ad(ξ) η = vee([hat ξ, hat η])
    A, B = G.hat(delta), G.hat(eta)
    np.testing.assert_allclose(apply(G.ad(delta), eta), G.vee(A @ B - B @ A), atol=1e-13)
    # Ad is a homomorphism: Ad(a b) = Ad(a) Ad(b), Ad(T⁻¹) = Ad(T)⁻¹
    U = group.poses(rng, (n,))
    np.testing.assert_allclose(G.adjoint(G.compose(T, U)), G.adjoint(T) @ G.adjoint(U), atol=1e-12)
    eye = np.broadcast_to(np.eye(group.dim), (n, group.dim, group.dim))
    np.testing.assert_allclose(G.adjoint(G.inverse(T)) @ G.adjoint(T), eye, atol=1e-13)


# --- Jacobians of Exp and Log ----------------------------------------------------------------


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_jacobian_identities(group, angle):
    G = group.module
    xi = group.at_angle(angle)
    Jr, Jl = G.right_jacobian(xi), G.left_jacobian(xi)
    Jr_inv, Jl_inv = G.right_jacobian_inverse(xi), G.left_jacobian_inverse(xi)
    eye = np.broadcast_to(np.eye(group.dim), Jr.shape)
    np.testing.assert_allclose(Jl, G.adjoint(G.exp(xi)) @ Jr, atol=1e-14)  # Jl = Ad(Exp ξ) Jr
    np.testing.assert_allclose(Jl, G.right_jacobian(-xi), atol=1e-15)  # Jr(−ξ) = Jl(ξ)
    np.testing.assert_allclose(Jl_inv, G.right_jacobian_inverse(-xi), atol=1e-15)
    np.testing.assert_allclose(Jr @ Jr_inv, eye, atol=1e-14)
    np.testing.assert_allclose(Jr_inv @ Jr, eye, atol=1e-14)
    np.testing.assert_allclose(Jl @ Jl_inv, eye, atol=1e-14)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_jacobians_by_finite_differences(group, angle):
    G = group.module
    xi = group.at_angle(angle, n=8)
    T_inv = G.inverse(G.exp(xi))[:, None]
    # Exp(ξ + δ) = Exp(ξ) Exp(Jr δ) = Exp(Jl δ) Exp(ξ)
    fd_right = central_difference(lambda x: G.log(G.compose(T_inv, G.exp(x))), xi)
    fd_left = central_difference(lambda x: G.log(G.compose(G.exp(x), T_inv)), xi)
    np.testing.assert_allclose(G.right_jacobian(xi), fd_right, atol=2e-8)
    np.testing.assert_allclose(G.left_jacobian(xi), fd_left, atol=2e-8)


@pytest.mark.parametrize("angle", [a for a in EDGE_ANGLES if a < 3] + [np.pi - 1e-3])
def test_log_jacobians_by_finite_differences(group, angle):
    # Log(X Exp(δ)) ≈ Log X + Jr⁻¹ δ, Log(Exp(δ) X) ≈ Log X + Jl⁻¹ δ  (Log jumps at π: stop short)
    G = group.module
    xi = group.at_angle(angle, n=8)
    X = G.exp(xi)[:, None]
    zero = np.zeros_like(xi)
    fd_right = central_difference(lambda d: G.log(G.compose(X, G.exp(d))), zero, step=1e-7)
    fd_left = central_difference(lambda d: G.log(G.compose(G.exp(d), X)), zero, step=1e-7)
    np.testing.assert_allclose(G.right_jacobian_inverse(xi), fd_right, atol=5e-7)
    np.testing.assert_allclose(G.left_jacobian_inverse(xi), fd_left, atol=5e-7)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_of_a_perturbed_tangent_is_a_right_perturbation(group, angle):
    G = group.module
    rng = np.random.default_rng(4)
    xi = group.at_angle(angle)
    for size in (1e-4, 1e-5):
        delta = size * rng.normal(size=xi.shape) / np.sqrt(group.dim)
        lhs = G.exp(xi + delta)
        rhs = G.compose(G.exp(xi), G.exp(apply(G.right_jacobian(xi), delta)))
        assert np.abs(lhs - rhs).max() < 20 * size**2 + 1e-14


# --- Jacobians of the group operations -------------------------------------------------------


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_compose_inverse_between_jacobians_by_finite_differences(group, angle):
    G, n = group.module, 6
    a = G.exp(group.at_angle(angle, n=n, seed=1))
    b = G.exp(group.at_angle(angle, n=n, seed=2))
    zero = np.zeros((n, group.dim))
    A, B = a[:, None], b[:, None]  # broadcast against the perturbation axis

    def perturbed(T, d):  # T ⊕ δ = T Exp(δ), batched over δ's extra axis
        return G.compose(T[..., None, :, :], G.exp(d))

    def fd(f, base):  # Jacobian of δ ↦ f(δ) ⊖ base = Log(base⁻¹ f(δ))
        return central_difference(lambda d: G.log(G.between(base[:, None], f(d))), zero)

    J_a, J_b = G.compose_jacobians(a, b)
    ab = G.compose(a, b)
    np.testing.assert_allclose(J_a, fd(lambda d: G.compose(perturbed(a, d), B), ab), atol=2e-8)
    np.testing.assert_allclose(J_b, fd(lambda d: G.compose(A, perturbed(b, d)), ab), atol=2e-8)

    J_inv = G.inverse_jacobian(a)
    np.testing.assert_allclose(J_inv, fd(lambda d: G.inverse(perturbed(a, d)), G.inverse(a)), atol=2e-8)

    J_a, J_b = G.between_jacobians(a, b)
    a_to_b = G.between(a, b)
    np.testing.assert_allclose(J_a, fd(lambda d: G.between(perturbed(a, d), B), a_to_b), atol=2e-8)
    np.testing.assert_allclose(J_b, fd(lambda d: G.between(A, perturbed(b, d)), a_to_b), atol=2e-8)

    p = 3.0 * np.random.default_rng(6).normal(size=(n, group.point_dim))
    J_T, J_p = G.act_jacobians(a, p)
    assert J_T.shape == (n, group.point_dim, group.dim) and J_p.shape == (n, group.point_dim, group.point_dim)
    fd_T = central_difference(lambda d: G.act(perturbed(a, d), p[:, None]), zero)
    fd_p = central_difference(lambda q: G.act(A, q), p)
    np.testing.assert_allclose(J_T, fd_T, atol=2e-8)
    np.testing.assert_allclose(J_p, fd_p, atol=2e-8)


# --- batching and broadcasting ---------------------------------------------------------------


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_every_function_takes_any_batch_shape(group, shape):
    G, d, k, p_dim = group.module, group.dim, group.matrix_size, group.point_dim
    rng = np.random.default_rng(7)
    xi = group.random_tangents(rng, shape)
    flat = xi.reshape(-1, d)
    for f in (G.right_jacobian, G.right_jacobian_inverse, G.left_jacobian, G.left_jacobian_inverse, G.ad):
        out = f(xi)
        assert out.shape == shape + (d, d)
        np.testing.assert_array_equal(out.reshape(-1, d, d), f(flat))
    T = G.exp(xi)
    assert T.shape == shape + (k, k)
    np.testing.assert_array_equal(T.reshape(-1, k, k), G.exp(flat))
    np.testing.assert_array_equal(G.log(T).reshape(-1, d), G.log(T.reshape(-1, k, k)))
    assert G.adjoint(T).shape == shape + (d, d)
    assert G.inverse_jacobian(T).shape == shape + (d, d)
    assert G.inverse(T).shape == shape + (k, k)
    U = group.poses(rng, shape)
    for f in (G.compose, G.between):
        assert f(T, U).shape == shape + (k, k)
    for f in (G.compose_jacobians, G.between_jacobians):
        J_a, J_b = f(T, U)
        assert J_a.shape == J_b.shape == shape + (d, d)
    p = rng.normal(size=shape + (p_dim,))
    assert G.act(T, p).shape == shape + (p_dim,)
    J_T, J_p = G.act_jacobians(T, p)
    assert J_T.shape == shape + (p_dim, d) and J_p.shape == shape + (p_dim, p_dim)
    if group.name == "sim3":  # the rotation is s R / s: rebuilt to rounding
        np.testing.assert_allclose(G.from_rotation_translation_scale(G.rotation(T), G.translation(T), G.scale(T)), T, rtol=1e-15, atol=1e-15)
    else:
        np.testing.assert_array_equal(G.from_rotation_translation(G.rotation(T), G.translation(T)), T)


def test_two_argument_functions_broadcast_batch_shapes(group):
    G, k, p_dim = group.module, group.matrix_size, group.point_dim
    rng = np.random.default_rng(8)
    a, b = group.poses(rng, (3, 1)), group.poses(rng, (4,))
    out = G.compose(a, b)
    assert out.shape == (3, 4, k, k)
    np.testing.assert_allclose(out[2, 3], a[2, 0] @ b[3], atol=1e-14)
    np.testing.assert_allclose(G.between(a, b)[1, 2], np.linalg.inv(a[1, 0]) @ b[2], atol=1e-13)
    J_a, J_b = G.between_jacobians(a, b)
    assert J_a.shape == J_b.shape == (3, 4, group.dim, group.dim)
    p = rng.normal(size=(5, p_dim))
    assert G.act(b[0], p).shape == (5, p_dim)
    np.testing.assert_allclose(G.act(b[0], p), p @ b[0, :p_dim, :p_dim].T + b[0, :p_dim, p_dim], atol=1e-14)


def test_bad_shapes_are_rejected(group):
    G, k = group.module, group.matrix_size
    with pytest.raises(ValueError, match=rf"\(\.\.\., {group.dim}\)"):
        G.exp(np.zeros(group.dim + 1))
    with pytest.raises(ValueError, match=rf"\(\.\.\., {k}, {k}\)"):
        G.log(np.eye(k + 1))


# --- group axioms (hypothesis) ---------------------------------------------------------------


def _check_group_axioms(G, x, y, z, p):
    a, b, c = G.exp(x), G.exp(y), G.exp(z)
    eye = np.eye(a.shape[-1])
    np.testing.assert_allclose(G.compose(G.compose(a, b), c), G.compose(a, G.compose(b, c)), atol=1e-11)
    np.testing.assert_allclose(G.compose(a, eye), a, atol=0)
    np.testing.assert_allclose(G.compose(a, G.inverse(a)), eye, atol=1e-13)
    np.testing.assert_allclose(G.compose(G.inverse(a), a), eye, atol=1e-13)
    np.testing.assert_allclose(G.inverse(a), G.exp(-x), atol=1e-13)
    np.testing.assert_allclose(G.between(a, b), G.compose(G.inverse(a), b), atol=1e-13)
    np.testing.assert_allclose(G.act(G.compose(a, b), p), G.act(a, G.act(b, p)), atol=1e-11)
    np.testing.assert_allclose(G.exp(G.log(G.compose(a, b))), G.compose(a, b), atol=1e-12)
    # one-parameter subgroup: Exp(sξ) Exp(tξ) = Exp((s + t)ξ)
    np.testing.assert_allclose(G.compose(G.exp(0.3 * x), G.exp(0.7 * x)), a, atol=1e-12)


def _vectors(n, bound):
    return arrays(np.float64, (n,), elements=st.floats(-bound, bound, allow_nan=False, width=64))


@pytest.mark.parametrize("case", GROUP_CASES, ids=lambda case: case.name)
def test_group_axioms(case):
    @settings(max_examples=150, deadline=None)
    @given(_vectors(case.dim, 4.0), _vectors(case.dim, 4.0), _vectors(case.dim, 4.0), _vectors(case.point_dim, 10.0))
    def check(x, y, z, p):
        _check_group_axioms(case.module, x, y, z, p)

    check()


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_large_batch_layout_gives_identical_results(group, shape, monkeypatch):
    # Outputs above so3._DIRECT_WRITE_BYTES are assembled through a component-major buffer; force
    # that path on small inputs and compare bit for bit with the direct one.
    G = group.module
    rng = np.random.default_rng(9)
    xi = group.random_tangents(rng, shape)
    T, U = G.exp(xi), group.poses(rng, shape)
    p = rng.normal(size=shape + (group.point_dim,))
    calls = {
        "exp": lambda: G.exp(xi),
        "Jr": lambda: G.right_jacobian(xi),
        "Jr_inv": lambda: G.right_jacobian_inverse(xi),
        "Ad": lambda: G.adjoint(T),
        "between": lambda: G.between(T, U),
        "act_J": lambda: G.act_jacobians(T, p)[0],
    }
    direct = {k: f() for k, f in calls.items()}
    monkeypatch.setattr(so3, "_DIRECT_WRITE_BYTES", 0)
    for k, f in calls.items():
        np.testing.assert_array_equal(f(), direct[k], err_msg=k)
