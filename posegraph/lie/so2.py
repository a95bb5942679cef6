"""SO(2): rotations as ``(..., 2, 2)`` matrices, tangent vectors ``w = [θ]`` as ``(..., 1)``.

The tangent keeps a trailing axis of length 1 (the group's dimension), so that code written for
any group sees ``(..., dim)`` tangents and ``(..., dim, dim)`` Jacobians; :func:`from_angle` and
:func:`to_angle` convert plain angles ``(...,)``.  Every function takes any leading batch shape and
works on the whole batch in one vectorised numpy call (float64).

Conventions (as gtsam's ``Rot2``):

* ``hat([θ]) = θ J`` with ``J = [[0, −1], [1, 0]]`` (rotation by +90°); ``vee`` is its inverse.
* ``Exp([θ]) = [[cos θ, −sin θ], [sin θ, cos θ]]``; ``log`` returns ``θ = atan2(sin, cos)`` in
  ``[−π, π]`` (gtsam's ``Rot2.Logmap``/``theta``).
* SO(2) is commutative, so ``Exp(θ + δ) = Exp(θ) Exp(δ)`` exactly: the right and left Jacobians
  and their inverses are all ``[[1]]``, and the adjoint is ``[[1]]``.

No Taylor branch is needed anywhere: ``sin``, ``cos`` and ``atan2`` are accurate at every angle.
"""

from __future__ import annotations

import numpy as np

from posegraph.lie.so3 import _as_float, _check_last

__all__ = [
    "hat",
    "vee",
    "exp",
    "log",
    "right_jacobian",
    "right_jacobian_inverse",
    "left_jacobian",
    "left_jacobian_inverse",
    "from_angle",
    "to_angle",
    "project",
]


def from_angle(theta) -> np.ndarray:
    """Rotation matrix ``(..., 2, 2)`` by the angles ``theta (...,)`` (radians, counter-clockwise)."""
    theta = _as_float(theta)
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def to_angle(R) -> np.ndarray:
    """Angle ``(...,)`` in ``[−π, π]`` of ``R (..., 2, 2)``: ``atan2(R₁₀ − R₀₁, R₀₀ + R₁₁)``.

    Both sums use all four entries, so a matrix slightly off SO(2) gives the angle of the nearest
    rotation (:func:`project`).
    """
    R = _as_float(R)
    _check_last(R, (2, 2), "R")
    return np.arctan2(R[..., 1, 0] - R[..., 0, 1], R[..., 0, 0] + R[..., 1, 1])


def hat(w) -> np.ndarray:
    """``hat([θ]) = [[0, −θ], [θ, 0]]``: ``(..., 1) -> (..., 2, 2)``."""
    w = _as_float(w)
    _check_last(w, (1,), "w")
    out = np.zeros(w.shape[:-1] + (2, 2), dtype=np.float64)
    out[..., 0, 1] = -w[..., 0]
    out[..., 1, 0] = w[..., 0]
    return out


def vee(W) -> np.ndarray:
    """Inverse of :func:`hat`: ``(..., 2, 2) -> (..., 1)``, from the skew part ``(W − Wᵀ)/2``."""
    W = _as_float(W)
    _check_last(W, (2, 2), "W")
    return 0.5 * (W[..., 1, 0] - W[..., 0, 1])[..., None]


def exp(w) -> np.ndarray:
    """``Exp([θ]) = [[cos θ, −sin θ], [sin θ, cos θ]]``: ``(..., 1) -> (..., 2, 2)``; gtsam's ``Rot2.Expmap``."""
    w = _as_float(w)
    _check_last(w, (1,), "w")
    return from_angle(w[..., 0])


def log(R) -> np.ndarray:
    """``[θ]`` ``(..., 1)`` with ``θ = atan2(R₁₀ − R₀₁, R₀₀ + R₁₁)`` in ``[−π, π]``; gtsam's ``Rot2.Logmap``.

    ``R`` slightly off SO(2) is tolerated (see :func:`to_angle`).
    """
    return to_angle(R)[..., None]


def _ones(w) -> np.ndarray:
    w = _as_float(w)
    _check_last(w, (1,), "w")
    return np.ones(w.shape[:-1] + (1, 1), dtype=np.float64)


def right_jacobian(w) -> np.ndarray:
    """``Jr([θ]) = [[1]]`` (``(..., 1) -> (..., 1, 1)``): SO(2) is commutative."""
    return _ones(w)


def right_jacobian_inverse(w) -> np.ndarray:
    """``Jr([θ])⁻¹ = [[1]]`` (``(..., 1) -> (..., 1, 1)``)."""
    return _ones(w)


def left_jacobian(w) -> np.ndarray:
    """``Jl([θ]) = [[1]]`` (``(..., 1) -> (..., 1, 1)``)."""
    return _ones(w)


def left_jacobian_inverse(w) -> np.ndarray:
    """``Jl([θ])⁻¹ = [[1]]`` (``(..., 1) -> (..., 1, 1)``)."""
    return _ones(w)


def project(M) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to ``M (..., 2, 2)``: the rotation by :func:`to_angle` ``(M)``.

    ``tr(R(φ)ᵀ M) = cos φ (M₀₀ + M₁₁) + sin φ (M₁₀ − M₀₁)`` is largest at that angle; a matrix with
    both sums zero (e.g. a reflection ``diag(1, −1)``) has no unique answer and gives the identity.
    """
    return from_angle(to_angle(M))
