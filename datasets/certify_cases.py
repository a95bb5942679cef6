"""Hard cases for the certificate: noisy lattice grids (2D and 3D) with scaled information, and a
ring with one wrong loop closure — the graphs of issue #32, on which a certificate whose test is not
scale-invariant says "certified" at a point that is not the global optimum.

* :func:`lattice` — a robot walking a snake path through an ``side^dim`` lattice (odometry along the
  path), every other pair of lattice neighbours a loop closure; each measurement is the true
  relative pose times ``Exp(δ)`` with ``δ``'s rotation part ~ N(0, rotation_noise²) and its
  translation part ~ N(0, translation_noise²) per axis; information ``scale · diag(1/σ_r², 1/σ_t²)``
  (σ the noise, 1 where the noise is 0). ``scale`` multiplies every edge's information: the minimisers
  do not change, every cost is multiplied by ``scale``.
* :func:`ring_with_wrong_closure` — ``n`` SE(2) poses on a circle, odometry around it (closing the
  loop) with little noise, and one loop closure across the ring whose measured rotation is off by
  ``angle`` radians.

Written as g2o files by ``python -m datasets.certify_cases OUT_DIR`` (the issue's nine cases).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.lie.group import SE2, SE3

__all__ = ["lattice", "ring_with_wrong_closure", "ISSUE_CASES"]


def _snake_path(side: int, dim: int) -> np.ndarray:
    """``(side**dim, dim)`` lattice points in boustrophedon order (consecutive points are neighbours)."""
    points = [np.zeros(0, dtype=np.int64)]
    for _ in range(dim):
        grown = []
        for k in range(side):
            block = points if k % 2 == 0 else points[::-1]
            grown += [np.append(p, k) for p in block]
        points = grown
    return np.array(points)[:, ::-1]


def _lattice_edges(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(edge_from, edge_to)``: the path's odometry, then every other non-consecutive lattice neighbour pair."""
    index = {tuple(p): k for k, p in enumerate(points)}
    n, dim = points.shape
    pairs = [(k, k + 1) for k in range(n - 1)]
    closures = []
    for k, p in enumerate(points):
        for axis in range(dim):
            q = p.copy()
            q[axis] += 1
            other = index.get(tuple(q))
            if other is not None and abs(other - k) > 1:
                closures.append((min(k, other), max(k, other)))
    pairs += sorted(closures)[::2]
    edges = np.array(pairs, dtype=np.int64)
    return edges[:, 0], edges[:, 1]


def _noisy_graph(truth, edge_from, edge_to, rotation_noise, translation_noise, scale, rng, group) -> PoseGraph:
    """The graph of ``truth`` with measurements ``X_i⁻¹ X_j Exp(δ)`` and isotropic information (module docstring)."""
    m, rot, tra = edge_from.size, list(group.rotation_axes), list(group.translation_axes)
    sigma = np.zeros(group.dim)
    sigma[rot], sigma[tra] = rotation_noise, translation_noise
    exact = np.linalg.inv(truth[edge_from]) @ truth[edge_to]
    measurements = exact @ group.exp(sigma * rng.normal(size=(m, group.dim)))
    precision = scale / np.where(sigma > 0, sigma, 1.0) ** 2
    information = np.broadcast_to(np.diag(precision), (m, group.dim, group.dim)).copy()
    start = np.empty_like(truth)
    start[0] = truth[0]
    for k in range(1, truth.shape[0]):  # odometry composed: a generator run once per file
        start[k] = start[k - 1] @ measurements[k - 1]
    return PoseGraph(ids=np.arange(truth.shape[0], dtype=np.int64), poses=start, edge_from=edge_from,
                     edge_to=edge_to, measurements=measurements, information=information, group=group)  # fmt: skip


def lattice(dim: int, side: int, rotation_noise: float, translation_noise: float, scale: float = 1.0,
            seed: int = 0) -> PoseGraph:  # fmt: skip
    """A ``side^dim``-pose lattice graph in 2D (SE(2)) or 3D (SE(3)), random orientations (module docstring)."""
    rng = np.random.default_rng(seed)
    group = SE3 if dim == 3 else SE2
    points = _snake_path(side, dim).astype(np.float64)
    n = points.shape[0]
    if dim == 3:
        q = rng.normal(size=(n, 4))
        from posegraph.lie import so3

        rotations = so3.from_quaternion(q / np.linalg.norm(q, axis=1, keepdims=True))
    else:
        rotations = SE2.rotations.exp(rng.uniform(-np.pi, np.pi, (n, 1)))
    truth = np.zeros((n, dim + 1, dim + 1))
    truth[:, :dim, :dim], truth[:, :dim, dim], truth[:, dim, dim] = rotations, points, 1.0
    edge_from, edge_to = _lattice_edges(points.astype(np.int64))
    return _noisy_graph(truth, edge_from, edge_to, rotation_noise, translation_noise, scale, rng, group)


def ring_with_wrong_closure(n: int = 1000, angle: float = 3.1, noise: float = 0.01, seed: int = 0) -> PoseGraph:
    """``n`` SE(2) poses on a circle of circumference ``n``, odometry around it and one closure from 0 to n/2
    rotated by ``angle`` (module docstring); noise σ on every axis, information 1/σ²."""
    rng = np.random.default_rng(seed)
    heading = 2 * np.pi * np.arange(n) / n
    radius = n / (2 * np.pi)
    tangent = np.stack([radius * np.sin(heading), radius * (1 - np.cos(heading)), heading], axis=1)
    truth = SE2.exp(np.zeros((n, 3)))
    truth[:, :2, :2] = SE2.rotations.exp(heading[:, None])
    truth[:, :2, 2] = tangent[:, :2]
    edge_from = np.r_[np.arange(n), 0].astype(np.int64)
    edge_to = np.r_[(np.arange(n) + 1) % n, n // 2].astype(np.int64)
    graph = _noisy_graph(truth, edge_from, edge_to, noise, noise, 1.0, rng, SE2)
    graph.measurements[-1] = graph.measurements[-1] @ SE2.exp(np.array([0.0, 0.0, angle]))
    return graph


ISSUE_CASES = {
    "grid3d_512_noise0.5_x1e-4": lambda: lattice(3, 8, 0.5, 0.5, 1e-4),
    "grid3d_1000_noise0.3_x1e-4": lambda: lattice(3, 10, 0.3, 0.3, 1e-4),
    "grid2d_400_noise0.5_x1e-3": lambda: lattice(2, 20, 0.5, 0.5, 1e-3),
    "ring2d_1000_wrong_closure": lambda: ring_with_wrong_closure(1000, 3.1),
    "grid2d_900_noise1": lambda: lattice(2, 30, 1.0, 1.0),
    "grid3d_512_noise1": lambda: lattice(3, 8, 1.0, 1.0),
    "grid3d_512_noise0.7": lambda: lattice(3, 8, 0.7, 0.7),
    "grid3d_1000_noise1": lambda: lattice(3, 10, 1.0, 1.0),
    "grid2d_400_noise1.5": lambda: lattice(2, 20, 1.5, 1.5),
}
"""The issue's cases by name (sizes, noise and information scale as it describes them)."""


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description="write the certificate's hard cases as g2o files")
    parser.add_argument("out_dir", type=Path)
    args = parser.parse_args(argv)
    from posegraph.io.g2o import write_g2o

    args.out_dir.mkdir(parents=True, exist_ok=True)
    for name, make in ISSUE_CASES.items():
        write_g2o(args.out_dir / f"{name}.g2o", make())


if __name__ == "__main__":
    main()
