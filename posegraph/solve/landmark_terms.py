"""The landmark measurements' share of the cost and of the normal equations, family by family.

Each family of :class:`posegraph.model.landmarks.Observations` is a batch of factors joining a pose
block (``d``) and a point block (``s``), or a point alone (priors). With residuals ``e`` ``(q, r)``,
Jacobians ``A = ∂e/∂δ_pose`` ``(q, r, d)`` and ``P = ∂e/∂δ_point`` ``(q, r, s)``
(:func:`posegraph.solve.landmark_residuals.landmark_jacobians`), information Ω and IRLS weight ``w``
(1 without a robust loss), a measurement adds::

    H_pose,pose = w AᵀΩA,   H_point,point = w PᵀΩP,   H_pose,point = w AᵀΩP,
    g_pose = w AᵀΩe,        g_point = w PᵀΩe,

scattered into the pattern's CSC ``data`` and ``g`` by the maps
:func:`posegraph.solve.sparsity.analyze_pattern` made for the family (one ``np.bincount`` each),
beside the pose edges' blocks: the same system, the same factorisation, blocks of two sizes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.solve.landmark_residuals import landmark_jacobians, sensed_residuals
from posegraph.solve.sparsity import HessianPattern, PointFamily, PointVariables

__all__ = [
    "LandmarkErrors", "LandmarkBlocks", "point_variables", "landmark_errors", "linearize_landmarks",
    "add_landmark_gradient", "add_landmark_hessian", "retract_points",
]


def point_variables(graph: PoseGraph) -> PointVariables | None:
    """The landmark variables of ``graph`` for :func:`~posegraph.solve.sparsity.analyze_pattern`, None without landmarks."""
    landmarks = graph.landmarks
    if landmarks is None:
        return None
    families = tuple(PointFamily(None if f.unary else np.asarray(f.pose, dtype=np.int64), np.asarray(f.landmark, dtype=np.int64))
                     for f in landmarks.observations)  # fmt: skip
    return PointVariables(landmarks.count, landmarks.space_dim, np.asarray(landmarks.fixed, dtype=bool), families)


@dataclass(frozen=True, eq=False)
class LandmarkErrors:
    """The residuals of every family at one estimate."""

    residuals: tuple
    """Per family ``(q, r)`` residuals ``e``."""
    squared: np.ndarray
    """``(Σq,)`` ``eᵀΩe`` of every measurement, families one after the other."""
    sensed: tuple = ()
    """Per family the points in the sensor frames (:func:`~posegraph.solve.landmark_residuals.sensed_residuals`),
    which the linearisation at the same estimate reuses."""


def landmark_errors(graph: PoseGraph, poses: np.ndarray, points: np.ndarray) -> LandmarkErrors:
    """Residuals and squared norms of every landmark measurement of ``graph`` at ``poses``, ``points``."""
    families = graph.landmarks.observations
    evaluated = [sensed_residuals(graph.group, poses, points, f) for f in families]
    residuals = tuple(e for e, _ in evaluated)
    squared = [np.einsum("qi,qij,qj->q", e, np.asarray(f.information, dtype=np.float64), e) for e, f in zip(residuals, families)]
    return LandmarkErrors(residuals, np.concatenate(squared) if squared else np.zeros(0), tuple(s for _, s in evaluated))


@dataclass(frozen=True, eq=False)
class LandmarkBlocks:
    """The families' normal-equation blocks, raveled in the order of their scatter maps."""

    hessian: tuple
    """Per family ``[H_pose,pose, H_point,point, H_pose,point]`` raveled and concatenated (priors: ``H_point,point``)."""
    gradient: tuple
    """Per family ``(q, d + s)`` ``[g_pose, g_point]`` (priors: ``(q, s)``)."""


def linearize_landmarks(
    graph: PoseGraph, poses: np.ndarray, points: np.ndarray, weights: np.ndarray | None = None, errors: LandmarkErrors | None = None
) -> LandmarkBlocks:
    """The blocks of every family at ``poses``, ``points`` (module docstring); ``weights`` ``(Σq,)`` or
    None; ``errors``: :func:`landmark_errors` there, if already computed (its residuals are reused).

    Each block is one batched product, ``Aᵀ(wΩA)``, ``Pᵀ(wΩP)``, ``Aᵀ(wΩP)``, written straight into its
    part of the family's raveled output (:func:`_pair_blocks`)."""
    hessian, gradient, start = [], [], 0
    for number, family in enumerate(graph.landmarks.observations):  # ≤ 4 families
        evaluated = None if errors is None else (errors.residuals[number], errors.sensed[number])
        e, A, P = landmark_jacobians(graph.group, poses, points, family, evaluated)
        omega = np.asarray(family.information, dtype=np.float64)
        if weights is not None:
            omega = omega * weights[start : start + family.count, None, None]
        start += family.count
        omega_P = omega @ P
        if A is None:
            hessian.append((np.swapaxes(P, 1, 2) @ omega_P).ravel())
            gradient.append(np.einsum("qrc,qr->qc", omega_P, e))
            continue
        blocks, pair_gradient = _pair_blocks(A, P, omega @ A, omega_P, e)
        hessian.append(blocks)
        gradient.append(pair_gradient)
    return LandmarkBlocks(tuple(hessian), tuple(gradient))


def _pair_blocks(A: np.ndarray, P: np.ndarray, omega_A: np.ndarray, omega_P: np.ndarray, e: np.ndarray):
    """``(hessian (q·(d² + s² + d·s),), gradient (q, d + s))`` of a pose–point family: ``[AᵀΩA, PᵀΩP, AᵀΩP]``
    raveled one after the other and ``[AᵀΩe, PᵀΩe]``, from ``A (q, r, d)``, ``P (q, r, s)``, ``ΩA``, ``ΩP``
    (weights in Ω) and ``e (q, r)``."""
    q, _, d = A.shape
    s = P.shape[2]
    hessian, gradient = np.empty(q * (d * d + s * s + d * s)), np.empty((q, d + s))
    A_t = np.swapaxes(A, 1, 2)
    np.matmul(A_t, omega_A, out=hessian[: q * d * d].reshape(q, d, d))
    np.matmul(np.swapaxes(P, 1, 2), omega_P, out=hessian[q * d * d : q * (d * d + s * s)].reshape(q, s, s))
    np.matmul(A_t, omega_P, out=hessian[q * (d * d + s * s) :].reshape(q, d, s))
    np.einsum("qrc,qr->qc", omega_A, e, out=gradient[:, :d])
    np.einsum("qrc,qr->qc", omega_P, e, out=gradient[:, d:])
    return hessian, gradient


def add_landmark_gradient(pattern: HessianPattern, gradient: np.ndarray, blocks: LandmarkBlocks) -> None:
    """Add the families' gradient blocks into ``gradient`` ``(D,)`` (in place)."""
    size = pattern.dimension
    for (_, rows), values in zip(pattern.family_positions, blocks.gradient):
        gradient += np.bincount(rows, weights=values.ravel(), minlength=size + 1)[:size]


def add_landmark_hessian(pattern: HessianPattern, data: np.ndarray, blocks: LandmarkBlocks) -> None:
    """Add the families' Hessian blocks into the lower-triangle ``data`` ``(nnz,)`` (in place)."""
    nnz = pattern.nnz
    for (positions, _), values in zip(pattern.family_positions, blocks.hessian):
        data += np.bincount(positions, weights=values, minlength=nnz + 1)[:nnz]


def retract_points(pattern: HessianPattern, points: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``p + δ`` for the free landmarks (``delta`` the whole ``(D,)`` step); held ones unchanged."""
    return points + pattern.expand_points(delta)
