"""SE(3)-specific checks: the Jacobians' lower blocks against Solà's Q formula, and the SO(3) parts.

The properties SE(3) shares with SE(2) (Exp/Log, adjoints, finite differences of every Jacobian,
batching, axioms) are tested over both groups in test_groups.py.  Independent reference here:
Solà's matrix formula for the Q block (products of skew matrices, not the entrywise form the
module uses).
"""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.lie import se3, so3
from tests.lie.helpers import BATCH_SHAPES, EDGE_ANGLES, tangents, tangents_at_angle

pytestmark = pytest.mark.filterwarnings("error")  # no RuntimeWarning (0/0, overflow) anywhere


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


# --- Jacobians: lower blocks ----------------------------------------------------------------


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



@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_large_batch_layout_gives_identical_so3_results(shape, monkeypatch):
    # The SO(3) functions share the component-major output path (test_groups.py checks SE(3)'s).
    rng = np.random.default_rng(9)
    R = se3.exp(tangents(rng, shape))[..., :3, :3]
    w = tangents(rng, shape)[..., :3]
    calls = {
        "so3_exp": lambda: so3.exp(w),
        "quaternion": lambda: so3.from_quaternion(so3.to_quaternion(R)),
    }
    direct = {k: f() for k, f in calls.items()}
    monkeypatch.setattr(so3, "_DIRECT_WRITE_BYTES", 0)
    for k, f in calls.items():
        np.testing.assert_array_equal(f(), direct[k], err_msg=k)
