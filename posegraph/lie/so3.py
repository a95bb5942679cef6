"""SO(3): rotations as ``(..., 3, 3)`` matrices, tangent vectors ``w`` as ``(..., 3)``.

Every function takes any leading batch shape and works on the whole batch in one vectorised
numpy call; all arithmetic is float64.

Conventions (as in gtsam's ``Rot3`` and Solà, "A micro Lie theory for state estimation in
robotics", 2018):

* ``hat(w)`` is the skew matrix ``[w]×`` with ``[w]× p = w × p``; ``vee`` is its inverse.
* ``exp(w)`` is the rotation by ``θ = |w|`` about ``w / θ``; ``log`` returns ``θ`` in ``[0, π]``.
* Right perturbations ``R ⊕ δ = R · Exp(δ)``.  The *right Jacobian* satisfies
  ``Exp(w + δ) ≈ Exp(w) · Exp(Jr(w) δ)``, the left one ``Exp(w + δ) ≈ Exp(Jl(w) δ) · Exp(w)``;
  ``Jl(w) = Jr(−w) = Jr(w)ᵀ``.  gtsam: ``Rot3.ExpmapDerivative = Jr``,
  ``Rot3.LogmapDerivative(w) = Jr(w)⁻¹``.

Closed forms (``W = [w]×``, ``θ = |w|``).  ``W² = w wᵀ − θ² I`` turns each of them into
``α I + β W + γ w wᵀ``, which is how they are built, entry by entry::

    Exp(w)  = I + A W + B W²          = cos θ I + A W + B w wᵀ       (Rodrigues)
    Jr(w)   = I − B W + C W²          = A I − B W + C w wᵀ
    Jr⁻¹(w) = I + ½ W + D W²          = E I + ½ W + D w wᵀ
    Jl(w), Jl⁻¹(w): the same with W → −W

with the scalar functions of θ::

    A = sin θ / θ
    B = (1 − cos θ) / θ²       = 2 sin²(θ/2) / θ²
    C = (θ − sin θ) / θ³                                (A = 1 − θ² C)
    E = (θ/2) cot(θ/2)         = A / (2B)               (= 1 − θ² D)
    D = (1 − E) / θ²           = 1/θ² − (1 + cos θ) / (2 θ sin θ)

Numerics.  Below ``_SERIES_ANGLE`` every scalar is its Taylor polynomial in θ² (no cancellation,
no division, no trigonometry); above it the closed forms are evaluated from ``sin(θ/2)`` and
``cos(θ/2)`` on those elements only.  ``E`` is a cotangent of the half angle, so ``Jr⁻¹`` never
divides by ``sin θ`` and stays exact through ``θ = π``.  ``log`` goes through the unit quaternion
(Shepperd's method), so near ``θ = π`` the axis comes from the symmetric part of ``R``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "hat",
    "vee",
    "exp",
    "log",
    "right_jacobian",
    "right_jacobian_inverse",
    "left_jacobian",
    "left_jacobian_inverse",
    "from_quaternion",
    "to_quaternion",
    "project",
]

# ---------------------------------------------------------------------------------------------
# Scalar coefficients A … E and their derivatives, accurate to about one ulp for θ in [0, π]
# ---------------------------------------------------------------------------------------------

# Below this angle the coefficients are Taylor polynomials, above it closed forms.  The closed forms
# of C, D and of the derivatives subtract nearly equal O(1) numbers: they lose ~eps/θ² (C, D) to
# ~eps/θ⁴ (dC, dD) relative, i.e. 1e-14 … 1e-9 at θ = 0.1.  At θ = 1 the worst of them (dD) is
# still within 1e-16 absolute, and ten terms of each series are within 2e-17 of the 50-digit value
# (the slowest to converge, D and E, have radius 2π).  See docs/lie.md.
_SERIES_ANGLE = 1.0
_SERIES_TERMS = 10

# Bernoulli numbers B₂, B₄, … for (x/2) cot(x/2) = Σₙ (−1)ⁿ B₂ₙ x²ⁿ/(2n)!, as (numerator, denominator).
# Every series below is kept as exact integer ratios and rounded once, by int / int (correctly rounded).
_BERNOULLI_EVEN = [(1, 6), (-1, 30), (1, 42), (-1, 30), (5, 66), (-691, 2730), (7, 6), (-3617, 510),
                   (43867, 798), (-174611, 330), (854513, 138)]


def _taylor(m: int, n: int) -> list[tuple[int, int]]:
    """First n coefficients of Σₖ (−1)ᵏ θ²ᵏ / (2k + m)!  (m = 1: A, 2: B, 3: C)."""
    return [((-1) ** k, math.factorial(2 * k + m)) for k in range(n)]


def _half_cot_series(n: int) -> list[tuple[int, int]]:
    """E = (θ/2) cot(θ/2) = Σₖ (−1)ᵏ B₂ₖ θ²ᵏ / (2k)!  (B₀ = 1)."""
    bernoulli = [(1, 1)] + _BERNOULLI_EVEN
    return [((-1) ** k * p, q * math.factorial(2 * k)) for k, (p, q) in enumerate(bernoulli[:n])]


def _d_series(n: int) -> list[tuple[int, int]]:
    """D = (1 − E)/θ²: minus the series of E shifted by one power of θ²."""
    return [(-p, q) for p, q in _half_cot_series(n + 1)[1:]]


def _derivative_over_theta(coefficients: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Series of f'(θ)/θ from the series of f in powers of θ²: Σₖ 2k cₖ θ²ᵏ⁻²."""
    return [(2 * k * p, q) for k, (p, q) in enumerate(coefficients)][1:]


def _rounded(coefficients: list[tuple[int, int]]) -> tuple[float, ...]:
    """The exact ratios rounded to the nearest doubles."""
    return tuple(p / q for p, q in coefficients)


_N = _SERIES_TERMS + 1  # one more, for the derivative series
_A_SERIES = _rounded(_taylor(1, _N)[:_SERIES_TERMS])
_B_SERIES = _rounded(_taylor(2, _N)[:_SERIES_TERMS])
_C_SERIES = _rounded(_taylor(3, _N)[:_SERIES_TERMS])
_D_SERIES = _rounded(_d_series(_N)[:_SERIES_TERMS])
_E_SERIES = _rounded(_half_cot_series(_SERIES_TERMS))
_DB_SERIES = _rounded(_derivative_over_theta(_taylor(2, _N)))  # (dB/dθ)/θ
_DC_SERIES = _rounded(_derivative_over_theta(_taylor(3, _N)))  # (dC/dθ)/θ
_DD_SERIES = _rounded(_derivative_over_theta(_d_series(_N)))  # (dD/dθ)/θ
_DE_SERIES = _rounded(_derivative_over_theta(_half_cot_series(_N)))  # (dE/dθ)/θ


def _polynomial(theta_sq: np.ndarray, coefficients: tuple[float, ...]) -> np.ndarray:
    """Σₖ coefficients[k] θ²ᵏ by Horner's rule."""
    out = np.full_like(theta_sq, coefficients[-1])
    for c in coefficients[-2::-1]:
        out *= theta_sq
        out += c
    return out


def _piecewise(theta: np.ndarray, series: list[tuple[float, ...]], closed) -> list[np.ndarray]:
    """Evaluate several coefficients: Taylor polynomials below ``_SERIES_ANGLE``, ``closed`` above.

    ``theta`` is 1-D.  Each branch only sees its own elements (so ``closed`` never sees θ = 0), and
    a batch entirely on one side — small residuals, say — costs one branch only.
    """
    small = theta < _SERIES_ANGLE
    if small.all():
        theta_sq = theta * theta
        return [_polynomial(theta_sq, s) for s in series]
    if not small.any():
        return list(closed(theta))
    out = [np.empty_like(theta) for _ in series]
    theta_small = theta[small]
    theta_sq = theta_small * theta_small
    large = ~small
    for o, s, value in zip(out, series, closed(theta[large])):
        o[small] = _polynomial(theta_sq, s)
        o[large] = value
    return out


def _half_angle(theta: np.ndarray):
    """``(sin θ, 1 − cos θ, sin(θ/2), cos(θ/2))`` from the half angle: 1 − cos θ = 2 sin²(θ/2)."""
    sin_half = np.sin(0.5 * theta)
    cos_half = np.cos(0.5 * theta)
    return 2.0 * sin_half * cos_half, 2.0 * sin_half * sin_half, sin_half, cos_half


def _closed_abc(theta: np.ndarray):
    sin, one_minus_cos, _, _ = _half_angle(theta)
    theta_sq = theta * theta
    return sin / theta, one_minus_cos / theta_sq, (theta - sin) / (theta_sq * theta)


def _exp_coefficients(theta: np.ndarray, count: int = 3):
    """``(A, B, C)``, the first ``count`` of them (SE(2)'s ``Exp`` needs no ``C``); ``theta`` is 1-D."""
    if count == 3:
        return _piecewise(theta, [_A_SERIES, _B_SERIES, _C_SERIES], _closed_abc)
    return _piecewise(theta, [_A_SERIES, _B_SERIES, _C_SERIES][:count], lambda t: _closed_abc(t)[:count])


def _half_cot(theta: np.ndarray) -> np.ndarray:
    """``E = (θ/2)cot(θ/2)`` alone, as :func:`_inverse_jacobian_coefficients` computes it (SE(2)'s ``Log``
    needs no ``D``: its Horner pass is half the coefficients' cost on small angles); ``theta`` is 1-D."""

    def closed(t):
        return (0.5 * t * np.cos(0.5 * t) / np.sin(0.5 * t),)

    return _piecewise(theta, [_E_SERIES], closed)[0]


def _jacobian_coefficients(theta: np.ndarray):
    """``(A, B, C, dA, dB, dC)`` with ``dX = (dX/dθ)/θ``; ``theta`` is 1-D.

    Closed forms: ``dB = (A − 2B)/θ²``, ``dC = (B − 3C)/θ²``; ``dA = −2C − θ² dC`` from
    ``A = 1 − θ² C`` (no cancellation, used in both regimes).
    """

    def closed(t):
        a, b, c = _closed_abc(t)
        t_sq = t * t
        return a, b, c, (a - 2.0 * b) / t_sq, (b - 3.0 * c) / t_sq

    a, b, c, db, dc = _piecewise(theta, [_A_SERIES, _B_SERIES, _C_SERIES, _DB_SERIES, _DC_SERIES], closed)
    da = -2.0 * c - theta * theta * dc
    return a, b, c, da, db, dc


def _inverse_jacobian_coefficients(theta: np.ndarray, derivatives: bool = False):
    """``(E, D)`` or, with ``derivatives``, ``(E, D, dE, dD)``; ``theta`` is 1-D.

    ``E = (θ/2)cot(θ/2)``, ``D = (1 − E)/θ²``, ``dE = (dE/dθ)/θ = −C/(2B)`` and
    ``dD = (dD/dθ)/θ = (C/(2B) − 2D)/θ²``.  None divides by ``sin θ``: all stay accurate
    through ``θ = π`` and are singular only at ``θ = 2π``.
    """

    def closed(t):
        sin, one_minus_cos, sin_half, cos_half = _half_angle(t)
        t_sq = t * t
        e = 0.5 * t * cos_half / sin_half
        d = (1.0 - e) / t_sq
        if not derivatives:
            return e, d
        de = -(t - sin) / (2.0 * t * one_minus_cos)  # −C/(2B)
        return e, d, de, (-de - 2.0 * d) / t_sq

    series = [_E_SERIES, _D_SERIES] + ([_DE_SERIES, _DD_SERIES] if derivatives else [])
    return _piecewise(theta, series, closed)


# ---------------------------------------------------------------------------------------------
# Batched arrays as lists of components
#
# Inputs are split once into contiguous 1-D component arrays over the flattened batch; each entry of
# an output matrix is a few elementwise operations on those.  For large batches this is several
# times faster than stacks of small matmuls or einsum chains.  How the entries reach the output
# depends on size: while the output fits in cache, each entry is written straight into it (one
# allocation); beyond that, strided writes would stream the whole output through memory once per
# entry, so the entries go into a component-major buffer, transposed in one pass.
# ---------------------------------------------------------------------------------------------

# Output bytes above which the component-major buffer pays off (measured: direct writes win at
# 9k 6×6 matrices = 2.6 MB, the buffer at 100k = 29 MB; see docs/lie.md).
_DIRECT_WRITE_BYTES = 4 * 2**20


def _as_float(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _check_last(x: np.ndarray, shape: tuple[int, ...], name: str) -> None:
    if x.ndim < len(shape) or x.shape[x.ndim - len(shape):] != shape:
        want = ", ".join(map(str, shape))
        raise ValueError(f"{name} must have shape (..., {want}), got {x.shape}")


def _components(x, shape: tuple[int, ...], name: str):
    """``(rows, batch)``: ``x (*batch, *shape)`` as a contiguous ``(prod(shape), n)`` array."""
    x = _as_float(x)
    _check_last(x, shape, name)
    batch = x.shape[: x.ndim - len(shape)]
    size = math.prod(shape)
    return np.ascontiguousarray(x.reshape(-1, size).T), batch


def _from_entries(entries, batch: tuple[int, ...]) -> np.ndarray:
    """``(*batch, rows, cols)`` matrix from nested lists of 1-D arrays (or scalars), one per entry."""
    rows, cols = len(entries), len(entries[0])
    n = math.prod(batch)
    if n * rows * cols * 8 <= _DIRECT_WRITE_BYTES:
        out = np.empty((n, rows, cols), dtype=np.float64)
        for i, row in enumerate(entries):
            for j, value in enumerate(row):
                out[:, i, j] = value
        return out.reshape(batch + (rows, cols))
    buffer = np.empty((rows, cols, n), dtype=np.float64)
    for i, row in enumerate(entries):
        for j, value in enumerate(row):
            buffer[i, j] = value
    return np.ascontiguousarray(buffer.transpose(2, 0, 1)).reshape(batch + (rows, cols))


def _from_vector(components, batch: tuple[int, ...]) -> np.ndarray:
    """``(*batch, k)`` from a list of k 1-D arrays."""
    return np.stack(components, axis=-1).reshape(batch + (len(components),))


def _combine_entries(alpha, beta, gamma, w0, w1, w2):
    """Entries of ``alpha I + beta [w]× + gamma w wᵀ`` (3×3 nested list of 1-D arrays)."""
    g0, g1, g2 = gamma * w0, gamma * w1, gamma * w2
    b0, b1, b2 = beta * w0, beta * w1, beta * w2
    s01, s02, s12 = g0 * w1, g0 * w2, g1 * w2
    return [
        [g0 * w0 + alpha, s01 - b2, s02 + b1],
        [s01 + b2, g1 * w1 + alpha, s12 - b0],
        [s02 - b1, s12 + b0, g2 * w2 + alpha],
    ]


def _norm(w0, w1, w2):
    return np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)


# ---------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------


def hat(w) -> np.ndarray:
    """Skew matrix ``[w]×`` of ``w (..., 3)``: ``hat(w) @ p == cross(w, p)``. Returns ``(..., 3, 3)``."""
    w = _as_float(w)
    _check_last(w, (3,), "w")
    out = np.zeros(w.shape + (3,), dtype=np.float64)
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def vee(W) -> np.ndarray:
    """Inverse of :func:`hat`: ``(..., 3, 3) -> (..., 3)``, from the skew part ``(W − Wᵀ)/2``."""
    W = _as_float(W)
    _check_last(W, (3, 3), "W")
    return 0.5 * np.stack(
        [W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]], axis=-1
    )


def _exp_entries(w0, w1, w2):
    a, b, _ = _exp_coefficients(_norm(w0, w1, w2))
    # cos θ = 1 − θ² B: exact in both regimes, no separate cosine needed.
    cos = 1.0 - (w0 * w0 + w1 * w1 + w2 * w2) * b
    return _combine_entries(cos, a, b, w0, w1, w2)


def exp(w) -> np.ndarray:
    """Rotation matrix ``Exp(w) = cos θ I + (sin θ/θ) [w]× + ((1 − cos θ)/θ²) w wᵀ`` (Rodrigues).

    ``w (..., 3)`` -> ``(..., 3, 3)``; equals gtsam's ``Rot3.Expmap``.
    """
    (w0, w1, w2), batch = _components(w, (3,), "w")
    return _from_entries(_exp_entries(w0, w1, w2), batch)


def _quaternion_components(r):
    """Unit quaternion ``(qx, qy, qz, qw)``, ``qw ≥ 0``, from the 9 entries of R (row-major 1-D arrays).

    Shepperd's method: the symmetric matrix ``K = 4 q qᵀ`` has entries that are sums and differences
    of entries of ``R``.  Its row ``k`` with the largest diagonal ``4 q_k² ≥ 1`` is ``4 q_k q``:
    normalising that row gives ``±q`` without ever dividing by a small number, at any angle.  The
    normalisation also absorbs a matrix slightly off SO(3).
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    n = r00.shape[0]
    K = np.empty((4, 4, n), dtype=np.float64)
    K[0, 0] = 1.0 + r00 - r11 - r22
    K[1, 1] = 1.0 - r00 + r11 - r22
    K[2, 2] = 1.0 - r00 - r11 + r22
    K[3, 3] = 1.0 + r00 + r11 + r22
    K[0, 1] = K[1, 0] = r01 + r10
    K[0, 2] = K[2, 0] = r02 + r20
    K[1, 2] = K[2, 1] = r12 + r21
    K[0, 3] = K[3, 0] = r21 - r12
    K[1, 3] = K[3, 1] = r02 - r20
    K[2, 3] = K[3, 2] = r10 - r01
    k = np.argmax(K[[0, 1, 2, 3], [0, 1, 2, 3]], axis=0)
    row = np.take_along_axis(K, k[None, None, :], axis=0)[0]  # (4, n) = 4 q_k q
    # Scale to unit length and pick the sign with qw ≥ 0 in one factor.
    scale = np.where(row[3] < 0.0, -1.0, 1.0) / np.sqrt(np.einsum("kn,kn->n", row, row))
    return row * scale


def to_quaternion(R) -> np.ndarray:
    """Unit quaternion ``(..., 4)`` in g2o order ``[qx, qy, qz, qw]`` with ``qw ≥ 0`` (Shepperd's method).

    ``R (..., 3, 3)`` may be slightly off SO(3); the result is always a unit quaternion.
    """
    r, batch = _components(R, (3, 3), "R")
    return _from_vector(list(_quaternion_components(r)), batch)


def from_quaternion(q) -> np.ndarray:
    """Rotation matrix ``(..., 3, 3)`` from a quaternion ``(..., 4)`` in g2o order ``[qx, qy, qz, qw]``.

    The quaternion is normalised first; ``q`` and ``−q`` give the same rotation.
    Raises ``ValueError`` for a zero or non-finite quaternion.
    """
    (x, y, z, w), batch = _components(q, (4,), "q")
    norm_sq = x * x + y * y + z * z + w * w
    if not np.all(np.isfinite(norm_sq)) or np.any(norm_sq == 0.0):
        raise ValueError("quaternion must be finite and non-zero")
    s = 2.0 / norm_sq  # normalises: 2/|q|² in place of 2 for a unit quaternion
    xx, yy, zz = s * x * x, s * y * y, s * z * z
    xy, xz, yz = s * x * y, s * x * z, s * y * z
    wx, wy, wz = s * w * x, s * w * y, s * w * z
    entries = [
        [1.0 - (yy + zz), xy - wz, xz + wy],
        [xy + wz, 1.0 - (xx + zz), yz - wx],
        [xz - wy, yz + wx, 1.0 - (xx + yy)],
    ]
    return _from_entries(entries, batch)


# Below this |q_v| = sin(θ/2) the ratio 2 atan2(|q_v|, q_w)/|q_v| = (2/q_w)(1 − x²/3 + …),
# x = |q_v|/q_w, is exactly 2.0 in double precision (q_w = 1 and x² < 1e-20); the closed form
# itself is accurate down to denormals, the branch only avoids 0/0.
_TINY_SIN_HALF = 1e-10


def _log_components(r):
    """Rotation vector components ``(w0, w1, w2)`` of R given as its 9 entries."""
    qx, qy, qz, qw = _quaternion_components(r)
    sin_half = _norm(qx, qy, qz)
    tiny = sin_half < _TINY_SIN_HALF
    factor = np.where(tiny, 2.0, 2.0 * np.arctan2(sin_half, qw) / np.where(tiny, 1.0, sin_half))
    return factor * qx, factor * qy, factor * qz


def log(R) -> np.ndarray:
    """Rotation vector ``w (..., 3)`` with ``Exp(w) = R`` and ``θ = |w|`` in ``[0, π]``.

    Via the unit quaternion ``q = (q_v, q_w)``, ``q_w ≥ 0``: ``w = 2 atan2(|q_v|, q_w) q_v / |q_v|``.
    Near ``θ = π`` the axis comes from the dominant row of ``4 q qᵀ`` (the symmetric part of ``R``),
    never from dividing by ``sin θ``; ``atan2`` gives the angle to full precision everywhere.
    ``R`` slightly off SO(3) is tolerated.  At exactly ``θ = π`` both ``±w`` are valid answers.
    Equals gtsam's ``Rot3.Logmap``.
    """
    r, batch = _components(R, (3, 3), "R")
    return _from_vector(list(_log_components(r)), batch)


def right_jacobian(w) -> np.ndarray:
    """Right Jacobian ``Jr(w) = I − B [w]× + C [w]×² = A I − B [w]× + C w wᵀ``.

    ``(..., 3) -> (..., 3, 3)``; ``Exp(w + δ) ≈ Exp(w) Exp(Jr(w) δ)``; gtsam's ``Rot3.ExpmapDerivative``.
    """
    (w0, w1, w2), batch = _components(w, (3,), "w")
    a, b, c = _exp_coefficients(_norm(w0, w1, w2))
    return _from_entries(_combine_entries(a, -b, c, w0, w1, w2), batch)


def left_jacobian(w) -> np.ndarray:
    """Left Jacobian ``Jl(w) = I + B [w]× + C [w]×² = Jr(w)ᵀ = Jr(−w)`` (``(..., 3) -> (..., 3, 3)``)."""
    (w0, w1, w2), batch = _components(w, (3,), "w")
    a, b, c = _exp_coefficients(_norm(w0, w1, w2))
    return _from_entries(_combine_entries(a, b, c, w0, w1, w2), batch)


def right_jacobian_inverse(w) -> np.ndarray:
    """``Jr(w)⁻¹ = I + ½ [w]× + D [w]×²`` with ``D = 1/θ² − (1 + cos θ)/(2θ sin θ)``.

    Built as ``E I + ½ [w]× + D w wᵀ`` with ``E = (θ/2)cot(θ/2)``: no division by ``sin θ``, exact
    through ``θ = π`` (singular at ``θ = 2π``).  ``Log(R Exp(δ)) ≈ Log(R) + Jr⁻¹(Log R) δ``;
    gtsam's ``Rot3.LogmapDerivative``.  ``(..., 3) -> (..., 3, 3)``.
    """
    (w0, w1, w2), batch = _components(w, (3,), "w")
    e, d = _inverse_jacobian_coefficients(_norm(w0, w1, w2))
    return _from_entries(_combine_entries(e, 0.5, d, w0, w1, w2), batch)


def left_jacobian_inverse(w) -> np.ndarray:
    """``Jl(w)⁻¹ = I − ½ [w]× + D [w]×² = Jr(w)⁻ᵀ`` (``(..., 3) -> (..., 3, 3)``)."""
    (w0, w1, w2), batch = _components(w, (3,), "w")
    e, d = _inverse_jacobian_coefficients(_norm(w0, w1, w2))
    return _from_entries(_combine_entries(e, -0.5, d, w0, w1, w2), batch)


def project(M) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to ``M (..., 3, 3)``: ``U diag(1, 1, det(U Vᵀ)) Vᵀ``.

    From the SVD ``M = U S Vᵀ``; flipping the last singular direction keeps ``det = +1`` when ``M``
    is closest to a reflection.
    """
    M = _as_float(M)
    _check_last(M, (3, 3), "M")
    U, _, Vt = np.linalg.svd(M)
    det = np.linalg.det(U @ Vt)
    U[..., :, 2] *= np.where(det < 0.0, -1.0, 1.0)[..., None]
    return U @ Vt
