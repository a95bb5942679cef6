"""Initial landmark positions given the poses: each point by weighted linear least squares over its measurements.

Shapes: ``n`` poses ``(n, k, k)``, ``L`` landmarks ``(L, s)`` (``s = k − 1``), a family of ``q``
measurements (:class:`posegraph.model.landmarks.Observations`). With the poses known every
measurement is, exactly or after a change of variables, *affine* in its point, ``e ≈ A p − b``, so
each landmark's estimate solves its own weighted normal equations

    N_l p_l = g_l,    N_l = Σ_k A_kᵀ W_k A_k,    g_l = Σ_k A_kᵀ W_k b_k      (sum over the measurements of l),

accumulated for all landmarks at once (``np.add.at``) and solved as one batch of ``s × s`` systems.
With the sensor pose ``S = X_i O`` (rotation ``R_s = R_i R_O``, translation ``t_s = R_i t_O + t_i``):

* ``"position"``: ``e = R_sᵀ(p − t_s) − z``, so ``A = R_sᵀ``, ``b = R_sᵀ t_s + z``, ``W = Ω``; i.e.
  ``AᵀWA = R_s Ω R_sᵀ`` and ``AᵀWb = R_s Ω R_sᵀ (t_s + R_s z)``: the world point ``t_s + R_s z``
  weighted by Ω turned into the world frame.
* ``"prior"``: ``e = p − z``: ``A = I``, ``b = z``, ``W = Ω``.
* ``"bearing_range"`` (2D): the measured point in the sensor frame ``y = z_r [cos z_θ, sin z_θ]``
  makes it a position measurement with ``W = J⁻ᵀ Ω J⁻¹``, ``J = ∂y/∂(θ, r) = [[−z_r sin z_θ, cos z_θ],
  [z_r cos z_θ, sin z_θ]]`` (Ω carried to first order; ``|z_r|`` is floored at 1e-9).
* ``"bearing"`` (2D): the point is on the ray from ``t_s`` along ``u = R_s [cos z, sin z]``: its
  distance to the ray's line is ``nᵀ(p − t_s)`` with the normal ``n = R_s [−sin z, cos z]``, so
  ``A = nᵀ``, ``b = nᵀ t_s``; the bearing's error is that distance over the range ρ, hence
  ``W = Ω_θ/ρ²``. ρ is unknown before the solve: a first pass takes ``W = Ω_θ/ρ₀²`` with ρ₀ the
  mean distance from the landmark's sensors to its other measurements' points (1 if it has none),
  and a second pass ``W = Ω_θ/ρ_k²`` at the first estimate (Gauss–Newton's weight there).

Both passes are exact without noise: the true point zeroes every term. A landmark whose ``N_l``
is singular or ill-conditioned (``λ_min ≤ 1e-9 λ_max``: no measurement, one bearing, parallel rays)
is *undetermined*: it gets the mean of its measurements' guesses (the world point of a position or
bearing-range measurement, ``z`` of a prior, the point at unit range along a bearing's ray), or, if
it has no measurement, its given position. Fixed landmarks keep their given positions (and are never
undetermined).
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph

__all__ = ["initialize_landmarks", "CONDITION_FLOOR"]

CONDITION_FLOOR = 1e-9
"""A landmark's normal matrix counts as singular when ``λ_min ≤ CONDITION_FLOOR · λ_max`` (or ``λ_max = 0``)."""


def _sensor(poses: np.ndarray, family) -> tuple[np.ndarray, np.ndarray]:
    """``R_s (q, s, s)``, ``t_s (q, s)`` of the sensor poses ``X_i O`` (``O`` the identity if no offsets)."""
    S = poses[family.pose]
    if family.offsets is not None:
        S = S @ np.asarray(family.offsets, dtype=np.float64)
    s = S.shape[-1] - 1
    return S[:, :s, :s], S[:, :s, s]


def _unit(angle: np.ndarray) -> np.ndarray:
    """``(q, 2)`` unit vectors ``[cos a, sin a]``."""
    return np.stack([np.cos(angle), np.sin(angle)], axis=1)


def _rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R v`` for ``R (q, s, s)``, ``v (q, s)``."""
    return np.einsum("qij,qj->qi", R, v)


def range_point_information(z: np.ndarray, information: np.ndarray) -> np.ndarray:
    """``J⁻ᵀ Ω J⁻¹`` ``(q, 2, 2)``: the information of ``y = r [cos θ, sin θ]`` from that of ``(θ, r)``."""
    theta, r = z[:, 0], np.where(np.abs(z[:, 1]) < 1e-9, 1e-9, z[:, 1])
    J = np.empty((len(z), 2, 2))
    J[:, 0, 0], J[:, 0, 1] = -r * np.sin(theta), np.cos(theta)
    J[:, 1, 0], J[:, 1, 1] = r * np.cos(theta), np.sin(theta)
    J_inv = np.linalg.inv(J)
    return np.swapaxes(J_inv, 1, 2) @ information @ J_inv


def _terms(family, poses: np.ndarray, estimate: np.ndarray | None, range_guess: np.ndarray):
    """One family's ``(AᵀWA (q, s, s), AᵀWb (q, s), guess (q, s))`` (module docstring).

    ``estimate`` ``(L, s)`` the first pass's points (None in the first pass), ``range_guess`` ``(L,)`` ρ₀.
    """
    z, information = np.asarray(family.measurements, np.float64), np.asarray(family.information, np.float64)
    if family.kind == "prior":
        return information, (information @ z[:, :, None])[:, :, 0], z
    R, t = _sensor(poses, family)
    if family.kind == "bearing":
        n = _rotate(R, _unit(z[:, 0] + np.pi / 2))  # R_s [−sin z, cos z]
        if estimate is None:
            rho2 = range_guess[family.landmark] ** 2
        else:
            rho2 = np.maximum(np.sum((estimate[family.landmark] - t) ** 2, axis=1), 1e-18)
        weight = information[:, 0, 0] / rho2
        normal = weight[:, None, None] * n[:, :, None] * n[:, None, :]
        return normal, (normal @ t[:, :, None])[:, :, 0], t + _rotate(R, _unit(z[:, 0]))
    if family.kind == "bearing_range":
        y, information = z[:, 1:2] * _unit(z[:, 0]), range_point_information(z, information)
    else:
        y = z
    normal = R @ information @ np.swapaxes(R, 1, 2)
    point = t + _rotate(R, y)
    return normal, (normal @ point[:, :, None])[:, :, 0], point


def _accumulate(graph: PoseGraph, poses, estimate, range_guess):
    """Per-landmark sums ``N (L, s, s)``, ``g (L, s)``, guesses' sum ``(L, s)`` and count ``(L,)``."""
    landmarks = graph.landmarks
    L, s = landmarks.count, landmarks.space_dim
    N, g, guess, count = np.zeros((L, s, s)), np.zeros((L, s)), np.zeros((L, s)), np.zeros(L)
    for family in landmarks.observations:  # ≤ 4 families
        normal, rhs, point = _terms(family, poses, estimate, range_guess)
        np.add.at(N, family.landmark, normal)
        np.add.at(g, family.landmark, rhs)
        np.add.at(guess, family.landmark, point)
        np.add.at(count, family.landmark, 1.0)
    return N, g, guess, count


def _solve(N: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(p (L, s), determined (L,))``: ``N p = g`` where ``λ_min(N) > CONDITION_FLOOR · λ_max(N) > 0``, else NaN."""
    scale = np.abs(N).max(axis=(1, 2), initial=0.0)
    safe = np.where(scale > 0, scale, 1.0)[:, None, None]
    eigenvalues = np.linalg.eigvalsh(N / safe)  # symmetric by construction (up to rounding)
    determined = (scale > 0) & (eigenvalues[:, 0] > CONDITION_FLOOR * eigenvalues[:, -1])
    p = np.full(g.shape, np.nan)
    if determined.any():
        p[determined] = np.linalg.solve(N[determined], g[determined][:, :, None])[:, :, 0]
    return p, determined


def _range_guess(graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """ρ₀ ``(L,)``: the mean distance from a landmark's bearing sensors to the mean of its other
    measurements' guesses (module docstring); 1 where it has no other measurement."""
    L, s = graph.landmarks.count, graph.landmarks.space_dim
    centre, other = np.zeros((L, s)), np.zeros(L)
    distance, seen = np.zeros(L), np.zeros(L)
    for family in graph.landmarks.observations:  # ≤ 4 families
        if family.kind != "bearing":
            np.add.at(centre, family.landmark, _terms(family, poses, None, None)[2])
            np.add.at(other, family.landmark, 1.0)
    centre /= np.maximum(other, 1.0)[:, None]
    for family in graph.landmarks.observations:
        if family.kind == "bearing":
            _, t = _sensor(poses, family)
            np.add.at(distance, family.landmark, np.linalg.norm(centre[family.landmark] - t, axis=1))
            np.add.at(seen, family.landmark, 1.0)
    rho = distance / np.maximum(seen, 1.0)
    return np.where((other > 0) & (rho > 1e-9), rho, 1.0)


def initialize_landmarks(graph: PoseGraph, poses: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Landmark positions given the poses: ``(points (L, s), undetermined (L,) bool)`` (module docstring).

    ``poses`` ``(n, k, k)`` (the graph's own if None). A graph without landmarks gives ``(0, s)`` and
    ``(0,)`` arrays (``s`` from the group).
    """
    poses = np.asarray(graph.poses if poses is None else poses, dtype=np.float64)
    landmarks = graph.landmarks
    if landmarks is None:
        return np.zeros((0, graph.group.space_dim)), np.zeros(0, dtype=bool)
    N, g, guess, count = _accumulate(graph, poses, None, _range_guess(graph, poses))
    if any(f.kind == "bearing" for f in landmarks.observations):  # again with Gauss–Newton's weights at the estimate
        first, determined = _solve(N, g)
        estimate = np.where(determined[:, None], first, guess / np.maximum(count, 1.0)[:, None])
        N, g, guess, count = _accumulate(graph, poses, estimate, None)
    points, determined = _solve(N, g)
    fallback = np.where(count[:, None] > 0, guess / np.maximum(count, 1.0)[:, None], landmarks.positions)
    points = np.where(determined[:, None], points, fallback)
    fixed = np.asarray(landmarks.fixed, dtype=bool)
    points[fixed] = landmarks.positions[fixed]
    return points, ~determined & ~fixed
