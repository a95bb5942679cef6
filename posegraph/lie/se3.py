"""SE(3): rigid transforms as ``(..., 4, 4)`` matrices, tangent vectors ``ξ = [ω; v]`` as ``(..., 6)``.

Rotation first, as in gtsam's ``Pose3``: ``ξ[..., :3] = ω`` (rotation vector), ``ξ[..., 3:] = v``.
Every function takes any leading batch shape (two-argument functions broadcast them) and works
on the whole batch in one vectorised numpy call (float64).

Conventions (Solà, "A micro Lie theory for state estimation in robotics", 2018, in [ω; v] order):

* ``hat(ξ) = [[ [ω]×, v ], [0, 0]]``; ``Exp(ξ) = [[R, Jl(ω) v], [0, 1]]`` with ``R = so3.exp(ω)``.
* Right perturbations ``T ⊕ δ = T · Exp(δ)``, ``Y ⊖ X = Log(X⁻¹ Y)``.  Each ``J_out_in`` below is
  the right Jacobian ``∂(out ⊖ out₀)/∂δ`` of an output w.r.t. a right perturbation of one
  input, named as in manif.
* ``Ad(T) = [[R, 0], [[t]× R, R]]``, so that ``T Exp(δ) = Exp(Ad(T) δ) T``;
  ``ad(ξ) = [[ [ω]×, 0 ], [ [v]×, [ω]× ]]`` and ``Ad(Exp ξ) = expm(ad ξ)``.
* ``Jr(ξ)``: ``Exp(ξ + δ) ≈ Exp(ξ) Exp(Jr(ξ) δ)``; ``Jl(ξ) = Jr(−ξ) = Ad(Exp ξ) Jr(ξ)``.
  gtsam names: ``Pose3.ExpmapDerivative = Jr``, ``Pose3.LogmapDerivative = Jr⁻¹ ∘ Log``,
  ``Pose3.AdjointMap = Ad``, ``Pose3.adjointMap = ad``.

The four Jacobians share one structure.  ``Jr(ξ) = f(ad ξ)`` for a power series ``f``
(``f(x) = (1 − e⁻ˣ)/x``; ``x/(1 − e⁻ˣ)`` for ``Jr⁻¹``; ``x → −x`` for the left ones), and
``ad ξ`` is block lower-triangular with ``[ω]×`` on the diagonal and ``[v]×`` below it, so::

    f(ad ξ) = [[ F(ω),       0    ],
               [ D_v F(ω),  F(ω)  ]]

where ``F(ω) = f([ω]×)`` is the SO(3) Jacobian and ``D_v F(ω) = d/dε F(ω + ε v)|₀`` is its
directional derivative along ``v``.  With ``F(ω) = α I + β [ω]× + γ ω ωᵀ`` (``α, β, γ`` functions
of ``θ = |ω|``, and ``dθ = s/θ`` for ``s = ω·v``), that derivative — the "Q block" of Barfoot and
Solà — is::

    D_v F = (α'/θ) s I + β [v]× + (β'/θ) s [ω]× + γ (v ωᵀ + ω vᵀ) + (γ'/θ) s ω ωᵀ

``Jr``: ``(α, β, γ) = (A, −B, C)``; ``Jl``: ``(A, B, C)``; ``Jr⁻¹``: ``(E, ½, D)``;
``Jl⁻¹``: ``(E, −½, D)`` (``A … E`` in :mod:`posegraph.lie.so3`).  Expanding Solà's ``Q(ρ, θ)``
with ``[a]×[b]× = b aᵀ − (a·b) I`` gives exactly this; for the inverse the block equals
``−Jr⁻¹(ω) Q Jr⁻¹(ω)`` but needs no matrix product and no division by ``sin θ``.
"""

from __future__ import annotations

import numpy as np

from posegraph.lie import so3
from posegraph.lie.so3 import (
    _as_float,
    _check_last,
    _combine_entries,
    _components,
    _exp_coefficients,
    _from_entries,
    _from_vector,
    _inverse_jacobian_coefficients,
    _jacobian_coefficients,
    _log_components,
    _norm,
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
]

_ZERO3 = (0.0, 0.0, 0.0)


def _pose_components(T, batch=None):
    """``(R entries (9, n) row-major, t (3, n), batch)`` of ``T (..., 4, 4)``, broadcast to ``batch``."""
    T = _as_float(T)
    _check_last(T, (4, 4), "T")
    if batch is not None:
        T = np.broadcast_to(T, batch + (4, 4))
    c, batch = _components(T, (4, 4), "T")
    return c[[0, 1, 2, 4, 5, 6, 8, 9, 10]], c[[3, 7, 11]], batch


def _pose_from(r, t, batch) -> np.ndarray:
    """``(*batch, 4, 4)`` from 9 rotation entries (row-major) and 3 translation components."""
    return _from_entries(
        [[r[0], r[1], r[2], t[0]], [r[3], r[4], r[5], t[1]], [r[6], r[7], r[8], t[2]], [0.0, 0.0, 0.0, 1.0]],
        batch,
    )


def _cross(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _broadcast_batch(*arrays_and_core) -> tuple[int, ...]:
    shapes = []
    for x, core in arrays_and_core:
        x = np.asarray(x)
        _check_last(x, core, "input")
        shapes.append(x.shape[: x.ndim - len(core)])
    return np.broadcast_shapes(*shapes)


# ---------------------------------------------------------------------------------------------
# Construction, hat / vee
# ---------------------------------------------------------------------------------------------


def from_rotation_translation(R, t) -> np.ndarray:
    """``T = [[R, t], [0, 1]]`` from ``R (..., 3, 3)`` and ``t (..., 3)`` (batch shapes broadcast)."""
    R = _as_float(R)
    t = _as_float(t)
    _check_last(R, (3, 3), "R")
    _check_last(t, (3,), "t")
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    out = np.zeros(batch + (4, 4), dtype=np.float64)
    out[..., :3, :3] = R
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def rotation(T) -> np.ndarray:
    """Rotation block ``(..., 3, 3)`` of ``T`` (a view)."""
    T = _as_float(T)
    _check_last(T, (4, 4), "T")
    return T[..., :3, :3]


def translation(T) -> np.ndarray:
    """Translation ``(..., 3)`` of ``T`` (a view)."""
    T = _as_float(T)
    _check_last(T, (4, 4), "T")
    return T[..., :3, 3]


def hat(xi) -> np.ndarray:
    """``hat([ω; v]) = [[ [ω]×, v ], [0, 0]]``: ``(..., 6) -> (..., 4, 4)``."""
    xi = _as_float(xi)
    _check_last(xi, (6,), "xi")
    out = np.zeros(xi.shape[:-1] + (4, 4), dtype=np.float64)
    out[..., :3, :3] = so3.hat(xi[..., :3])
    out[..., :3, 3] = xi[..., 3:]
    return out


def vee(X) -> np.ndarray:
    """Inverse of :func:`hat`: ``(..., 4, 4) -> (..., 6)`` as ``[ω; v]``."""
    X = _as_float(X)
    _check_last(X, (4, 4), "X")
    return np.concatenate([so3.vee(X[..., :3, :3]), X[..., :3, 3]], axis=-1)


# ---------------------------------------------------------------------------------------------
# Exp, Log, adjoints
# ---------------------------------------------------------------------------------------------


def exp(xi) -> np.ndarray:
    """``Exp([ω; v]) = [[Exp(ω), Jl(ω) v], [0, 1]]`` with ``Jl(ω) v = A v + B ω×v + C ω (ω·v)``.

    ``(..., 6) -> (..., 4, 4)``; equals gtsam's ``Pose3.Expmap``.
    """
    c, batch = _components(xi, (6,), "xi")
    w, v = c[:3], c[3:]
    theta_sq = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    a, b, cc = _exp_coefficients(np.sqrt(theta_sq))
    cos = 1.0 - theta_sq * b  # = cos θ, exact in both regimes of B
    R = _combine_entries(cos, a, b, *w)
    wxv = _cross(w, v)
    cs = cc * (w[0] * v[0] + w[1] * v[1] + w[2] * v[2])
    t = [a * v[i] + b * wxv[i] + cs * w[i] for i in range(3)]
    return _from_entries([R[0] + [t[0]], R[1] + [t[1]], R[2] + [t[2]], [0.0, 0.0, 0.0, 1.0]], batch)


def _log_of(r, t, batch) -> np.ndarray:
    """:func:`log` of the pose with rotation entries ``r`` (9, row-major) and translation ``t`` (3)."""
    w = _log_components(r)
    e, d = _inverse_jacobian_coefficients(_norm(*w))
    wxt = _cross(w, t)
    ds = d * (w[0] * t[0] + w[1] * t[1] + w[2] * t[2])
    v = [e * t[i] - 0.5 * wxt[i] + ds * w[i] for i in range(3)]
    return _from_vector([*w, *v], batch)


def log(T) -> np.ndarray:
    """``Log(T) = [ω; Jl(ω)⁻¹ t]`` with ``ω = so3.log(R)`` (θ in ``[0, π]``).

    ``Jl⁻¹(ω) t = E t − ½ ω×t + D ω (ω·t)`` with ``E = (θ/2)cot(θ/2)``, exact through ``θ = π``.
    ``(..., 4, 4) -> (..., 6)``; equals gtsam's ``Pose3.Logmap``.  The bottom row of ``T`` is
    ignored and ``R`` may be slightly off SO(3).
    """
    return _log_of(*_pose_components(T))


def _adjoint_entries(r, t):
    """Rows of ``[[R, 0], [[t]× R, R]]``; row i of ``[t]× R`` is ``(t × R[:, j])_i`` for each column j."""
    r0, r1, r2 = r[0:3], r[3:6], r[6:9]  # rows of R
    tr0 = [t[1] * r2[j] - t[2] * r1[j] for j in range(3)]
    tr1 = [t[2] * r0[j] - t[0] * r2[j] for j in range(3)]
    tr2 = [t[0] * r1[j] - t[1] * r0[j] for j in range(3)]
    return [
        [*r0, *_ZERO3],
        [*r1, *_ZERO3],
        [*r2, *_ZERO3],
        [*tr0, *r0],
        [*tr1, *r1],
        [*tr2, *r2],
    ]


def adjoint(T) -> np.ndarray:
    """``Ad(T) = [[R, 0], [[t]× R, R]]`` (``(..., 4, 4) -> (..., 6, 6)``, [ω; v] order).

    ``T Exp(δ) T⁻¹ = Exp(Ad(T) δ)``; equals gtsam's ``Pose3.AdjointMap``.
    """
    r, t, batch = _pose_components(T)
    return _from_entries(_adjoint_entries(r, t), batch)


def ad(xi) -> np.ndarray:
    """Small adjoint ``ad([ω; v]) = [[ [ω]×, 0 ], [ [v]×, [ω]× ]]`` (``(..., 6) -> (..., 6, 6)``).

    ``ad(ξ) η`` is the Lie bracket ``[ξ, η]``; equals gtsam's ``Pose3.adjointMap``.
    """
    xi = _as_float(xi)
    _check_last(xi, (6,), "xi")
    out = np.zeros(xi.shape[:-1] + (6, 6), dtype=np.float64)
    W = so3.hat(xi[..., :3])
    out[..., :3, :3] = W
    out[..., 3:, 3:] = W
    out[..., 3:, :3] = so3.hat(xi[..., 3:])
    return out


# ---------------------------------------------------------------------------------------------
# Jacobians of Exp and Log
# ---------------------------------------------------------------------------------------------


def _jacobian_from(w, v, alpha, beta, gamma, dalpha, dbeta, dgamma, batch) -> np.ndarray:
    """``[[F, 0], [D_v F, F]]`` for ``F = α I + β [ω]× + γ ω ωᵀ`` (see the module docstring).

    ``dalpha, dbeta, dgamma`` are the θ-derivatives divided by θ; ``dbeta`` may be ``None`` (β constant).
    """
    F = _combine_entries(alpha, beta, gamma, *w)
    s = w[0] * v[0] + w[1] * v[1] + w[2] * v[2]
    # γ (v ωᵀ + ω vᵀ) + (γ'/θ) s ω ωᵀ = m ωᵀ + ω mᵀ with m = γ v + ½ (γ'/θ) s ω.
    half_dgs = 0.5 * dgamma * s
    m = [gamma * v[i] + half_dgs * w[i] for i in range(3)]
    # β [v]× + (β'/θ) s [ω]× = [u]× with u = β v + (β'/θ) s ω.
    if dbeta is None:
        u = [beta * v[i] for i in range(3)]
    else:
        dbs = dbeta * s
        u = [beta * v[i] + dbs * w[i] for i in range(3)]
    das = dalpha * s
    p01 = m[0] * w[1] + w[0] * m[1]
    p02 = m[0] * w[2] + w[0] * m[2]
    p12 = m[1] * w[2] + w[1] * m[2]
    L = [
        [2.0 * m[0] * w[0] + das, p01 - u[2], p02 + u[1]],
        [p01 + u[2], 2.0 * m[1] * w[1] + das, p12 - u[0]],
        [p02 - u[1], p12 + u[0], 2.0 * m[2] * w[2] + das],
    ]
    return _from_entries([F[0] + [*_ZERO3], F[1] + [*_ZERO3], F[2] + [*_ZERO3], L[0] + F[0], L[1] + F[1], L[2] + F[2]], batch)


def right_jacobian(xi) -> np.ndarray:
    """Right Jacobian ``Jr(ξ)`` (``(..., 6) -> (..., 6, 6)``): ``Exp(ξ + δ) ≈ Exp(ξ) Exp(Jr(ξ) δ)``.

    ``[[Jr(ω), 0], [D_v Jr(ω), Jr(ω)]]`` (module docstring); equals gtsam's ``Pose3.ExpmapDerivative``.
    """
    c, batch = _components(xi, (6,), "xi")
    w, v = c[:3], c[3:]
    a, b, cc, da, db, dc = _jacobian_coefficients(_norm(*w))
    return _jacobian_from(w, v, a, -b, cc, da, -db, dc, batch)


def left_jacobian(xi) -> np.ndarray:
    """Left Jacobian ``Jl(ξ) = Jr(−ξ) = Ad(Exp ξ) Jr(ξ)``: ``Exp(ξ + δ) ≈ Exp(Jl(ξ) δ) Exp(ξ)``."""
    c, batch = _components(xi, (6,), "xi")
    w, v = c[:3], c[3:]
    a, b, cc, da, db, dc = _jacobian_coefficients(_norm(*w))
    return _jacobian_from(w, v, a, b, cc, da, db, dc, batch)


def right_jacobian_inverse(xi) -> np.ndarray:
    """``Jr(ξ)⁻¹ = [[Jr⁻¹(ω), 0], [D_v Jr⁻¹(ω), Jr⁻¹(ω)]]`` (``(..., 6) -> (..., 6, 6)``).

    ``D_v Jr⁻¹(ω) = (E'/θ) s I + ½ [v]× + D (v ωᵀ + ω vᵀ) + (D'/θ) s ω ωᵀ`` with ``s = ω·v``; it
    equals ``−Jr⁻¹(ω) Q Jr⁻¹(ω)``.  ``Log(X Exp(δ)) ≈ Log(X) + Jr⁻¹(Log X) δ``; equals gtsam's
    ``Pose3.LogmapDerivative`` at ``X = Exp(ξ)``.  Exact through ``|ω| = π``, singular at ``2π``.
    """
    c, batch = _components(xi, (6,), "xi")
    w, v = c[:3], c[3:]
    e, d, de, dd = _inverse_jacobian_coefficients(_norm(*w), derivatives=True)
    return _jacobian_from(w, v, e, 0.5, d, de, None, dd, batch)


def left_jacobian_inverse(xi) -> np.ndarray:
    """``Jl(ξ)⁻¹ = Jr(−ξ)⁻¹`` (``(..., 6) -> (..., 6, 6)``)."""
    c, batch = _components(xi, (6,), "xi")
    w, v = c[:3], c[3:]
    e, d, de, dd = _inverse_jacobian_coefficients(_norm(*w), derivatives=True)
    return _jacobian_from(w, v, e, -0.5, d, de, None, dd, batch)


# ---------------------------------------------------------------------------------------------
# Group operations and their Jacobians
# ---------------------------------------------------------------------------------------------


def inverse(T) -> np.ndarray:
    """``T⁻¹ = [[Rᵀ, −Rᵀ t], [0, 1]]`` (``(..., 4, 4)``)."""
    r, t, batch = _pose_components(T)
    rt = [r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]]
    minus_rt_t = [-(rt[3 * i] * t[0] + rt[3 * i + 1] * t[1] + rt[3 * i + 2] * t[2]) for i in range(3)]
    return _pose_from(rt, minus_rt_t, batch)


def _product(ra, ta, rb, tb):
    """Entries of ``(Ra, ta) · (Rb, tb)``: ``Ra Rb`` and ``Ra tb + ta``."""
    r = [ra[3 * i] * rb[j] + ra[3 * i + 1] * rb[3 + j] + ra[3 * i + 2] * rb[6 + j] for i in range(3) for j in range(3)]
    t = [ra[3 * i] * tb[0] + ra[3 * i + 1] * tb[1] + ra[3 * i + 2] * tb[2] + ta[i] for i in range(3)]
    return r, t


def compose(a, b) -> np.ndarray:
    """``a · b`` (``(..., 4, 4)``, batch shapes broadcast)."""
    batch = _broadcast_batch((a, (4, 4)), (b, (4, 4)))
    ra, ta, _ = _pose_components(a, batch)
    rb, tb, _ = _pose_components(b, batch)
    return _pose_from(*_product(ra, ta, rb, tb), batch)


def _between_entries(ra, ta, rb, tb):
    """Entries ``(r (9), t (3))`` of ``a⁻¹ b``: ``Raᵀ Rb`` and ``Raᵀ (tb − ta)``."""
    d = [tb[i] - ta[i] for i in range(3)]
    r = [ra[i] * rb[j] + ra[3 + i] * rb[3 + j] + ra[6 + i] * rb[6 + j] for i in range(3) for j in range(3)]
    t = [ra[i] * d[0] + ra[3 + i] * d[1] + ra[6 + i] * d[2] for i in range(3)]
    return r, t


def between(a, b) -> np.ndarray:
    """``a⁻¹ · b = [[Raᵀ Rb, Raᵀ (tb − ta)], [0, 1]]`` (batch shapes broadcast)."""
    batch = _broadcast_batch((a, (4, 4)), (b, (4, 4)))
    ra, ta, _ = _pose_components(a, batch)
    rb, tb, _ = _pose_components(b, batch)
    return _pose_from(*_between_entries(ra, ta, rb, tb), batch)


def edge_errors(Z, Xi, Xj) -> tuple[np.ndarray, np.ndarray]:
    """``(Xi⁻¹ Xj (..., 4, 4), Log(Z⁻¹ Xi⁻¹ Xj) (..., 6))``: the relative pose of an edge and its residual.

    Bit for bit ``between(Xi, Xj)`` and ``log(between(Z, ·))`` of it (the same operations), each input
    read once and the relative pose's entries not read back from the matrix it is returned as.
    """
    batch = _broadcast_batch((Z, (4, 4)), (Xi, (4, 4)), (Xj, (4, 4)))
    r, t = _between_entries(*_pose_components(Xi, batch)[:2], *_pose_components(Xj, batch)[:2])
    rz, tz, _ = _pose_components(Z, batch)
    return _pose_from(r, t, batch), _log_of(*_between_entries(rz, tz, r, t), batch)


def adjoint_of_inverse(T) -> np.ndarray:
    """``Ad(T⁻¹) = [[Rᵀ, 0], [−Rᵀ [t]×, Rᵀ]]`` (``(..., 4, 4) -> (..., 6, 6)``): bit for bit
    ``adjoint(inverse(T))`` in one pass (``∂e/∂δ_i`` of an edge needs ``Ad(X_j⁻¹ X_i)``)."""
    r, t, batch = _pose_components(T)
    rt = [r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]]
    minus_rt_t = [-(rt[3 * i] * t[0] + rt[3 * i + 1] * t[1] + rt[3 * i + 2] * t[2]) for i in range(3)]
    return _from_entries(_adjoint_entries(rt, minus_rt_t), batch)


def act(T, p) -> np.ndarray:
    """``T · p = R p + t`` for points ``p (..., 3)`` (batch shapes broadcast)."""
    batch = _broadcast_batch((T, (4, 4)), (p, (3,)))
    r, t, _ = _pose_components(T, batch)
    pc, _ = _components(np.broadcast_to(_as_float(p), batch + (3,)), (3,), "p")
    return _from_vector([r[3 * i] * pc[0] + r[3 * i + 1] * pc[1] + r[3 * i + 2] * pc[2] + t[i] for i in range(3)], batch)


def _identity(batch: tuple[int, ...], n: int) -> np.ndarray:
    return np.broadcast_to(np.eye(n), batch + (n, n)).copy()


def compose_jacobians(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Right Jacobians of ``a · b``: ``(J_ab_a, J_ab_b) = (Ad(b⁻¹), I)``, each ``(..., 6, 6)``.

    ``(a Exp(δ)) b = (a b) Exp(Ad(b⁻¹) δ)``.
    """
    batch = _broadcast_batch((a, (4, 4)), (b, (4, 4)))
    J_a = np.broadcast_to(adjoint(inverse(b)), batch + (6, 6)).copy()
    return J_a, _identity(batch, 6)


def inverse_jacobian(T) -> np.ndarray:
    """Right Jacobian of ``T⁻¹``: ``J_inv_T = −Ad(T)`` (``(..., 6, 6)``): ``(T Exp(δ))⁻¹ = T⁻¹ Exp(−Ad(T) δ)``."""
    return -adjoint(T)


def between_jacobians(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Right Jacobians of ``a⁻¹ · b``: ``(J_ab_a, J_ab_b) = (−Ad(b⁻¹ a), I)``, each ``(..., 6, 6)``.

    Chain rule through ``inverse`` then ``compose``:
    ``J_ab_a = Ad(b⁻¹) · (−Ad(a)) = −Ad(b⁻¹ a)``.
    """
    batch = _broadcast_batch((a, (4, 4)), (b, (4, 4)))
    J_a = np.broadcast_to(-adjoint(between(b, a)), batch + (6, 6)).copy()
    return J_a, _identity(batch, 6)


def act_jacobians(T, p) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``T · p``: ``J_out_T = [−R [p]×, R]`` ``(..., 3, 6)`` and ``J_out_p = R`` ``(..., 3, 3)``.

    ``(T Exp(δ)) p ≈ T p + R (ω × p) + R v`` for ``δ = [ω; v]``, and ``ω × p = −[p]× ω``.
    """
    batch = _broadcast_batch((T, (4, 4)), (p, (3,)))
    r, _, _ = _pose_components(T, batch)
    (p0, p1, p2), _ = _components(np.broadcast_to(_as_float(p), batch + (3,)), (3,), "p")
    rows = []
    for i in range(3):
        ri0, ri1, ri2 = r[3 * i], r[3 * i + 1], r[3 * i + 2]
        # row i of −R [p]×: (R_i2 p1 − R_i1 p2, R_i0 p2 − R_i2 p0, R_i1 p0 − R_i0 p1)
        rows.append([ri2 * p1 - ri1 * p2, ri0 * p2 - ri2 * p0, ri1 * p0 - ri0 * p1, ri0, ri1, ri2])
    J_T = _from_entries(rows, batch)
    return J_T, np.ascontiguousarray(J_T[..., 3:])
