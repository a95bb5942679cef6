"""40-digit references for the SO(3)/SE(3)/SE(2) Jacobians, written independently of posegraph.lie.

Straight from the textbook formulas with mpmath matrices: the SO(3) closed forms with
``1 − cos θ`` and ``sin θ`` as written (mpmath's 40 digits absorb the cancellation), and the SE(3)
lower blocks from Solà's Q(ρ, θ) (2018, eq. 180) as products of skew matrices.  Inputs are float64
numbers, taken as exact.  The arithmetic runs with ``WORKING_DIGITS`` so that, after the worst
cancellation in these formulas (``1 − θ²/2 − cos θ ≈ θ⁴/24``: 48 digits at θ = 1e-12), at least
``DIGITS`` = 40 correct digits remain; results are rounded to float64 at the end.
"""

from __future__ import annotations

import mpmath as mp
import numpy as np

DIGITS = 40
WORKING_DIGITS = DIGITS + 60


def _hat(w):
    return mp.matrix([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def _vec(x):
    return [mp.mpf(float(c)) for c in x]


def _to_numpy(M):
    return np.array([[float(M[i, j]) for j in range(M.cols)] for i in range(M.rows)])


def _so3_parts(w):
    theta = mp.sqrt(sum(c * c for c in w))
    W = _hat(w)
    return theta, W, W * W


def so3_exp(w):
    with mp.workdps(WORKING_DIGITS):
        w = _vec(w)
        theta, W, W2 = _so3_parts(w)
        return _to_numpy(mp.eye(3) + (mp.sin(theta) / theta) * W + ((1 - mp.cos(theta)) / theta**2) * W2)


def _jr(w):
    theta, W, W2 = _so3_parts(w)
    return mp.eye(3) - ((1 - mp.cos(theta)) / theta**2) * W + ((theta - mp.sin(theta)) / theta**3) * W2


def _jr_inv(w):
    theta, W, W2 = _so3_parts(w)
    d = 1 / theta**2 - (1 + mp.cos(theta)) / (2 * theta * mp.sin(theta))
    return mp.eye(3) + W / 2 + d * W2


def _q(rho, phi):
    """Solà's Q(ρ, θ): the lower-left block of the SE(3) left Jacobian (here in [ω; v] order)."""
    theta = mp.sqrt(sum(c * c for c in phi))
    P, R = _hat(phi), _hat(rho)
    s, c = mp.sin(theta), mp.cos(theta)
    c1 = (theta - s) / theta**3
    c2 = (1 - theta**2 / 2 - c) / theta**4
    c3 = (c2 - 3 * (theta - s - theta**3 / 6) / theta**5) / 2
    return R / 2 + c1 * (P * R + R * P + P * R * P) - c2 * (P * P * R + R * P * P - 3 * P * R * P) - c3 * (P * R * P * P + P * P * R * P)


def _blocks(top, lower):
    out = mp.zeros(6, 6)
    for i in range(3):
        for j in range(3):
            out[i, j] = top[i, j]
            out[i + 3, j + 3] = top[i, j]
            out[i + 3, j] = lower[i, j]
    return out


def so3_right_jacobian(w):
    with mp.workdps(WORKING_DIGITS):
        return _to_numpy(_jr(_vec(w)))


def so3_right_jacobian_inverse(w):
    with mp.workdps(WORKING_DIGITS):
        return _to_numpy(_jr_inv(_vec(w)))


def se3_right_jacobian(xi):
    """``[[Jr(ω), 0], [Q(−v, −ω), Jr(ω)]]``."""
    with mp.workdps(WORKING_DIGITS):
        w, v = _vec(xi[:3]), _vec(xi[3:])
        return _to_numpy(_blocks(_jr(w), _q([-c for c in v], [-c for c in w])))


def se3_right_jacobian_inverse(xi):
    """``[[Jr⁻¹, 0], [−Jr⁻¹ Q(−v, −ω) Jr⁻¹, Jr⁻¹]]``."""
    with mp.workdps(WORKING_DIGITS):
        w, v = _vec(xi[:3]), _vec(xi[3:])
        inv = _jr_inv(w)
        return _to_numpy(_blocks(inv, -inv * _q([-c for c in v], [-c for c in w]) * inv))


def _se2_right_jacobian(xi):
    """Solà (2018) eq. 163, ``Jr([ρ; θ])`` in [v_x, v_y, ω] order, written out as there (θ ≠ 0)."""
    r1, r2, t = _vec(xi)
    s, c = mp.sin(t), mp.cos(t)
    return mp.matrix(
        [
            [s / t, (1 - c) / t, (t * r1 - r2 + r2 * c - r1 * s) / t**2],
            [(c - 1) / t, s / t, (r1 + t * r2 - r1 * c - r2 * s) / t**2],
            [0, 0, 1],
        ]
    )


def se2_right_jacobian(xi):
    """Solà's eq. 163 for ``Jr([v; ω])``."""
    with mp.workdps(WORKING_DIGITS):
        return _to_numpy(_se2_right_jacobian(xi))


def se2_right_jacobian_inverse(xi):
    """The inverse of Solà's eq. 163, by mpmath's LU at working precision."""
    with mp.workdps(WORKING_DIGITS):
        return _to_numpy(mp.inverse(_se2_right_jacobian(xi)))


def se2_exp(xi):
    """``[[R(ω), V v], [0, 1]]`` with ``V = (1/ω) [[sin ω, −(1 − cos ω)], [1 − cos ω, sin ω]]`` (Solà eq. 156)."""
    with mp.workdps(WORKING_DIGITS):
        v1, v2, t = _vec(xi)
        s, c = mp.sin(t), mp.cos(t)
        return _to_numpy(mp.matrix([[c, -s, (s * v1 - (1 - c) * v2) / t], [s, c, ((1 - c) * v1 + s * v2) / t], [0, 0, 1]]))


def se2_log(T):
    """``[V⁻¹ t; ω]`` with ``ω = atan2(R₁₀, R₀₀)``, inverting V by mpmath's LU (``T`` taken as exact)."""
    with mp.workdps(WORKING_DIGITS):
        t = mp.atan2(mp.mpf(float(T[1, 0])), mp.mpf(float(T[0, 0])))
        s, c = mp.sin(t), mp.cos(t)
        V = mp.matrix([[s / t, -(1 - c) / t], [(1 - c) / t, s / t]])
        v = mp.lu_solve(V, mp.matrix([mp.mpf(float(T[0, 2])), mp.mpf(float(T[1, 2]))]))
        return np.array([float(v[0]), float(v[1]), float(t)])
