"""Sim(3): similarities ``p ↦ s R p + t`` as ``(..., 4, 4)`` matrices, tangents ``ξ = [ω; υ; λ]`` as ``(..., 7)``.

Matrix form and tangent order
-----------------------------
An element is ``S = [[s R, t], [0, 1]]`` with ``R ∈ SO(3)``, ``t ∈ R³``, scale ``s > 0``; products
of these matrices are compositions of similarities (``S₁ S₂ = [[s₁s₂ R₁R₂, s₁R₁t₂ + t₁], [0, 1]]``,
as g2o's ``Sim3::operator*``).  The tangent is rotation first, then translation, then the
log-scale ``λ = log s``: ``ξ[..., :3] = ω``, ``ξ[..., 3:6] = υ``, ``ξ[..., 6] = λ`` — the order of
gtsam's ``Similarity3`` and of g2o's ``Sim3(Vector7)`` (``[ω, υ, σ]``), so Ω read from g2o needs
no permutation.  ``hat(ξ) = [[ [ω]× + λ I, υ ], [0, 0]]``; every function takes any leading batch
shape and never loops over it in Python.  Conventions as :mod:`posegraph.lie.se3`: right
perturbations ``S ⊕ δ = S·Exp(δ)``, right Jacobians named ``J_out_in``.

gtsam's ``Similarity3(R, t, s)`` is the matrix ``G = [[R, t], [0, 1/s]]``, acting as
``p ↦ s (R p + t)``.  Its projective normalisation ``s·G = [[s R, s t], [0, 1]]`` is this
module's matrix, and it is a group isomorphism.  Because ``exp(A + λI) = e^λ exp(A)``, gtsam's
hat ``[[ [ω]×, υ ], [0, −λ]]`` and this module's differ by ``λ I₄``: the same 7-vector ``[ω; υ; λ]``
is the tangent of corresponding elements, so ``Expmap``, ``Logmap`` and ``AdjointMap`` agree
entry for entry once gtsam's ``(R, t, s)`` is mapped to ``(s R, s t)``.

Exp and the V matrix
--------------------
``Exp(ξ) = [[e^λ Exp(ω), V(ω, λ) υ], [0, 1]]`` where, from the series of ``exp(hat ξ)``,
``V = Σₖ (W + λ I)ᵏ / (k+1)! = ∫₀¹ e^{λτ} Exp(τ ω) dτ`` (``W = [ω]×``).  Rodrigues'
``Exp(τω) = I + sin(τθ)/θ W + (1 − cos τθ)/θ² W²`` under the integral gives::

    V = a I + b W + c W²,
    a = ∫₀¹ e^{λτ} dτ                     = (e^λ − 1)/λ
    b = ∫₀¹ e^{λτ} sin(θτ)/θ dτ           = [s λ A + s θ² B − (s − 1)] / (λ² + θ²)
    c = ∫₀¹ e^{λτ} (1 − cos θτ)/θ² dτ     = [s λ² B + (s − 1) − s λ A] / (λ (λ² + θ²))

(``s = e^λ``; ``A = sin θ/θ``, ``B = (1 − cos θ)/θ²`` from :mod:`posegraph.lie.so3`, which carry
their own Taylor branch for θ → 0; integrate ``e^{λτ} e^{iθτ}`` and take real and imaginary
parts).  At ``λ = 0`` they are SO(3)'s ``(1, B, C)`` (the SE(3) V), at ``θ = 0``
``(a, ∫τe^{λτ}, ½∫τ²e^{λτ})``.  Numerics, by regime:

* θ → 0 alone (``|λ| ≥ _SERIES_RADIUS``): the closed forms above never divide by θ; ``A``, ``B``
  are so3's Taylor polynomials below its ``_SERIES_ANGLE``.  The numerators of ``b`` and ``c``
  are ``O(|z|²)`` and ``O(λ|z|²)`` (``z = λ + iθ``) out of terms ``O(|z|)``, ``O(λ)``: at
  ``|z| ≥ _SERIES_RADIUS`` that cancellation costs under two digits.
* λ → 0 alone (``θ ≥ _SERIES_RADIUS``): ``a = expm1(λ)/λ`` is exact for every λ ≠ 0; ``c``'s
  numerator is ``λ(1 − A) + O(λ²)`` computed from terms of size ``λ``, so it too is exact down to
  the smallest λ.  Only ``λ = 0`` itself is 0/0: there ``a = 1``, ``c = C(θ)`` are substituted
  (``np.where`` with a safe divisor, so the unused branch never divides by zero).
* Both small (``|z| = √(λ² + θ²) < _SERIES_RADIUS``): the double Taylor series
  ``b = Σ λʲ (−θ²)ᵏ / (j! (2k+1)! (j+2k+2))``, ``c = Σ λʲ (−θ²)ᵏ / (j! (2k+2)! (j+2k+3))``
  (expand ``e^{λτ}`` and the Rodrigues ratios in τ, integrate each monomial), truncated at
  ``j + 2k ≤ _SERIES_ORDER``: the first term left out is below ``0.7²¹/21! ≈ 1e-23``.

Log and V⁻¹
-----------
``Log(S) = [ω; V⁻¹ t; λ]`` with ``s = det(sR)^{1/3}``, ``λ = log s``, ``ω = so3.log(sR/s)`` (via
the quaternion: the axis near θ = π comes from the symmetric part of R, never from ``1/sin θ``).
``V⁻¹`` lies in the same algebra ``{I, W, W²}`` (``W³ = −θ² W``)::

    V⁻¹ = I/a − (b/D) W + (b² − p c)/(a D) W²,    p = a − θ² c,   D = p² + θ² b²

(multiply out and match coefficients).  ``p ± iθb`` are V's eigenvalues off the axis,
``(e^{λ±iθ} − 1)/(λ ± iθ)``, so ``D > 0`` up to ``θ = 2π`` at ``λ = 0``: exact through ``θ = π``,
where ``p = 0`` at ``λ = 0`` and the coefficients are SE(3)'s ``(1, −½, 1/π²)``.

Adjoints and Jacobians
----------------------
``Ad(S) = [[R, 0, 0], [[t]× R, s R, −t], [0, 0, 1]]`` (``S Exp(δ) S⁻¹ = Exp(Ad(S) δ)``), and
``ad(ξ) = [[ [ω]×, 0, 0 ], [ [υ]×, [ω]× + λ I, −υ ], [0, 0, 0]]``.  The right Jacobian is
``Jr(ξ) = Σ (−ad ξ)ᵏ/(k+1)! = ∫₀¹ Ad(Exp(−τ ξ)) dτ``: its blocks ``∫R = Jr_SO3(ω)`` and
``∫ s R = V(−ω, −λ)`` are closed forms above, and the remaining ``∫[t]×R`` and ``∫t`` are
integrated by Gauss–Legendre with :data:`QUADRATURE_NODES` nodes — the integrand is entire in τ,
and the rule's error ``(N!)⁴/((2N+1)((2N)!)³)·max|f⁽²ᴺ⁾|`` is below 1e-18 for ``|ad ξ| ≤ 4``
(θ ≤ π, |λ| ≤ 2.4) with N = 10.  ``Jr`` is block lower-triangular in the order (ω | υ, λ), so
``Jr⁻¹`` follows by block elimination with ``Jr_SO3(ω)⁻¹`` and ``V(−ω, −λ)⁻¹`` (both closed
forms), never a general 7×7 inverse.  ``Jl(ξ) = Jr(−ξ)``.
"""

from __future__ import annotations

import math

import numpy as np

from posegraph.lie import so3
from posegraph.lie.so3 import _as_float, _check_last, _closed_abc, _exp_coefficients

__all__ = [
    "hat", "vee", "exp", "log", "adjoint", "ad", "right_jacobian", "right_jacobian_inverse", "left_jacobian",
    "left_jacobian_inverse", "inverse", "compose", "between", "act", "from_rotation_translation_scale",
    "rotation", "translation", "scale", "compose_jacobians", "inverse_jacobian", "between_jacobians",
    "act_jacobians", "v_coefficients", "g2o_exp", "g2o_exp_inverse", "g2o_log",
]  # fmt: skip

_SERIES_RADIUS = 0.7
"""``|z| = √(λ² + θ²)`` below which V's ``b, c`` are the double Taylor series (module docstring)."""
_SERIES_ORDER = 20
"""Highest total degree ``j + 2k`` kept in the double series (the first left out is below 0.7²¹/21! ≈ 1e-23)."""
_LAMBDA_NEGLIGIBLE = 1e-150
"""Outside the series' radius, ``|λ|`` below which ``c = C(θ)`` exactly as at λ = 0: the closed form's
numerator (~λ) and divisor (λ·z²) would reach the subnormal range and lose their bits (λ = 5e-324
gave c off by 25 %), while ``c − C(θ)`` is O(λ), far below round-off."""
QUADRATURE_NODES = 10
"""Gauss–Legendre nodes for the Jacobian blocks ``∫[t(τ)]× R(τ) dτ`` and ``∫t(τ) dτ``."""


def _series_table(extra: int, rotation_factorial_offset: int) -> np.ndarray:
    """``(J, K)`` coefficients ``1/(j! (2k+o)! (j+2k+extra))`` (zero above the total degree)."""
    K = _SERIES_ORDER // 2 + 1
    table = np.zeros((_SERIES_ORDER + 1, K))
    for j in range(_SERIES_ORDER + 1):
        for k in range(K):
            if j + 2 * k <= _SERIES_ORDER:
                denominator = math.factorial(j) * math.factorial(2 * k + rotation_factorial_offset) * (j + 2 * k + extra)
                table[j, k] = (-1) ** k / denominator
    return table


_B_TABLE = _series_table(2, 1)
_C_TABLE = _series_table(3, 2)


_BC_TABLE = np.concatenate([_B_TABLE, _C_TABLE], axis=1)  # (J, 2K): b's columns, then c's


def _series_bc(theta_sq: np.ndarray, lam: np.ndarray):
    """The double series of ``b, c`` by Horner's rule: in λ for every power of θ² at once, then in θ²."""
    in_lam = np.broadcast_to(_BC_TABLE[-1], (lam.shape[0], _BC_TABLE.shape[1])).copy()
    column = lam[:, None]
    for row in _BC_TABLE[-2::-1]:
        in_lam *= column
        in_lam += row
    K = _B_TABLE.shape[1]
    b, c = in_lam[:, K - 1].copy(), in_lam[:, 2 * K - 1].copy()
    for k in range(K - 2, -1, -1):
        b *= theta_sq
        b += in_lam[:, k]
        c *= theta_sq
        c += in_lam[:, K + k]
    return b, c


def _closed_bc(theta: np.ndarray, lam: np.ndarray):
    A, B, C = _exp_coefficients(theta)
    s = np.exp(lam)
    s_minus_one = np.expm1(lam)
    theta_sq = theta * theta
    z_sq = lam * lam + theta_sq
    b = (s * lam * A + s * theta_sq * B - s_minus_one) / z_sq
    zero = np.abs(lam) < _LAMBDA_NEGLIGIBLE
    c = (s * lam * lam * B + s_minus_one - s * lam * A) / np.where(zero, 1.0, lam * z_sq)
    return b, np.where(zero, C, c)


def v_coefficients(theta, lam):
    """``(a, b, c)`` of ``V(ω, λ) = a I + b [ω]× + c [ω]×²`` for ``θ = |ω|`` and λ (1-D arrays, module docstring)."""
    theta = np.asarray(theta, dtype=np.float64)
    lam = np.asarray(lam, dtype=np.float64)
    zero = lam == 0.0
    a = np.where(zero, 1.0, np.expm1(lam) / np.where(zero, 1.0, lam))
    small = theta * theta + lam * lam < _SERIES_RADIUS**2
    b = np.empty_like(theta)
    c = np.empty_like(theta)
    if small.any():
        b[small], c[small] = _series_bc(theta[small] ** 2, lam[small])
    if (~small).any():
        b[~small], c[~small] = _closed_bc(theta[~small], lam[~small])
    return a, b, c


def _v_inverse_coefficients(a, b, c, theta_sq):
    """``(x, y, z)`` with ``V⁻¹ = x I + y W + z W²`` (module docstring)."""
    p = a - theta_sq * c
    D = p * p + theta_sq * b * b
    return 1.0 / a, -b / D, (b * b - p * c) / (a * D)


def _flat(x, core: tuple[int, ...], name: str):
    """``(x reshaped to (n, *core), batch)``."""
    x = _as_float(x)
    _check_last(x, core, name)
    batch = x.shape[: x.ndim - len(core)]
    return x.reshape((-1,) + core), batch


def _combine(alpha, beta, gamma, w) -> np.ndarray:
    """``(n, 3, 3)``: ``α I + β [w]× + γ [w]×²`` for coefficient arrays ``(n,)`` and ``w (n, 3)``."""
    W = so3.hat(w)
    return alpha[:, None, None] * np.eye(3) + beta[:, None, None] * W + gamma[:, None, None] * (W @ W)


def _v_matrix(w: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """``V(ω, λ)`` ``(n, 3, 3)`` for ``w (n, 3)``, ``lam (n,)``."""
    return _combine(*v_coefficients(np.linalg.norm(w, axis=-1), lam), w)


def _v_inverse(w: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """``V(ω, λ)⁻¹`` ``(n, 3, 3)``."""
    theta = np.linalg.norm(w, axis=-1)
    return _combine(*_v_inverse_coefficients(*v_coefficients(theta, lam), theta * theta), w)


def _assemble(M: np.ndarray, t: np.ndarray, batch) -> np.ndarray:
    out = np.zeros((M.shape[0], 4, 4))
    out[:, :3, :3] = M
    out[:, :3, 3] = t
    out[:, 3, 3] = 1.0
    return out.reshape(batch + (4, 4))


def _split(S, batch=None):
    """``(R (n,3,3), t (n,3), s (n,), batch)`` of ``S (..., 4, 4)``, broadcast to ``batch`` if given."""
    S = _as_float(S)
    _check_last(S, (4, 4), "S")
    if batch is not None:
        S = np.broadcast_to(S, batch + (4, 4))
    flat, batch = _flat(S, (4, 4), "S")
    M = flat[:, :3, :3]
    s = np.cbrt(np.linalg.det(M))
    return M / s[:, None, None], flat[:, :3, 3], s, batch


def _broadcast(*pairs) -> tuple[int, ...]:
    shapes = []
    for x, core in pairs:
        x = np.asarray(x)
        _check_last(x, core, "input")
        shapes.append(x.shape[: x.ndim - len(core)])
    return np.broadcast_shapes(*shapes)


# --- construction, hat / vee -----------------------------------------------------------------


def from_rotation_translation_scale(R, t, s) -> np.ndarray:
    """``S = [[s R, t], [0, 1]]`` from ``R (..., 3, 3)``, ``t (..., 3)``, ``s (...)`` (batch shapes broadcast)."""
    R, t, s = _as_float(R), _as_float(t), _as_float(s)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1], s.shape)
    out = np.zeros(batch + (4, 4))
    out[..., :3, :3] = s[..., None, None] * R
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def scale(S) -> np.ndarray:
    """Scale ``s = det(s R)^{1/3}`` ``(...)`` of ``S``."""
    S = _as_float(S)
    _check_last(S, (4, 4), "S")
    return np.cbrt(np.linalg.det(S[..., :3, :3]))


def rotation(S) -> np.ndarray:
    """Rotation ``R = (s R)/s`` ``(..., 3, 3)`` of ``S``."""
    S = _as_float(S)
    return S[..., :3, :3] / scale(S)[..., None, None]


def translation(S) -> np.ndarray:
    """Translation ``t`` ``(..., 3)`` of ``S`` (a view)."""
    S = _as_float(S)
    _check_last(S, (4, 4), "S")
    return S[..., :3, 3]


def hat(xi) -> np.ndarray:
    """``hat([ω; υ; λ]) = [[ [ω]× + λ I, υ ], [0, 0]]``: ``(..., 7) -> (..., 4, 4)``."""
    xi = _as_float(xi)
    _check_last(xi, (7,), "xi")
    out = np.zeros(xi.shape[:-1] + (4, 4))
    out[..., :3, :3] = so3.hat(xi[..., :3]) + xi[..., 6, None, None] * np.eye(3)
    out[..., :3, 3] = xi[..., 3:6]
    return out


def vee(X) -> np.ndarray:
    """Inverse of :func:`hat`: ``(..., 4, 4) -> (..., 7)``; ω from the skew part, λ the mean of the diagonal.

    The mean is taken as ``X₀₀ + ((X₁₁ − X₀₀) + (X₂₂ − X₀₀))/3``, exact when the diagonal is ``λ I``.
    """
    X = _as_float(X)
    _check_last(X, (4, 4), "X")
    first = X[..., 0, 0]
    lam = first + ((X[..., 1, 1] - first) + (X[..., 2, 2] - first)) / 3.0
    return np.concatenate([so3.vee(X[..., :3, :3]), X[..., :3, 3], lam[..., None]], axis=-1)


# --- Exp, Log, adjoints ----------------------------------------------------------------------


def exp(xi) -> np.ndarray:
    """``Exp([ω; υ; λ]) = [[e^λ Exp(ω), V(ω, λ) υ], [0, 1]]`` (``(..., 7) -> (..., 4, 4)``).

    Equals gtsam's ``Similarity3.Expmap`` mapped as in the module docstring.
    """
    x, batch = _flat(xi, (7,), "xi")
    w, u, lam = x[:, :3], x[:, 3:6], x[:, 6]
    t = (_v_matrix(w, lam) @ u[:, :, None])[:, :, 0]
    return _assemble(np.exp(lam)[:, None, None] * so3.exp(w), t, batch)


def log(S) -> np.ndarray:
    """``Log(S) = [ω; V(ω, λ)⁻¹ t; λ]``, ``λ = log s``, ``ω = so3.log(R)`` with θ in ``[0, π]``.

    ``(..., 4, 4) -> (..., 7)``; the bottom row is ignored; equals gtsam's ``Similarity3.Logmap``.
    """
    R, t, s, batch = _split(S)
    w = so3.log(R)
    lam = np.log(s)
    u = (_v_inverse(w, lam) @ t[:, :, None])[:, :, 0]
    return np.concatenate([w, u, lam[:, None]], axis=-1).reshape(batch + (7,))


def _adjoint_flat(R, t, s) -> np.ndarray:
    out = np.zeros((R.shape[0], 7, 7))
    out[:, :3, :3] = R
    out[:, 3:6, :3] = so3.hat(t) @ R
    out[:, 3:6, 3:6] = s[:, None, None] * R
    out[:, 3:6, 6] = -t
    out[:, 6, 6] = 1.0
    return out


def adjoint(S) -> np.ndarray:
    """``Ad(S) = [[R, 0, 0], [[t]× R, s R, −t], [0, 0, 1]]`` (``(..., 4, 4) -> (..., 7, 7)``).

    ``S Exp(δ) S⁻¹ = Exp(Ad(S) δ)``; equals gtsam's ``Similarity3.AdjointMap``.
    """
    R, t, s, batch = _split(S)
    return _adjoint_flat(R, t, s).reshape(batch + (7, 7))


def ad(xi) -> np.ndarray:
    """``ad([ω; υ; λ]) = [[ [ω]×, 0, 0 ], [ [υ]×, [ω]× + λ I, −υ ], [0, 0, 0]]`` (``(..., 7) -> (..., 7, 7)``).

    ``ad(ξ) η = vee([hat ξ, hat η])``, the Lie bracket.
    """
    xi = _as_float(xi)
    _check_last(xi, (7,), "xi")
    out = np.zeros(xi.shape[:-1] + (7, 7))
    W = so3.hat(xi[..., :3])
    out[..., :3, :3] = W
    out[..., 3:6, :3] = so3.hat(xi[..., 3:6])
    out[..., 3:6, 3:6] = W + xi[..., 6, None, None] * np.eye(3)
    out[..., 3:6, 6] = -xi[..., 3:6]
    return out


# --- Jacobians of Exp and Log ----------------------------------------------------------------

def _gauss_legendre(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the ``count``-point Gauss–Legendre rule on [0, 1] (Golub–Welsch: the
    eigenvalues of the Jacobi matrix of the Legendre recurrence, ``β_k = k/√(4k² − 1)``, and twice
    the squared first components of its eigenvectors), without importing ``numpy.polynomial``."""
    k = np.arange(1, count)
    beta = k / np.sqrt(4.0 * k * k - 1.0)
    nodes, vectors = np.linalg.eigh(np.diag(beta, 1) + np.diag(beta, -1))
    return 0.5 * (nodes + 1.0), vectors[0] ** 2  # weights 2 v₀², halved with the interval


_TAU, _TAU_WEIGHTS = _gauss_legendre(QUADRATURE_NODES)  # on [0, 1]


def _right_jacobian_blocks(x: np.ndarray):
    """``(Jr_SO3(ω), X, V(−ω, −λ), y)``: ``Jr(ξ) = [[Jr_SO3, 0, 0], [X, V(−ω,−λ), −y], [0, 0, 1]]``.

    ``X = ∫₀¹ [t(τ)]× R(τ) dτ`` and ``y = ∫₀¹ t(τ) dτ`` for ``Exp(−τξ) = (e^{−τλ}R(τ), t(τ))``, by
    Gauss–Legendre over the nodes (one batched :func:`exp` of all of them).
    """
    E = exp(-_TAU[:, None, None] * x[None])  # (q, n, 4, 4)
    t = E[..., :3, 3]
    R = E[..., :3, :3] * np.exp(_TAU[:, None] * x[None, :, 6])[..., None, None]
    X = np.einsum("q,qnij->nij", _TAU_WEIGHTS, so3.hat(t) @ R)
    y = np.einsum("q,qni->ni", _TAU_WEIGHTS, t)
    w, lam = x[:, :3], x[:, 6]
    return so3.right_jacobian(w), X, _v_matrix(-w, -lam), y


def _jacobian_from_blocks(J_w, X, V, y, batch) -> np.ndarray:
    out = np.zeros((J_w.shape[0], 7, 7))
    out[:, :3, :3] = J_w
    out[:, 3:6, :3] = X
    out[:, 3:6, 3:6] = V
    out[:, 3:6, 6] = -y
    out[:, 6, 6] = 1.0
    return out.reshape(batch + (7, 7))


def _inverse_from_blocks(x: np.ndarray, batch) -> np.ndarray:
    """``Jr⁻¹`` by block elimination: ``[[Jw⁻¹, 0, 0], [−V⁻¹ X Jw⁻¹, V⁻¹, V⁻¹ y], [0, 0, 1]]``."""
    _, X, _, y = _right_jacobian_blocks(x)
    w, lam = x[:, :3], x[:, 6]
    J_w_inv = so3.right_jacobian_inverse(w)
    V_inv = _v_inverse(-w, -lam)
    return _jacobian_from_blocks(J_w_inv, -V_inv @ X @ J_w_inv, V_inv, -(V_inv @ y[:, :, None])[:, :, 0], batch)


def right_jacobian(xi) -> np.ndarray:
    """``Jr(ξ) = ∫₀¹ Ad(Exp(−τξ)) dτ`` (``(..., 7) -> (..., 7, 7)``): ``Exp(ξ + δ) ≈ Exp(ξ) Exp(Jr(ξ) δ)``."""
    x, batch = _flat(xi, (7,), "xi")
    return _jacobian_from_blocks(*_right_jacobian_blocks(x), batch)


def left_jacobian(xi) -> np.ndarray:
    """``Jl(ξ) = Jr(−ξ)``: ``Exp(ξ + δ) ≈ Exp(Jl(ξ) δ) Exp(ξ)``."""
    return right_jacobian(-_as_float(xi))


def right_jacobian_inverse(xi) -> np.ndarray:
    """``Jr(ξ)⁻¹`` (``(..., 7) -> (..., 7, 7)``): ``Log(S Exp(δ)) ≈ Log(S) + Jr⁻¹(Log S) δ``."""
    x, batch = _flat(xi, (7,), "xi")
    return _inverse_from_blocks(x, batch)


def left_jacobian_inverse(xi) -> np.ndarray:
    """``Jl(ξ)⁻¹ = Jr(−ξ)⁻¹``."""
    return right_jacobian_inverse(-_as_float(xi))


# --- group operations and their Jacobians ----------------------------------------------------


def inverse(S) -> np.ndarray:
    """``S⁻¹ = [[Rᵀ/s, −Rᵀ t/s], [0, 1]]``."""
    S = _as_float(S)
    _check_last(S, (4, 4), "S")
    M, t = S[..., :3, :3], S[..., :3, 3]
    s_sq = np.linalg.det(M) ** (2.0 / 3.0)
    M_inv = np.swapaxes(M, -1, -2) / s_sq[..., None, None]  # (sR)ᵀ/s² = Rᵀ/s
    out = np.zeros(S.shape)
    out[..., :3, :3] = M_inv
    out[..., :3, 3] = -(M_inv @ t[..., None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def compose(a, b) -> np.ndarray:
    """``a · b`` (batch shapes broadcast)."""
    _broadcast((a, (4, 4)), (b, (4, 4)))
    return _as_float(a) @ _as_float(b)


def between(a, b) -> np.ndarray:
    """``a⁻¹ · b`` (batch shapes broadcast)."""
    _broadcast((a, (4, 4)), (b, (4, 4)))
    return inverse(a) @ _as_float(b)


def act(S, p) -> np.ndarray:
    """``S · p = s R p + t`` for points ``p (..., 3)`` (batch shapes broadcast)."""
    _broadcast((S, (4, 4)), (p, (3,)))
    S = _as_float(S)
    return (S[..., :3, :3] @ _as_float(p)[..., None])[..., 0] + S[..., :3, 3]


def _identity(batch, n: int) -> np.ndarray:
    return np.broadcast_to(np.eye(n), batch + (n, n)).copy()


def compose_jacobians(a, b):
    """Right Jacobians of ``a · b``: ``(J_ab_a, J_ab_b) = (Ad(b⁻¹), I)``, each ``(..., 7, 7)``."""
    batch = _broadcast((a, (4, 4)), (b, (4, 4)))
    return np.broadcast_to(adjoint(inverse(b)), batch + (7, 7)).copy(), _identity(batch, 7)


def inverse_jacobian(S) -> np.ndarray:
    """Right Jacobian of ``S⁻¹``: ``−Ad(S)``: ``(S Exp(δ))⁻¹ = S⁻¹ Exp(−Ad(S) δ)``."""
    return -adjoint(S)


def between_jacobians(a, b):
    """Right Jacobians of ``a⁻¹ · b``: ``(−Ad(b⁻¹ a), I)``, each ``(..., 7, 7)``."""
    batch = _broadcast((a, (4, 4)), (b, (4, 4)))
    return np.broadcast_to(-adjoint(between(b, a)), batch + (7, 7)).copy(), _identity(batch, 7)


def act_jacobians(S, p):
    """Jacobians of ``S · p``: ``J_out_S = [−sR [p]×, sR, sR p]`` ``(..., 3, 7)``, ``J_out_p = sR`` ``(..., 3, 3)``.

    ``S Exp(δ) p ≈ S p + sR (ω × p + υ + λ p)`` for ``δ = [ω; υ; λ]``.
    """
    batch = _broadcast((S, (4, 4)), (p, (3,)))
    M = np.broadcast_to(_as_float(S)[..., :3, :3], batch + (3, 3))
    p = np.broadcast_to(_as_float(p), batch + (3,))
    J = np.concatenate([-M @ so3.hat(p), M, (M @ p[..., None])], axis=-1)
    return J, M.copy()


# --- g2o's own Exp and Log (its file format and its EdgeSim3 error) ---------------------------

_G2O_EPS = 1e-5
"""g2o's threshold in ``Sim3(Vector7)`` and ``Sim3::log`` (``g2o/types/sim3/sim3.h``): on ``|σ|``, on θ
(Exp) and on ``1 − d``, ``d = (tr R − 1)/2`` (Log)."""


def _g2o_w_coefficients(theta, sigma, s, rotation_small):
    """g2o's ``(A, B, C)`` of ``W = A Ω + B Ω² + C I`` (its V(ω, σ)), with its first-order branches.

    ``C = 1`` where ``|σ| < 1e-5`` (exact: ``(s − 1)/σ``); where ``rotation_small``, the θ = 0 limits
    ``((σ−1)s+1)/σ²``, ``((σ²/2−σ+1)s−1)/σ³`` (``½``, ``⅙`` if also ``|σ| < 1e-5``); elsewhere the closed
    forms (SO(3)'s ``B``, ``C`` at ``|σ| < 1e-5``). All 1-D; every division has a safe divisor.
    """
    sigma_small = np.abs(sigma) < _G2O_EPS
    sg = np.where(sigma_small, 1.0, sigma)
    th = np.where(rotation_small, 1.0, theta)
    C = np.where(sigma_small, 1.0, (s - 1.0) / sg)
    A_near = np.where(sigma_small, 0.5, ((sg - 1.0) * s + 1.0) / (sg * sg))
    B_near = np.where(sigma_small, 1.0 / 6.0, ((0.5 * sg * sg - sg + 1.0) * s - 1.0) / (sg * sg * sg))
    _, B_rotation, C_rotation = _closed_abc(th)
    a, b, c = s * np.sin(th), s * np.cos(th), th * th + sigma * sigma
    A_general = (a * sigma + (1.0 - b) * th) / (th * c)
    B_general = (C - ((b - 1.0) * sigma + a * th) / c) / (th * th)
    A = np.where(rotation_small, A_near, np.where(sigma_small, B_rotation, A_general))
    B = np.where(rotation_small, B_near, np.where(sigma_small, C_rotation, B_general))
    return A, B, C


def _g2o_w(w, sigma, rotation_small) -> np.ndarray:
    """g2o's ``W`` ``(n, 3, 3)`` for ``w (n, 3)``, ``sigma (n,)``."""
    A, B, C = _g2o_w_coefficients(np.linalg.norm(w, axis=1), sigma, np.exp(sigma), rotation_small)
    return _combine(C, A, B, w)


def g2o_exp(xi) -> np.ndarray:
    """g2o's ``Sim3(Vector7)`` of ``[ω; υ; σ]``: ``[[e^σ Exp(ω), W υ], [0, 1]]`` with g2o's ``W`` (``(..., 7) -> (..., 4, 4)``).

    How g2o reads the classic ``VERTEX_SIM3:EXPMAP`` / ``EDGE_SIM3:EXPMAP`` lines. Equal to :func:`exp`
    except in g2o's first-order branches (``|σ| < 1e-5``: ``C = 1``, off by ``σ/2`` relative; θ < 1e-5).
    The rotation is the exact ``Exp(ω)`` (g2o's ``I + Ω + Ω²/2`` below θ = 1e-5, renormalised, differs by ``O(θ³)``).
    """
    x, batch = _flat(xi, (7,), "xi")
    w, u, sigma = x[:, :3], x[:, 3:6], x[:, 6]
    t = (_g2o_w(w, sigma, np.linalg.norm(w, axis=1) < _G2O_EPS) @ u[:, :, None])[:, :, 0]
    return _assemble(np.exp(sigma)[:, None, None] * so3.exp(w), t, batch)


def g2o_exp_inverse(S) -> np.ndarray:
    """The ``[ω; υ; σ]`` that :func:`g2o_exp` maps to ``S`` (``(..., 4, 4) -> (..., 7)``): what to write in a
    classic g2o Sim(3) line so that g2o reads ``S`` back. ``ω = so3.log(R)``, ``σ = log s``, ``υ = W⁻¹ t``."""
    R, t, s, batch = _split(S)
    w = so3.log(R)
    sigma = np.log(s)
    u = np.linalg.solve(_g2o_w(w, sigma, np.linalg.norm(w, axis=1) < _G2O_EPS), t[:, :, None])[:, :, 0]
    return np.concatenate([w, u, sigma[:, None]], axis=-1).reshape(batch + (7,))


def g2o_log(S) -> np.ndarray:
    """g2o's ``Sim3::log``, which ``EdgeSim3`` uses as its error: ``(..., 4, 4) -> (..., 7)``.

    Equal to :func:`log` to first order only: where ``1 − d < 1e-5`` (θ below ~4.5e-3) g2o takes
    ``ω = ½ vee(R − Rᵀ)`` (``sin θ`` along the axis, not θ) with the θ = 0 limits of ``W``; where
    ``|σ| < 1e-5`` it takes ``C = 1``; elsewhere ``θ = acos d`` and the closed forms, ``υ = W⁻¹ t``.
    Reproduced so that the χ² reported for a g2o Sim(3) file is the one g2o computes (``docs/g2o.md``).
    """
    R, t, s, batch = _split(S)
    sigma = np.log(s)
    d = np.clip(0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0), -1.0, 1.0)
    near = d > 1.0 - _G2O_EPS
    theta = np.arccos(d)
    factor = np.where(near, 0.5, theta / (2.0 * np.sqrt(np.where(near, 1.0, 1.0 - d * d))))
    w = (2.0 * factor)[:, None] * so3.vee(R)  # g2o's deltaR(R) = vee(R − Rᵀ) = 2 vee(R)
    A, B, C = _g2o_w_coefficients(theta, sigma, s, near)
    u = np.linalg.solve(_combine(C, A, B, w), t[:, :, None])[:, :, 0]
    return np.concatenate([w, u, sigma[:, None]], axis=-1).reshape(batch + (7,))
