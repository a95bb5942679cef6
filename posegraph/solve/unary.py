"""Residuals, Jacobians and normal-equation blocks of the unary edges (priors, :mod:`posegraph.model.priors`).

Priors are few (a GNSS fix every few poses), so they have their own small arrays, linearised
alongside the binary edges and added into the same ``g`` and H: each touches only the diagonal
block of its vertex, which every free vertex has in the pattern
(:func:`posegraph.solve.sparsity.analyze_pattern`), so the symbolic analysis is unchanged.

Pose prior, ``e = Log(Z⁻¹ X O)``. Perturbing ``X ← X Exp(δ)``:
``Z⁻¹ X Exp(δ) O = Z⁻¹ X O Exp(Ad(O⁻¹) δ)``, so ``∂e/∂δ = Jr⁻¹(e) · Ad(O⁻¹)`` (``Jr⁻¹(e)`` alone
when ``O = I``, gtsam's ``PriorFactor``).

Position prior, ``e = t(X) − z``. ``t(X Exp(δ)) = t + R v + O(δ²)`` with ``v`` the translation
part of δ, so ``∂e/∂δ = R · S``, ``S`` ``(r, d)`` selecting the translation axes of the tangent
(SE(3): ``[0 R]``, gtsam's ``GPSFactor``; SE(2): ``[R 0]``).

Blocks per prior with weight ``w`` (1 without a robust loss): ``H = w JᵀΩJ``, ``g = w JᵀΩe``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PriorErrors", "PriorBlocks", "prior_errors", "prior_jacobians", "prior_squared_norms",
           "prior_cost", "linearize_priors", "add_prior_gradient", "add_prior_hessian"]


@dataclass(frozen=True, eq=False)
class PriorErrors:
    """The residuals of the priors at one set of poses."""

    pose: np.ndarray
    """``(a, d)`` — ``Log(Z⁻¹ X O)`` per pose prior."""
    position: np.ndarray
    """``(b, r)`` — ``t(X) − z`` per position prior."""


@dataclass(frozen=True, eq=False)
class PriorBlocks:
    """The linearisation of every prior: one gradient and one Hessian block on its vertex."""

    vertex: np.ndarray
    """``(a + b,)`` vertex index of each prior (pose priors first)."""
    gradient: np.ndarray
    """``(a + b, d)`` — ``w JᵀΩe``."""
    hessian: np.ndarray
    """``(a + b, d, d)`` — ``w JᵀΩJ``."""


def prior_errors(poses: np.ndarray, graph) -> PriorErrors:
    """Residuals of ``graph.priors`` at ``poses`` ``(n, k, k)``."""
    priors, group = graph.priors, graph.group
    r = group.space_dim
    at = poses[priors.pose_vertex] @ priors.pose_offsets
    pose = group.log(group.between(priors.pose_measurements, at)) if priors.num_pose else np.zeros((0, group.dim))
    position = poses[priors.position_vertex, :r, r] - priors.position_measurements
    return PriorErrors(pose, position)


def prior_squared_norms(errors: PriorErrors, priors) -> np.ndarray:
    """``(a + b,)`` squared Mahalanobis norms ``eᵀΩe``, pose priors first."""
    pose = np.einsum("ui,uij,uj->u", errors.pose, priors.pose_information, errors.pose)
    position = np.einsum("ui,uij,uj->u", errors.position, priors.position_information, errors.position)
    return np.concatenate([pose, position])


def prior_cost(poses: np.ndarray, graph) -> float:
    """``½ Σ eᵀΩe`` over the priors of ``graph`` at ``poses`` (0 without priors)."""
    if graph.priors is None:
        return 0.0
    return 0.5 * float(np.sum(prior_squared_norms(prior_errors(poses, graph), graph.priors)))


def prior_jacobians(poses: np.ndarray, graph, errors: PriorErrors) -> tuple[np.ndarray, np.ndarray]:
    """``(∂e/∂δ (a, d, d) of the pose priors, ∂e/∂δ (b, r, d) of the position priors)`` (module docstring)."""
    priors, group = graph.priors, graph.group
    r, d = group.space_dim, group.dim
    pose = group.right_jacobian_inverse(errors.pose) @ group.adjoint(group.inverse(priors.pose_offsets))
    selection = np.zeros((r, d))
    selection[np.arange(r), list(group.translation_axes)] = 1.0
    position = poses[priors.position_vertex, :r, :r] @ selection
    return pose, position


def linearize_priors(poses: np.ndarray, graph, errors: PriorErrors, weights: np.ndarray | None = None) -> PriorBlocks:
    """The gradient and Hessian blocks of every prior; ``weights`` ``(a + b,)`` IRLS weights or None."""
    priors = graph.priors
    jacobian_pose, jacobian_position = prior_jacobians(poses, graph, errors)
    parts = [(jacobian_pose, priors.pose_information, errors.pose),
             (jacobian_position, priors.position_information, errors.position)]
    gradient, hessian = [], []
    for jacobian, information, e in parts:
        weighted = np.swapaxes(jacobian, -1, -2) @ information  # JᵀΩ
        gradient.append((weighted @ e[..., None])[..., 0])
        hessian.append(weighted @ jacobian)
    gradient, hessian = np.concatenate(gradient), np.concatenate(hessian)
    if weights is not None:
        gradient *= weights[:, None]
        hessian *= weights[:, None, None]
    return PriorBlocks(np.concatenate([priors.pose_vertex, priors.position_vertex]), gradient, hessian)


def _free(pattern, blocks: PriorBlocks) -> tuple[np.ndarray, np.ndarray]:
    """``(which priors, their block columns)`` for the priors on free vertices (held ones take no step)."""
    column = pattern.variable_of[blocks.vertex]
    keep = column >= 0
    return np.flatnonzero(keep), column[keep]


def add_prior_gradient(pattern, gradient: np.ndarray, blocks: PriorBlocks) -> np.ndarray:
    """``gradient`` ``(dp,)`` with the priors' ``g`` blocks added (in place)."""
    which, column = _free(pattern, blocks)
    d = pattern.block_size
    rows = (d * column[:, None] + np.arange(d)).ravel()
    np.add.at(gradient, rows, blocks.gradient[which].ravel())
    return gradient


def add_prior_hessian(pattern, data: np.ndarray, blocks: PriorBlocks) -> np.ndarray:
    """The lower-triangle CSC ``data`` of H with the priors' diagonal blocks added (in place).

    Entry ``(a, b)``, ``a ≥ b``, of vertex column ``c``'s diagonal block sits at
    ``indptr[d·c + b] + (a − b)``: each scalar column starts with its diagonal entry
    (:mod:`posegraph.solve.sparsity`).
    """
    which, column = _free(pattern, blocks)
    d = pattern.block_size
    rows, cols = np.tril_indices(d)
    positions = np.asarray(pattern.indptr, dtype=np.int64)[d * column[:, None] + cols] + (rows - cols)
    np.add.at(data, positions.ravel(), blocks.hessian[which][:, rows, cols].ravel())
    return data
