"""SE(2)-specific checks: the embedding into SE(3), Solà's closed forms, conversions, wrapping.

Shared properties (Exp/Log, adjoints, finite differences of every Jacobian, batching, axioms) are
tested over SE(3) and SE(2) in test_groups.py.  Independent references here: :mod:`se3` (SE(2) is
the subgroup of SE(3) of rotations about z and translations in the xy plane, so every SE(2) map is
a sub-block of the SE(3) one) and 40-digit mpmath values of Solà's eq. 156/163.
"""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.lie import se2, se3, so2
from tests.lie import mpmath_reference as ref
from tests.lie.helpers import EDGE_ANGLES, se2_tangents, se2_tangents_at_angle

pytestmark = pytest.mark.filterwarnings("error")

# se(2) index k sits at se(3) index TANGENT_INDEX[k]: v_x → v_x (3), v_y → v_y (4), ω → ω_z (2).
TANGENT_INDEX = [3, 4, 2]


def embed_tangent(xi):
    out = np.zeros(xi.shape[:-1] + (6,))
    out[..., TANGENT_INDEX] = xi
    return out


def restrict(M):
    """The SE(2) block of an SE(3) tangent-space matrix ``(..., 6, 6)``."""
    return M[..., TANGENT_INDEX, :][..., :, TANGENT_INDEX]


def at_angle(angle, n=16, seed=0):
    return se2_tangents_at_angle(np.random.default_rng(seed), angle, n)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_every_map_is_the_se3_map_restricted_to_the_plane(angle):
    xi = at_angle(angle)
    xi3 = embed_tangent(xi)
    T = se2.exp(xi)
    np.testing.assert_allclose(se2.to_se3(T), se3.exp(xi3), atol=2e-15)
    np.testing.assert_allclose(se2.hat(xi), se3.hat(xi3)[..., [0, 1, 3], :][..., [0, 1, 3]], atol=0)
    np.testing.assert_allclose(embed_tangent(se2.log(T)), se3.log(se2.to_se3(T)), atol=2e-15 if angle < 3 else 2e-9)
    pairs = [
        (se2.right_jacobian, se3.right_jacobian),
        (se2.left_jacobian, se3.left_jacobian),
        (se2.right_jacobian_inverse, se3.right_jacobian_inverse),
        (se2.left_jacobian_inverse, se3.left_jacobian_inverse),
        (se2.ad, se3.ad),
    ]
    for ours, theirs in pairs:
        np.testing.assert_allclose(ours(xi), restrict(theirs(xi3)), atol=2e-15, err_msg=ours.__name__)
    np.testing.assert_allclose(se2.adjoint(T), restrict(se3.adjoint(se2.to_se3(T))), atol=0)
    # and the matrix embedding is a homomorphism
    U = se2.exp(at_angle(angle, seed=1))
    np.testing.assert_allclose(se2.to_se3(se2.compose(T, U)), se2.to_se3(T) @ se2.to_se3(U), atol=1e-14)


SMALL = (1e-12, 1e-8, 1e-6, 1e-4, 1e-2, 0.3)
NEAR_PI = (np.pi - 1e-3, np.pi - 1e-6, np.pi - 1e-12, np.pi)


@pytest.mark.parametrize("angle", SMALL + (1.0, 2.5) + NEAR_PI)
def test_exp_log_and_jacobians_against_40_digit_values(angle):
    xi = at_angle(angle, n=6, seed=2) * [3.0, 3.0, 1.0]
    worst = {}
    for x in xi:
        T = se2.exp(x)
        worst["exp"] = max(worst.get("exp", 0.0), np.abs(T - ref.se2_exp(x)).max())
        worst["log"] = max(worst.get("log", 0.0), np.abs(se2.log(T) - ref.se2_log(T)).max())
        worst["Jr"] = max(worst.get("Jr", 0.0), np.abs(se2.right_jacobian(x) - ref.se2_right_jacobian(x)).max())
        worst["Jl"] = max(worst.get("Jl", 0.0), np.abs(se2.left_jacobian(x) - ref.se2_right_jacobian(-x)).max())
        worst["Jr_inv"] = max(worst.get("Jr_inv", 0.0), np.abs(se2.right_jacobian_inverse(x) - ref.se2_right_jacobian_inverse(x)).max())
    # a few ulps of the largest entries (|v| up to ~10); Log near π is ill-conditioned in v
    bounds = {"exp": 4e-15, "log": 4e-15 if angle < 3 else 1e-9, "Jr": 4e-15, "Jl": 4e-15, "Jr_inv": 1e-14}
    for name, value in worst.items():
        assert value <= bounds[name], f"{name} at |ω| = {angle!r}: max |ours − mpmath| = {value:.1e}"


def test_log_returns_angles_in_minus_pi_to_pi_and_wraps():
    rng = np.random.default_rng(3)
    xi = se2_tangents(rng, (300,), max_angle=12.0)
    w = se2.log(se2.exp(xi))[:, 2]
    assert np.all(np.abs(w) <= np.pi)
    np.testing.assert_allclose(np.cos(w - xi[:, 2]), 1.0, atol=1e-14)
    np.testing.assert_allclose(se2.exp(se2.log(se2.exp(xi))), se2.exp(xi), atol=1e-13)


def test_xytheta_conversions():
    rng = np.random.default_rng(4)
    pose = np.c_[rng.normal(size=(50, 2)) * 10, rng.uniform(-np.pi, np.pi, 50)]
    T = se2.from_xytheta(pose)
    np.testing.assert_array_equal(T[:, :2, 2], pose[:, :2])
    np.testing.assert_array_equal(T[:, :2, :2], so2.from_angle(pose[:, 2]))
    np.testing.assert_array_equal(T[:, 2], np.broadcast_to([0.0, 0.0, 1.0], (50, 3)))
    np.testing.assert_allclose(se2.to_xytheta(T), pose, atol=4e-16 * np.pi)
    assert se2.to_xytheta(se2.from_xytheta([1.0, 2.0, 3 * np.pi / 2]))[2] == pytest.approx(-np.pi / 2)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        se2.from_xytheta([1.0, 2.0])


def test_to_se3_embeds_in_the_z0_plane():
    T = se2.from_xytheta([[1.0, -2.0, 0.5], [3.0, 4.0, -2.0]])
    T3 = se2.to_se3(T)
    assert T3.shape == (2, 4, 4)
    np.testing.assert_array_equal(T3[:, 2], [[0, 0, 1, 0]] * 2)
    np.testing.assert_array_equal(T3[:, :, 2], [[0, 0, 1, 0]] * 2)
    np.testing.assert_array_equal(T3[:, :2, 3], [[1.0, -2.0], [3.0, 4.0]])
    np.testing.assert_allclose(se3.log(T3)[:, :3], [[0, 0, 0.5], [0, 0, -2.0]], atol=1e-15)


def test_embed_in_se3_embeds_planar_poses_and_passes_3d_ones_through():
    from posegraph.lie import se3
    from posegraph.lie.group import embed_in_se3

    planar = se2.exp(np.array([[0.3, -1.2, 2.5], [1.0, 2.0, -0.4]]))
    np.testing.assert_array_equal(embed_in_se3(planar), se2.to_se3(planar))
    spatial = se3.exp(np.array([[0.1, 0.2, 0.3, 1.0, 2.0, 3.0]]))
    assert embed_in_se3(spatial) is spatial
