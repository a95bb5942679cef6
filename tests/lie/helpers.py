"""Shared inputs and finite differences for the Lie-core tests."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from posegraph.lie import se2, se3, sim3

# The rotation angles every identity is checked at (issue 2), besides random inputs.
EDGE_ANGLES = (0.0, 1e-12, 1e-8, 1e-4, 1.0, np.pi - 1e-6, np.pi)
BATCH_SHAPES = ((), (1,), (3, 1, 2))


def unit_vectors(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    u = rng.normal(size=shape + (3,))
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def rotation_vectors(rng, shape, max_angle=np.pi) -> np.ndarray:
    """Rotation vectors with uniformly random axes and angles in [0, max_angle]."""
    return unit_vectors(rng, shape) * rng.uniform(0.0, max_angle, size=shape + (1,))


def tangents(rng, shape, max_angle=np.pi, translation_scale=2.0) -> np.ndarray:
    """se(3) tangents [ω; v]: random-axis rotations up to ``max_angle``, v ~ N(0, scale²)."""
    return np.concatenate([rotation_vectors(rng, shape, max_angle), translation_scale * rng.normal(size=shape + (3,))], axis=-1)


def tangents_at_angle(rng, angle: float, n: int = 16) -> np.ndarray:
    """``n`` tangents with |ω| = angle (random axes, random v)."""
    return np.concatenate([angle * unit_vectors(rng, (n,)), rng.normal(size=(n, 3))], axis=-1)


def poses(rng, shape, max_angle=np.pi) -> np.ndarray:
    return se3.exp(tangents(rng, shape, max_angle))


def central_difference(f, x0: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """Jacobian ``(..., m, k)`` of a batched ``f: (..., k) -> (..., m)`` at ``x0 (..., k)``.

    All 2k evaluations go through one batched call of ``f``.
    """
    k = x0.shape[-1]
    offsets = step * np.eye(k)
    plus = f(x0[..., None, :] + offsets)  # (..., k, m): row j is f(x0 + h e_j)
    minus = f(x0[..., None, :] - offsets)
    return np.swapaxes(plus - minus, -1, -2) / (2.0 * step)


# --- SE(2) inputs and the groups the shared tests run over -----------------------------------


def se2_tangents(rng, shape, max_angle=np.pi, translation_scale=2.0) -> np.ndarray:
    """se(2) tangents [v_x, v_y, ω]: ω uniform in [−max_angle, max_angle], v ~ N(0, scale²)."""
    w = rng.uniform(-max_angle, max_angle, size=shape + (1,))
    return np.concatenate([translation_scale * rng.normal(size=shape + (2,)), w], axis=-1)


def se2_tangents_at_angle(rng, angle: float, n: int = 16) -> np.ndarray:
    """``n`` tangents with |ω| = angle (random signs, random v)."""
    sign = np.where(rng.uniform(size=(n, 1)) < 0.5, -1.0, 1.0)
    sign[0] = 1.0  # +angle and −angle both present whenever n ≥ 2
    sign[-1] = -1.0
    return np.concatenate([rng.normal(size=(n, 2)), angle * sign], axis=-1)


@dataclass(frozen=True)
class GroupCase:
    """One group the shared tests run over: its module, sizes and random inputs."""

    name: str
    module: object
    dim: int
    """Tangent dimension."""
    matrix_size: int
    """Group elements are ``(..., matrix_size, matrix_size)``; points have ``matrix_size − 1`` components."""
    random_tangents: Callable
    """``(rng, shape, max_angle=π) -> (*shape, dim)``."""
    tangents_at_angle: Callable
    """``(rng, angle, n) -> (n, dim)`` with rotation angle ``angle``."""

    @property
    def point_dim(self) -> int:
        return self.matrix_size - 1

    def poses(self, rng, shape, max_angle=np.pi) -> np.ndarray:
        return self.module.exp(self.random_tangents(rng, shape, max_angle))

    def at_angle(self, angle, n=16, seed=0) -> np.ndarray:
        return self.tangents_at_angle(np.random.default_rng(seed), angle, n)


def sim3_tangents(rng, shape, max_angle=np.pi, translation_scale=2.0, log_scale=0.5) -> np.ndarray:
    """sim(3) tangents [ω; υ; λ]: an se(3) tangent and a log-scale λ ~ N(0, log_scale²)."""
    return np.concatenate([tangents(rng, shape, max_angle, translation_scale), log_scale * rng.normal(size=shape + (1,))], axis=-1)


def sim3_tangents_at_angle(rng, angle: float, n: int = 16) -> np.ndarray:
    """``n`` sim(3) tangents with |ω| = angle; λ = 0 and λ near 0 among them (their own branches)."""
    lam = 0.5 * rng.normal(size=(n, 1))
    lam[:4, 0] = (0.0, 1e-12, 1e-6, -1e-3)[: min(n, 4)]
    return np.concatenate([tangents_at_angle(rng, angle, n), lam], axis=-1)


SE3_CASE = GroupCase("se3", se3, 6, 4, tangents, tangents_at_angle)
SE2_CASE = GroupCase("se2", se2, 3, 3, se2_tangents, se2_tangents_at_angle)
SIM3_CASE = GroupCase("sim3", sim3, 7, 4, sim3_tangents, sim3_tangents_at_angle)
GROUP_CASES = (SE3_CASE, SE2_CASE, SIM3_CASE)
