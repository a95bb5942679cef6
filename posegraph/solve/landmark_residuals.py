"""Residuals and Jacobians of landmark measurements (:mod:`posegraph.model.landmarks`), batched per family.

Shapes: ``q`` measurements in a family, ``r`` rows of each (:func:`posegraph.model.landmarks.measurement_size`),
``n`` poses ``(n, k, k)`` of ``group`` (``k = 3`` SE(2), ``4`` SE(3)), ``d = group.dim``, ``L`` points
``(L, s)`` with ``s = k − 1``. Every residual is *predicted − measured* (module docstring of
:mod:`posegraph.model.landmarks`); angles are wrapped to ``[−π, π)``.

The point in the sensor frame. Measurement ``k`` of pose ``X = X_i`` (rotation ``R``, translation
``t``) with offset ``O`` (``R_O``, ``t_O``; the identity if ``family.offsets`` is None) sees

    w = X⁻¹ ⊙ p = Rᵀ(p − t),        y = O⁻¹ ⊙ w = R_Oᵀ(w − t_O)      (s,)

and the residuals are

    "position":       e = y − z
    "bearing":        e = wrap(atan2(y₁, y₀) − z)                          (2D)
    "bearing_range":  e = [wrap(atan2(y₁, y₀) − z_θ), ‖y‖ − z_r]           (2D)
    "prior":          e = p − z

Jacobians, right perturbation of the pose ``X ← X·Exp(δ)`` (tangent order as gtsam's) and additive step
of the point ``p ← p + δ``: ``w(δ) = Exp(−δ) ⊙ w``, so to first order

    SE(3), δ = [ω; v]:   ∂w/∂δ = [[w]×, −I]                 (3, 6)   (gtsam: Pose3.transformTo's Hself)
    SE(2), δ = [v; ω]:   ∂w/∂δ = [−I, −J w],  J w = [−w₁, w₀]   (2, 3)   (gtsam: Pose2.transformTo's Hself)
    ∂w/∂p = Rᵀ,   ∂y/∂w = R_Oᵀ,
    ∂θ/∂y = [−y₁, y₀] / ‖y‖²,   ∂‖y‖/∂y = yᵀ / ‖y‖,

and each residual's Jacobians are the chain ``∂e/∂y · R_Oᵀ · (∂w/∂δ, Rᵀ)``; the prior's are
``(None, I)``.

gtsam (checked in ``tests/solve/test_landmark_residuals.py``): "position" is
``(X·O).transformTo(p) − z``; "bearing_range" equals ``BearingRangeFactor2D.unwhitenedError`` with the
same sign and order ``[bearing, range]`` (gtsam's error is ``measured.localCoordinates(predicted)``:
``Rot2`` gives ``wrap(θ_pred − θ_meas)``, the range ``r_pred − r_meas``); "bearing" equals
``BearingFactor2D``'s; "prior" equals ``PriorFactorPoint2/3``'s ``p − z``. So the costs ``½ eᵀΩe`` agree term by term.
"""

from __future__ import annotations

import numpy as np

from posegraph.model.landmarks import Observations, measurement_size

__all__ = ["landmark_residuals", "sensed_residuals", "landmark_jacobians", "landmark_cost", "sensor_points", "wrap_angle"]


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``[−π, π)``: ``(a + π) mod 2π − π`` (any shape)."""
    return np.mod(np.asarray(angle, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi


def _rotation_translation(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Blocks ``R (…, s, s)`` and ``t (…, s)`` of homogeneous matrices ``(…, k, k)``."""
    s = matrices.shape[-1] - 1
    return matrices[..., :s, :s], matrices[..., :s, s]


def sensor_points(group, poses: np.ndarray, points: np.ndarray, family: Observations):
    """The observed points in the body and sensor frames of each measurement, and the rotations used.

    Returns ``w = R_iᵀ(p − t_i)`` ``(q, s)``, ``y = R_Oᵀ(w − t_O)`` ``(q, s)``, ``R_i`` ``(q, s, s)``
    and ``R_O`` ``(q, s, s)`` or None (identity offsets). Not for ``"prior"`` families.
    """
    poses = np.asarray(poses, dtype=np.float64)
    R, t = _rotation_translation(poses[family.pose])
    p = np.asarray(points, dtype=np.float64)[family.landmark]
    w = np.einsum("qji,qj->qi", R, p - t)
    if family.offsets is None:
        return w, w, R, None
    R_O, t_O = _rotation_translation(np.asarray(family.offsets, dtype=np.float64))
    y = np.einsum("qji,qj->qi", R_O, w - t_O)
    return w, y, R, R_O


def _predicted_minus_measured(kind: str, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``(q, r)`` residuals of a pose–point family from sensor-frame points ``y (q, s)`` and ``z (q, r)``."""
    if kind == "position":
        return y - z
    if y.shape[-1] != 2:
        raise ValueError(f"landmark measurements of kind {kind!r} are 2D only; points here are {y.shape[-1]}D")
    bearing = wrap_angle(np.arctan2(y[:, 1], y[:, 0]) - z[:, 0])[:, None]
    if kind == "bearing":
        return bearing
    return np.concatenate([bearing, np.hypot(y[:, 0], y[:, 1])[:, None] - z[:, 1:2]], axis=1)


def landmark_residuals(group, poses: np.ndarray, points: np.ndarray, family: Observations) -> np.ndarray:
    """Residuals ``(q, r)`` of one family (formulas in the module docstring), predicted − measured.

    ``poses`` ``(n, k, k)`` the graph's poses of ``group``, ``points`` ``(L, s)`` the landmarks.
    """
    return sensed_residuals(group, poses, points, family)[0]


def _body_jacobian(w: np.ndarray) -> np.ndarray:
    """``∂w/∂δ`` ``(q, s, d)`` of ``w = (X·Exp(δ))⁻¹ ⊙ p`` at δ = 0 (module docstring)."""
    q, s = w.shape
    if s == 3:  # δ = [ω; v]: [[w]×, −I]
        J = np.zeros((q, 3, 6))
        J[:, 0, 1], J[:, 0, 2] = -w[:, 2], w[:, 1]
        J[:, 1, 0], J[:, 1, 2] = w[:, 2], -w[:, 0]
        J[:, 2, 0], J[:, 2, 1] = -w[:, 1], w[:, 0]
        J[:, :, 3:] = -np.eye(3)
        return J
    J = np.zeros((q, 2, 3))  # δ = [v; ω]: [−I, −J w] with J w = [−w₁, w₀]
    J[:, :, :2] = -np.eye(2)
    J[:, 0, 2], J[:, 1, 2] = w[:, 1], -w[:, 0]
    return J


def _measurement_jacobian(kind: str, y: np.ndarray) -> np.ndarray:
    """``∂e/∂y`` ``(q, r, s)``: I, ``[−y₁, y₀]/‖y‖²`` (bearing), and ``yᵀ/‖y‖`` below it (range)."""
    if kind == "position":
        return np.broadcast_to(np.eye(y.shape[-1]), (len(y), y.shape[-1], y.shape[-1]))
    rho2 = y[:, 0] ** 2 + y[:, 1] ** 2
    bearing = np.stack([-y[:, 1], y[:, 0]], axis=1)[:, None, :] / rho2[:, None, None]
    if kind == "bearing":
        return bearing
    return np.concatenate([bearing, (y / np.sqrt(rho2)[:, None])[:, None, :]], axis=1)


def sensed_residuals(group, poses: np.ndarray, points: np.ndarray, family: Observations):
    """``(e (q, r), sensed)``: the residuals of one family and what :func:`landmark_jacobians` reuses of
    them (:func:`sensor_points`' tuple; None for ``"prior"``)."""
    measurement_size(family.kind, group.space_dim)  # validates the kind
    if family.kind == "prior":
        return np.asarray(points, dtype=np.float64)[family.landmark] - np.asarray(family.measurements, dtype=np.float64), None
    sensed = sensor_points(group, poses, points, family)
    return _predicted_minus_measured(family.kind, sensed[1], np.asarray(family.measurements, dtype=np.float64)), sensed


def landmark_jacobians(group, poses: np.ndarray, points: np.ndarray, family: Observations, evaluated=None):
    """Residuals ``(q, r)`` and Jacobians of one family: ``(e, J_e_pose, J_e_point)``.

    ``J_e_pose`` ``(q, r, d)`` w.r.t. the right perturbation ``X_i·Exp(δ)`` in the group's tangent order
    (None for ``"prior"``), ``J_e_point`` ``(q, r, s)`` w.r.t. ``p + δ``. Formulas: module docstring.
    ``evaluated``: :func:`sensed_residuals` at the same poses and points, if already computed.
    """
    e, sensed = sensed_residuals(group, poses, points, family) if evaluated is None else evaluated
    if sensed is None:  # a point prior
        s = e.shape[1]
        return e, None, np.broadcast_to(np.eye(s), (len(e), s, s)).copy()
    w, y, R, R_O = sensed
    if family.kind == "position" and R_O is None:  # ∂e/∂w = I: the products by it left out
        return e, _body_jacobian(w), np.swapaxes(R, -1, -2).copy()
    J_e_w = _measurement_jacobian(family.kind, y)
    if R_O is not None:
        J_e_w = J_e_w @ np.swapaxes(R_O, -1, -2)  # ∂e/∂y · ∂y/∂w
    J_e_pose = J_e_w @ _body_jacobian(w)
    J_e_point = J_e_w @ np.swapaxes(R, -1, -2)
    return e, J_e_pose, J_e_point


def landmark_cost(group, poses: np.ndarray, points: np.ndarray, landmarks) -> float:
    """``½ Σ eᵀΩe`` over every family of ``landmarks`` (:class:`posegraph.model.landmarks.Landmarks` or
    None: 0) at poses ``(n, k, k)`` and points ``(L, s)``; the pose edges' cost is
    :func:`posegraph.solve.residuals.cost`'s."""
    if landmarks is None:
        return 0.0
    total = 0.0
    for family in landmarks.observations:  # ≤ 4 families
        e = landmark_residuals(group, poses, points, family)
        total += 0.5 * float(np.einsum("qi,qij,qj->", e, np.asarray(family.information, np.float64), e))
    return total
