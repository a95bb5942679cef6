"""How an edge's information Ω weighs the initialisers' linear problems.

Write an edge's residual as ``e = [δ; v] = Log(Z⁻¹ Xi⁻¹ Xj)`` with cost ``½ eᵀ Ω e`` and
blocks ``Ω = [[Ω_ωω, Ω_ωv], [Ω_vω, Ω_vv]]`` — the rotation and translation blocks, taken at the
group's ``rotation_axes`` and ``translation_axes`` (SE(3)'s ``[ω; v]``: 3 + 3; SE(2)'s
``[v_x, v_y, ω]``: 1 + 2, the rotation block then being the scalar ``Ω_θθ``).

Rotation weight (chordal relaxation)
    The chordal term of an edge is ``w ‖R_j − R_i R_z‖_F²``. With
    ``R_zᵀ R_iᵀ R_j = Exp(δ)`` and ``θ = |δ|`` it equals ``w ‖Exp(δ) − I‖_F² = 8 w sin²(θ/2)
    ≈ 2 w θ²``: it weighs every rotation axis alike. We take

        ``w = tr(Ω_ωω) / 3``   (in 2D: ``w = Ω_θθ``),

    the mean of ``uᵀ Ω_ωω u`` over unit axes ``u`` — the chordal term then equals the true
    rotational cost averaged over the direction of the error (for ``Ω_ωω = κ I`` it equals it to
    second order in θ, up to the common factor 4, which does not move the minimiser). The trace needs no inverse or
    factorisation, so it is defined for every information a file can hold, including
    ill-conditioned or slightly indefinite ones, and an edge whose rotation is known tightly about
    two axes and loosely about the third keeps a large weight (the smallest eigenvalue or
    ``3 / tr(Ω_ωω⁻¹)`` would let the one weak axis erase it). ``docs/initialisation.md`` compares
    the alternatives on the benchmark graphs.

Translation weight
    Given the rotations, ``δ`` is known and ``v`` is affine in the translations, so the edge cost is
    an exact quadratic in them: the full ``Ω_vv`` (3×3, or 2×2 in 2D) (and the coupling ``Ω_vω``) is used as is,
    see :func:`posegraph.init.chordal.translations_given_rotations`.

Floors
    Weights are made strictly positive so that every linear system stays definite whatever the
    file says: rotation weights below ``WEIGHT_FLOOR × max(w)`` are raised to it, and the
    eigenvalues of each ``Ω_vv`` below ``WEIGHT_FLOOR ×`` the largest eigenvalue of any ``Ω_vv``.
    Such an edge then barely influences the result, which is what its information says.
"""

from __future__ import annotations

import numpy as np

from posegraph.lie.group import SE3, LieGroup

__all__ = ["WEIGHT_FLOOR", "rotation_weights", "translation_information"]

WEIGHT_FLOOR = 1e-12
"""Relative floor of the weights. Legitimate graphs span ~1e-2..1e7 (ratio 1e-9); 1e-12 stays below
that, and above double precision's 1e-16 so the Cholesky factorisation still sees a positive pivot."""


def rotation_weights(information: np.ndarray, group: LieGroup = SE3) -> np.ndarray:
    """Scalar chordal weights ``w = tr(Ω_ωω)/dim ω``, floored; ``information`` ``(m,d,d)`` → ``(m,)``."""
    information = np.asarray(information, dtype=np.float64)
    axes = group.rotation_block
    weights = np.trace(information[:, axes, axes], axis1=1, axis2=2) / len(group.rotation_axes)
    if weights.size == 0:
        return weights
    largest = float(weights.max())
    if not largest > 0.0:
        # No edge carries rotational information: every edge counts the same.
        return np.ones_like(weights)
    return np.maximum(weights, WEIGHT_FLOOR * largest)


def translation_information(information: np.ndarray, group: LieGroup = SE3) -> np.ndarray:
    """The ``(m,r,r)`` translational blocks ``Ω_vv``, symmetrised, eigenvalues floored."""
    information = np.asarray(information, dtype=np.float64)
    axes = group.translation_block
    block = information[:, axes, axes]
    block = 0.5 * (block + block.transpose(0, 2, 1))
    if block.shape[0] == 0:
        return block
    # Fast path, without the eigendecomposition (~2.5 ms on parking-garage's 6,275 edges): the
    # largest trace bounds every eigenvalue from above, so when each block minus that bound's floor
    # still has a Cholesky factor, every eigenvalue is above the floor and nothing is clipped.
    traces = np.trace(block, axis1=1, axis2=2)
    bound = float(traces.max())
    if bound > 0.0 and np.isfinite(bound):
        try:
            np.linalg.cholesky(block - (WEIGHT_FLOOR * bound) * np.eye(len(group.translation_axes)))
            return block
        except np.linalg.LinAlgError:
            pass
    eigenvalues, eigenvectors = np.linalg.eigh(block)
    largest = float(eigenvalues[:, -1].max())
    floor = WEIGHT_FLOOR * largest if largest > 0.0 else 1.0
    if eigenvalues[:, 0].min() >= floor:
        return block
    clipped = np.maximum(eigenvalues, floor)
    return (eigenvectors * clipped[:, None, :]) @ eigenvectors.transpose(0, 2, 1)
