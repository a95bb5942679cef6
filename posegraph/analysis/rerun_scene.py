"""The geometry and colours of a pose graph as Rerun draws it, in plain numpy (no Rerun import here).

Everything is in the graph's world frame, metres, right-handed; a 2D graph (``SE2``, poses
``(n, 3, 3)``) is embedded in the plane ``z = 0`` so that it shows in a 3D view seen from above.
Colours are ``(…, 4)`` uint8 RGBA. :mod:`posegraph.analysis.rerun_log` and
:mod:`posegraph.incremental.rerun_replay` log what these functions return.
"""

from __future__ import annotations

import numpy as np

from posegraph.analysis.plot import position_covariances

__all__ = [
    "positions", "headings", "edge_segments", "weight_colours", "chi2_colours", "covariance_ellipsoids",
    "ellipse_outlines", "selected_poses", "FrameBudget", "OUTLIER_WEIGHT", "INLIER_COLOUR", "OUTLIER_COLOUR",
    "INITIAL_COLOUR", "ODOMETRY_COLOUR", "NEW_CLOSURE_COLOUR", "COVARIANCE_COLOUR", "BYTES_PER_POINT",
]

OUTLIER_WEIGHT = 0.5
"""An edge whose final weight is below this is an outlier (as the report's ``outlier_edges``)."""
INITIAL_COLOUR = (150, 150, 150, 255)
"""The start: grey."""
ODOMETRY_COLOUR = (0, 114, 178, 255)
"""An odometry edge of weight 1: blue (Okabe–Ito)."""
INLIER_COLOUR = (0, 158, 115, 255)
"""A loop closure of weight 1: green (Okabe–Ito); weights below 1 fade it towards grey."""
OUTLIER_COLOUR = (213, 94, 0, 170)
"""An edge of weight below :data:`OUTLIER_WEIGHT`: vermilion (Okabe–Ito), a little transparent (outliers
cross the map)."""
NEW_CLOSURE_COLOUR = (230, 159, 0, 255)
"""A loop closure just added by a replay update: orange (Okabe–Ito)."""
COVARIANCE_COLOUR = (204, 121, 167, 255)
"""Uncertainty ellipsoids and ellipses: reddish purple (Okabe–Ito)."""
BYTES_PER_POINT = 12
"""A 3D point in a recording: three float32."""


def positions(poses: np.ndarray) -> np.ndarray:
    """``(n, 3)`` float32 world positions of ``(n, k, k)`` poses (SE(3), Sim(3): ``t``; SE(2): ``(x, y, 0)``)."""
    poses = np.asarray(poses)
    k = poses.shape[-1] - 1
    out = np.zeros(poses.shape[:-2] + (3,), dtype=np.float32)
    out[..., :k] = poses[..., :k, k]
    return out


def headings(poses: np.ndarray, length: float) -> np.ndarray:
    """``(n, 3)`` float32 vectors of ``length`` along each pose's body x axis (its first rotation column,
    normalised: Sim(3)'s scale dropped), in the world frame."""
    poses = np.asarray(poses)
    k = poses.shape[-1] - 1
    axis = np.zeros(poses.shape[:-2] + (3,), dtype=np.float64)
    axis[..., :k] = poses[..., :k, 0]
    norms = np.linalg.norm(axis, axis=-1, keepdims=True)
    return (length * axis / np.where(norms > 0, norms, 1.0)).astype(np.float32)


def edge_segments(points: np.ndarray, edge_from: np.ndarray, edge_to: np.ndarray) -> np.ndarray:
    """``(m, 2, 3)`` the segment of each edge between its vertices' ``points (n, 3)``."""
    return np.stack([points[edge_from], points[edge_to]], axis=1)


def weight_colours(weights: np.ndarray, full: tuple = INLIER_COLOUR) -> np.ndarray:
    """``(m, 4)`` colours of edges by their final robust weight ``w ∈ [0, 1]``: ``full`` at 1, faded
    linearly towards :data:`INITIAL_COLOUR` as ``w`` falls to :data:`OUTLIER_WEIGHT`, and
    :data:`OUTLIER_COLOUR` below it."""
    w = np.clip(np.asarray(weights, dtype=np.float64), 0.0, 1.0)
    t = np.clip((w - OUTLIER_WEIGHT) / (1.0 - OUTLIER_WEIGHT), 0.0, 1.0)[:, None]
    mixed = t * np.asarray(full, np.float64) + (1 - t) * np.asarray(INITIAL_COLOUR, np.float64)
    colours = np.rint(mixed).astype(np.uint8)
    colours[w < OUTLIER_WEIGHT] = OUTLIER_COLOUR
    return colours


_HEAT = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64)
"""Five stops of viridis, low to high."""


def chi2_colours(chi2: np.ndarray, dimension: int) -> np.ndarray:
    """``(m, 4)`` viridis colours of per-edge ``χ²`` on a log scale: ``χ²/d`` from 0.1 (dark) to 100
    (yellow), ``d`` the residual's dimension (an edge that fits its information has ``χ² ≈ d``)."""
    per_dof = np.maximum(np.asarray(chi2, dtype=np.float64) / dimension, 1e-300)
    t = np.clip((np.log10(per_dof) + 1.0) / 3.0, 0.0, 1.0) * (len(_HEAT) - 1)
    low = np.minimum(t.astype(np.int64), len(_HEAT) - 2)
    frac = (t - low)[:, None]
    rgb = (1 - frac) * _HEAT[low] + frac * _HEAT[low + 1]
    return np.concatenate([np.rint(rgb), np.full((len(t), 1), 255.0)], axis=1).astype(np.uint8)


def selected_poses(n: int, count: int) -> np.ndarray:
    """At most ``count`` indices out of ``n``, evenly spread, the last included."""
    if n <= count:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, count).round().astype(np.int64))


def covariance_ellipsoids(poses: np.ndarray, covariances: np.ndarray, sigma: float = 1.0):
    """``(centres (n, 3), half_sizes (n, 3), quaternions (n, 4) xyzw)`` of the ``sigma``-σ ellipsoid of each
    SE(3) pose's position: half-sizes ``sigma·√λ`` along the eigenvectors of :func:`posegraph.analysis.plot.position_covariances`."""
    from posegraph.lie import so3

    poses, covariances = np.asarray(poses, np.float64), np.asarray(covariances, np.float64)
    eigenvalues, eigenvectors = np.linalg.eigh(position_covariances(poses, covariances))
    flip = np.linalg.det(eigenvectors) < 0
    eigenvectors[flip, :, 0] *= -1  # a rotation, not a reflection
    half_sizes = sigma * np.sqrt(np.clip(eigenvalues, 0.0, None))
    return positions(poses), half_sizes.astype(np.float32), so3.to_quaternion(eigenvectors).astype(np.float32)


def ellipse_outlines(poses: np.ndarray, covariances: np.ndarray, sigma: float = 1.0, segments: int = 32) -> np.ndarray:
    """``(n, segments + 1, 3)`` closed outlines at ``z = 0`` of the ``sigma``-σ ellipse of each SE(2) pose's
    position: ``c + sigma·L u`` for unit vectors ``u``, ``L Lᵀ`` the world position covariance."""
    poses, covariances = np.asarray(poses, np.float64), np.asarray(covariances, np.float64)
    eigenvalues, eigenvectors = np.linalg.eigh(position_covariances(poses, covariances))
    root = eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))[:, None, :]  # (n, 2, 2)
    angle = np.linspace(0.0, 2 * np.pi, segments + 1)
    circle = np.stack([np.cos(angle), np.sin(angle)])  # (2, segments + 1)
    outline = np.zeros((len(poses), segments + 1, 3))
    outline[..., :2] = positions(poses)[:, None, :2] + sigma * np.swapaxes(root @ circle, -1, -2)
    return outline.astype(np.float32)


class FrameBudget:
    """Which frames of an unknown-length sequence to record, so that their bytes stay under ``budget``.

    Frames of ``frame_bytes`` each: the first half of the budget takes every frame, the next quarter
    every second, the next eighth every fourth, …, so any number of frames fits and the early ones
    (where an optimiser moves most) are densest. :meth:`take` is called once per frame, in order.
    """

    def __init__(self, budget: int, frame_bytes: int) -> None:
        self.capacity = max(int(budget // max(frame_bytes, 1)), 0)
        self.stride = 1
        self.stage_left = self.capacity // 2
        self.seen = 0
        self.taken = 0

    def take(self) -> bool:
        """Whether to record the next frame."""
        self.seen += 1
        if self.capacity == 0:
            return False
        if self.stage_left == 0:
            self.stride *= 2
            self.stage_left = max(self.capacity // (2 * self.stride), 1)
        if (self.seen - 1) % self.stride:
            return False
        if self.taken >= self.capacity:
            return False
        self.stage_left -= 1
        self.taken += 1
        return True
