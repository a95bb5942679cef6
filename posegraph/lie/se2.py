"""SE(2): planar rigid transforms as ``(..., 3, 3)`` matrices, tangent vectors ``ξ = [v_x, v_y, ω]`` as ``(..., 3)``.

Translation first, as in gtsam's ``Pose2``: ``ξ[..., :2] = v``, ``ξ[..., 2] = ω`` (the angle).
Every function has the name and call signature of its :mod:`posegraph.lie.se3` counterpart, takes
any leading batch shape (two-argument functions broadcast them) and works on the whole batch in
one vectorised numpy call (float64).

Conventions (Solà, "A micro Lie theory for state estimation in robotics", 2018, §A.6 and eq.
163–164, in gtsam's [v; ω] order), with ``J = [[0, −1], [1, 0]]`` and ``R = R(ω)``:

* ``hat(ξ) = [[ω J, v], [0, 0]]``; ``Exp(ξ) = [[R, V(ω) v], [0, 1]]`` with
  ``V(ω) = A I + ω B J`` (the SO(3) ``Jl`` about the z axis, restricted to the plane).
* Right perturbations ``T ⊕ δ = T · Exp(δ)``, ``Y ⊖ X = Log(X⁻¹ Y)``; each ``J_out_in`` below
  is the right Jacobian of an output w.r.t. a right perturbation of one input (manif's names).
* ``Ad(T) = [[R, −J t], [0, 1]]`` (``−J t = [t_y, −t_x]``), so that ``T Exp(δ) = Exp(Ad(T) δ) T``;
  ``ad(ξ) = [[ω J, −J v], [0, 0]]`` and ``Ad(Exp ξ) = expm(ad ξ)``.
* gtsam names: ``Pose2.Expmap/Logmap``, ``Pose2.ExpmapDerivative = Jr``,
  ``Pose2.LogmapDerivative = Jr⁻¹ ∘ Log``, ``Pose2.AdjointMap = Ad``, ``Pose2.adjointMap = ad``.

The four Jacobians share one structure.  ``Jr(ξ) = f(ad ξ)`` for a power series ``f``
(``(1 − e⁻ˣ)/x`` for ``Jr``, ``x/(1 − e⁻ˣ)`` for ``Jr⁻¹``, ``x → −x`` for the left ones), and
``ad ξ = [[M, c], [0, 0]]`` with ``M = ω J``, ``c = −J v`` is block upper-triangular, so
``f(ad ξ) = [[f(M), (f(M) − f(0)) M⁻¹ c], [0, f(0)]]`` with ``f(0) = 1`` and ``M⁻¹ c = −v/ω``::

    f(M) = α I + β ω J,        last column = ((1 − α)/ω) v − β J v = ω γ v − β J v

where ``γ = (1 − α)/ω²`` and, with ``A … E`` of :mod:`posegraph.lie.so3` evaluated at ``|ω|``:

    Jr:   (α, β, γ) = (A, −B, C)            Jl:   (A,  B, C)
    Jr⁻¹: (α, β, γ) = (E,  ½, D)            Jl⁻¹: (E, −½, D)

(``1 − A = θ² C`` and ``1 − E = θ² D``).  Expanded, ``Jr`` is Solà's eq. 163.  ``Log`` inverts
``V`` as ``V⁻¹ = E I − (ω/2) J`` (the same ``Jl⁻¹``).

Numerics.  Every coefficient is an even function of ``ω`` taken from :mod:`so3`, which switches
to Taylor polynomials below ``so3._SERIES_ANGLE`` (the reason is given there): nothing here divides
by ``ω`` or by ``sin ω``, so this module needs no threshold of its own.  ``E = (ω/2)cot(ω/2)``
keeps ``Log`` and ``Jr⁻¹`` exact through ``|ω| = π``; ``Jr⁻¹`` is singular only at ``2π``.
"""

from __future__ import annotations

import numpy as np

from posegraph.lie import so2
from posegraph.lie.se3 import _broadcast_batch, _identity
from posegraph.lie.so3 import (
    _as_float,
    _check_last,
    _components,
    _exp_coefficients,
    _from_entries,
    _from_vector,
    _half_cot,
    _inverse_jacobian_coefficients,
)

__all__ = [
    "hat",
    "vee",
    "exp",
    "log",
    "adjoint",
    "ad",
    "right_jacobian",
    "right_jacobian_inverse",
    "left_jacobian",
    "left_jacobian_inverse",
    "inverse",
    "compose",
    "between",
    "edge_errors",
    "adjoint_of_inverse",
    "act",
    "from_rotation_translation",
    "rotation",
    "translation",
    "compose_jacobians",
    "inverse_jacobian",
    "between_jacobians",
    "act_jacobians",
    "from_xytheta",
    "to_xytheta",
    "to_se3",
]

_BOTTOM_ROW = (0.0, 0.0, 1.0)


def _pose_components(T, batch=None):
    """``(R entries (4, n) row-major, t (2, n), batch)`` of ``T (..., 3, 3)``, broadcast to ``batch``."""
    T = _as_float(T)
    _check_last(T, (3, 3), "T")
    if batch is not None:
        T = np.broadcast_to(T, batch + (3, 3))
    c, batch = _components(T, (3, 3), "T")
    return c[[0, 1, 3, 4]], c[[2, 5]], batch


def _pose_from(r, t, batch) -> np.ndarray:
    """``(*batch, 3, 3)`` from 4 rotation entries (row-major) and 2 translation components."""
    return _from_entries([[r[0], r[1], t[0]], [r[2], r[3], t[1]], [*_BOTTOM_ROW]], batch)


# ---------------------------------------------------------------------------------------------
# Construction, conversions, hat / vee
# ---------------------------------------------------------------------------------------------


def from_rotation_translation(R, t) -> np.ndarray:
    """``T = [[R, t], [0, 1]]`` from ``R (..., 2, 2)`` and ``t (..., 2)`` (batch shapes broadcast)."""
    R = _as_float(R)
    t = _as_float(t)
    _check_last(R, (2, 2), "R")
    _check_last(t, (2,), "t")
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    out = np.zeros(batch + (3, 3), dtype=np.float64)
    out[..., :2, :2] = R
    out[..., :2, 2] = t
    out[..., 2, 2] = 1.0
    return out


def rotation(T) -> np.ndarray:
    """Rotation block ``(..., 2, 2)`` of ``T`` (a view)."""
    T = _as_float(T)
    _check_last(T, (3, 3), "T")
    return T[..., :2, :2]


def translation(T) -> np.ndarray:
    """Translation ``(..., 2)`` of ``T`` (a view)."""
    T = _as_float(T)
    _check_last(T, (3, 3), "T")
    return T[..., :2, 2]


def from_xytheta(pose) -> np.ndarray:
    """``T (..., 3, 3)`` from ``[x, y, θ] (..., 3)`` (g2o's ``VERTEX_SE2``/``EDGE_SE2`` and gtsam's ``Pose2(x, y, θ)``)."""
    pose = _as_float(pose)
    _check_last(pose, (3,), "pose")
    return from_rotation_translation(so2.from_angle(pose[..., 2]), pose[..., :2])


def to_xytheta(T) -> np.ndarray:
    """``[x, y, θ] (..., 3)`` of ``T (..., 3, 3)``, ``θ = so2.to_angle(R)`` in ``[−π, π]``."""
    T = _as_float(T)
    _check_last(T, (3, 3), "T")
    return np.concatenate([T[..., :2, 2], so2.to_angle(T[..., :2, :2])[..., None]], axis=-1)


def to_se3(T) -> np.ndarray:
    """Embed ``T (..., 3, 3)`` in SE(3) at ``z = 0``: rotation about the z axis, ``(..., 4, 4)``.

    A homomorphism: ``to_se3(a b) = to_se3(a) to_se3(b)``, and ``to_se3(Exp [v_x, v_y, ω]) =
    se3.Exp([0, 0, ω, v_x, v_y, 0])``.
    """
    T = _as_float(T)
    _check_last(T, (3, 3), "T")
    out = np.zeros(T.shape[:-2] + (4, 4), dtype=np.float64)
    out[..., :2, :2] = T[..., :2, :2]
    out[..., :2, 3] = T[..., :2, 2]
    out[..., 2, 2] = 1.0
    out[..., 3, 3] = 1.0
    return out


def hat(xi) -> np.ndarray:
    """``hat([v; ω]) = [[0, −ω, v_x], [ω, 0, v_y], [0, 0, 0]]``: ``(..., 3) -> (..., 3, 3)``."""
    xi = _as_float(xi)
    _check_last(xi, (3,), "xi")
    out = np.zeros(xi.shape[:-1] + (3, 3), dtype=np.float64)
    out[..., :2, :2] = so2.hat(xi[..., 2:])
    out[..., :2, 2] = xi[..., :2]
    return out


def vee(X) -> np.ndarray:
    """Inverse of :func:`hat`: ``(..., 3, 3) -> (..., 3)`` as ``[v_x, v_y, ω]``."""
    X = _as_float(X)
    _check_last(X, (3, 3), "X")
    return np.concatenate([X[..., :2, 2], so2.vee(X[..., :2, :2])], axis=-1)


# ---------------------------------------------------------------------------------------------
# Exp, Log, adjoints
# ---------------------------------------------------------------------------------------------


def exp(xi) -> np.ndarray:
    """``Exp([v; ω]) = [[R(ω), V(ω) v], [0, 1]]``, ``V(ω) v = A v + ω B J v``.

    ``(..., 3) -> (..., 3, 3)``; equals gtsam's ``Pose2.Expmap``.
    """
    (v0, v1, w), batch = _components(xi, (3,), "xi")
    a, b = _exp_coefficients(np.abs(w), 2)
    cos, sin = np.cos(w), np.sin(w)
    wb = w * b  # = (1 − cos ω)/ω
    t0 = a * v0 - wb * v1
    t1 = a * v1 + wb * v0
    return _from_entries([[cos, -sin, t0], [sin, cos, t1], [*_BOTTOM_ROW]], batch)


def log(T) -> np.ndarray:
    """``Log(T) = [V(ω)⁻¹ t; ω]`` with ``ω = so2.to_angle(R)`` in ``[−π, π]``.

    ``V⁻¹ t = E t − (ω/2) J t`` with ``E = (ω/2)cot(ω/2)``, exact through ``|ω| = π``.
    ``(..., 3, 3) -> (..., 3)``; equals gtsam's ``Pose2.Logmap``.  The bottom row of ``T`` is
    ignored and ``R`` may be slightly off SO(2).
    """
    r, t, batch = _pose_components(T)
    w = np.arctan2(r[2] - r[1], r[0] + r[3])
    e = _half_cot(np.abs(w))
    half = 0.5 * w
    return _from_vector([e * t[0] + half * t[1], e * t[1] - half * t[0], w], batch)


def adjoint(T) -> np.ndarray:
    """``Ad(T) = [[R, [t_y, −t_x]ᵀ], [0, 1]]`` (``(..., 3, 3) -> (..., 3, 3)``, [v; ω] order).

    ``T Exp(δ) T⁻¹ = Exp(Ad(T) δ)``; equals gtsam's ``Pose2.AdjointMap``.
    """
    r, t, batch = _pose_components(T)
    return _from_entries([[r[0], r[1], t[1]], [r[2], r[3], -t[0]], [*_BOTTOM_ROW]], batch)


def ad(xi) -> np.ndarray:
    """Small adjoint ``ad([v; ω]) = [[0, −ω, v_y], [ω, 0, −v_x], [0, 0, 0]]`` (``(..., 3) -> (..., 3, 3)``).

    ``ad(ξ) η`` is the Lie bracket ``[ξ, η]``; equals gtsam's ``Pose2.adjointMap``.
    """
    xi = _as_float(xi)
    _check_last(xi, (3,), "xi")
    out = np.zeros(xi.shape[:-1] + (3, 3), dtype=np.float64)
    out[..., :2, :2] = so2.hat(xi[..., 2:])
    out[..., 0, 2] = xi[..., 1]
    out[..., 1, 2] = -xi[..., 0]
    return out


# ---------------------------------------------------------------------------------------------
# Jacobians of Exp and Log
# ---------------------------------------------------------------------------------------------


def _jacobian_from(v0, v1, w, alpha, beta, gamma, batch) -> np.ndarray:
    """``[[α I + β ω J, ω γ v − β J v], [0, 1]]`` (see the module docstring)."""
    bw = beta * w
    gw = gamma * w
    return _from_entries(
        [[alpha, -bw, gw * v0 + beta * v1], [bw, alpha, gw * v1 - beta * v0], [*_BOTTOM_ROW]], batch
    )


def _exp_jacobian(xi, sign: float) -> np.ndarray:
    """``Jr`` (sign −1) or ``Jl`` (sign +1): ``(α, β, γ) = (A, ±B, C)``."""
    (v0, v1, w), batch = _components(xi, (3,), "xi")
    a, b, c = _exp_coefficients(np.abs(w))
    return _jacobian_from(v0, v1, w, a, sign * b, c, batch)


def _log_jacobian(xi, sign: float) -> np.ndarray:
    """``Jr⁻¹`` (sign +1) or ``Jl⁻¹`` (sign −1): ``(α, β, γ) = (E, ±½, D)``."""
    (v0, v1, w), batch = _components(xi, (3,), "xi")
    e, d = _inverse_jacobian_coefficients(np.abs(w))
    return _jacobian_from(v0, v1, w, e, 0.5 * sign, d, batch)


def right_jacobian(xi) -> np.ndarray:
    """Right Jacobian ``Jr(ξ)`` (``(..., 3) -> (..., 3, 3)``): ``Exp(ξ + δ) ≈ Exp(ξ) Exp(Jr(ξ) δ)``.

    ``[[A I − ω B J, ω C v + B J v], [0, 1]]`` (Solà eq. 163); equals gtsam's ``Pose2.ExpmapDerivative``.
    """
    return _exp_jacobian(xi, -1.0)


def left_jacobian(xi) -> np.ndarray:
    """Left Jacobian ``Jl(ξ) = Jr(−ξ) = Ad(Exp ξ) Jr(ξ)``: ``Exp(ξ + δ) ≈ Exp(Jl(ξ) δ) Exp(ξ)``."""
    return _exp_jacobian(xi, 1.0)


def right_jacobian_inverse(xi) -> np.ndarray:
    """``Jr(ξ)⁻¹ = [[E I + (ω/2) J, ω D v − ½ J v], [0, 1]]`` (``(..., 3) -> (..., 3, 3)``).

    ``Log(X Exp(δ)) ≈ Log(X) + Jr⁻¹(Log X) δ``; equals gtsam's ``Pose2.LogmapDerivative`` at
    ``X = Exp(ξ)``.  Exact through ``|ω| = π``, singular at ``2π``.
    """
    return _log_jacobian(xi, 1.0)


def left_jacobian_inverse(xi) -> np.ndarray:
    """``Jl(ξ)⁻¹ = Jr(−ξ)⁻¹`` (``(..., 3) -> (..., 3, 3)``)."""
    return _log_jacobian(xi, -1.0)


# ---------------------------------------------------------------------------------------------
# Group operations and their Jacobians
# ---------------------------------------------------------------------------------------------


def inverse(T) -> np.ndarray:
    """``T⁻¹ = [[Rᵀ, −Rᵀ t], [0, 1]]`` (``(..., 3, 3)``)."""
    r, t, batch = _pose_components(T)
    rt = [r[0], r[2], r[1], r[3]]
    return _pose_from(rt, [-(rt[0] * t[0] + rt[1] * t[1]), -(rt[2] * t[0] + rt[3] * t[1])], batch)


def compose(a, b) -> np.ndarray:
    """``a · b`` (``(..., 3, 3)``, batch shapes broadcast)."""
    batch = _broadcast_batch((a, (3, 3)), (b, (3, 3)))
    ra, ta, _ = _pose_components(a, batch)
    rb, tb, _ = _pose_components(b, batch)
    r = [ra[2 * i] * rb[j] + ra[2 * i + 1] * rb[2 + j] for i in range(2) for j in range(2)]
    t = [ra[2 * i] * tb[0] + ra[2 * i + 1] * tb[1] + ta[i] for i in range(2)]
    return _pose_from(r, t, batch)


def between(a, b) -> np.ndarray:
    """``a⁻¹ · b = [[Raᵀ Rb, Raᵀ (tb − ta)], [0, 1]]`` (batch shapes broadcast)."""
    batch = _broadcast_batch((a, (3, 3)), (b, (3, 3)))
    ra, ta, _ = _pose_components(a, batch)
    rb, tb, _ = _pose_components(b, batch)
    d = tb - ta
    r = [ra[i] * rb[j] + ra[2 + i] * rb[2 + j] for i in range(2) for j in range(2)]
    t = [ra[i] * d[0] + ra[2 + i] * d[1] for i in range(2)]
    return _pose_from(r, t, batch)


def _entries(T, batch) -> tuple:
    """``(r0, r1, r2, r3, t0, t1)`` of ``T`` ``(*batch, 3, 3)``: 1-D strided views, no copies."""
    flat = np.broadcast_to(_as_float(T), batch + (3, 3)).reshape(-1, 9)
    return flat[:, 0], flat[:, 1], flat[:, 3], flat[:, 4], flat[:, 2], flat[:, 5]


def _between_entries(a, b) -> tuple:
    """The entries of ``a⁻¹ b`` from those of ``a`` and ``b`` (:func:`_entries`), as :func:`between` computes them."""
    d = (b[4] - a[4], b[5] - a[5])
    r = [a[i] * b[j] + a[2 + i] * b[2 + j] for i in range(2) for j in range(2)]
    return (*r, a[0] * d[0] + a[2] * d[1], a[1] * d[0] + a[3] * d[1])


def edge_errors(Z, Xi, Xj) -> tuple[np.ndarray, np.ndarray]:
    """``(Xi⁻¹ Xj (..., 3, 3), Log(Z⁻¹ Xi⁻¹ Xj) (..., 3))``: the relative pose of an edge and its residual.

    Bit for bit ``between(Xi, Xj)`` and ``log(between(Z, ·))`` of it (the same operations), each input
    read once and the relative pose's entries not read back: an edge pass has one fixed cost, not three.
    """
    batch = _broadcast_batch((Z, (3, 3)), (Xi, (3, 3)), (Xj, (3, 3)))
    relative = _between_entries(_entries(Xi, batch), _entries(Xj, batch))
    e = _between_entries(_entries(Z, batch), relative)
    w = np.arctan2(e[2] - e[1], e[0] + e[3])
    coefficient = _half_cot(np.abs(w))
    half = 0.5 * w
    log_e = _from_vector([coefficient * e[4] + half * e[5], coefficient * e[5] - half * e[4], w], batch)
    return _pose_from(relative[:4], relative[4:], batch), log_e


def adjoint_of_inverse(T) -> np.ndarray:
    """``Ad(T⁻¹) = [[Rᵀ, [−(R₀₁ t₀ + R₁₁ t₁), R₀₀ t₀ + R₁₀ t₁]ᵀ], [0, 1]]`` (``(..., 3, 3)``): bit for bit
    ``adjoint(inverse(T))`` in one pass (``∂e/∂δ_i`` of an edge needs ``Ad(X_j⁻¹ X_i)``)."""
    _check_last(_as_float(T), (3, 3), "T")
    batch = np.shape(T)[:-2]
    r0, r1, r2, r3, t0, t1 = _entries(T, batch)
    s0, s1 = -(r0 * t0 + r2 * t1), -(r1 * t0 + r3 * t1)  # Rᵀ t, negated as inverse() does
    return _from_entries([[r0, r2, s1], [r1, r3, -s0], [*_BOTTOM_ROW]], batch)


def act(T, p) -> np.ndarray:
    """``T · p = R p + t`` for points ``p (..., 2)`` (batch shapes broadcast)."""
    batch = _broadcast_batch((T, (3, 3)), (p, (2,)))
    r, t, _ = _pose_components(T, batch)
    pc, _ = _components(np.broadcast_to(_as_float(p), batch + (2,)), (2,), "p")
    return _from_vector([r[2 * i] * pc[0] + r[2 * i + 1] * pc[1] + t[i] for i in range(2)], batch)


def compose_jacobians(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Right Jacobians of ``a · b``: ``(J_ab_a, J_ab_b) = (Ad(b⁻¹), I)``, each ``(..., 3, 3)``.

    ``(a Exp(δ)) b = (a b) Exp(Ad(b⁻¹) δ)``.
    """
    batch = _broadcast_batch((a, (3, 3)), (b, (3, 3)))
    J_a = np.broadcast_to(adjoint(inverse(b)), batch + (3, 3)).copy()
    return J_a, _identity(batch, 3)


def inverse_jacobian(T) -> np.ndarray:
    """Right Jacobian of ``T⁻¹``: ``J_inv_T = −Ad(T)`` (``(..., 3, 3)``): ``(T Exp(δ))⁻¹ = T⁻¹ Exp(−Ad(T) δ)``."""
    return -adjoint(T)


def between_jacobians(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Right Jacobians of ``a⁻¹ · b``: ``(J_ab_a, J_ab_b) = (−Ad(b⁻¹ a), I)``, each ``(..., 3, 3)``.

    Chain rule through ``inverse`` then ``compose``: ``J_ab_a = Ad(b⁻¹) · (−Ad(a)) = −Ad(b⁻¹ a)``.
    """
    batch = _broadcast_batch((a, (3, 3)), (b, (3, 3)))
    J_a = np.broadcast_to(-adjoint(between(b, a)), batch + (3, 3)).copy()
    return J_a, _identity(batch, 3)


def act_jacobians(T, p) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``T · p``: ``J_out_T = [R, R J p]`` ``(..., 2, 3)`` and ``J_out_p = R`` ``(..., 2, 2)``.

    ``(T Exp(δ)) p ≈ T p + R v + ω R J p`` for ``δ = [v; ω]``, with ``J p = [−p_y, p_x]``.
    """
    batch = _broadcast_batch((T, (3, 3)), (p, (2,)))
    r, _, _ = _pose_components(T, batch)
    (p0, p1), _ = _components(np.broadcast_to(_as_float(p), batch + (2,)), (2,), "p")
    rows = [[r[2 * i], r[2 * i + 1], r[2 * i + 1] * p0 - r[2 * i] * p1] for i in range(2)]
    J_T = _from_entries(rows, batch)
    return J_T, np.ascontiguousarray(J_T[..., :2])
