"""Helpers shared by the solver tests: gtsam's view of a g2o file, aligned with ours."""

from __future__ import annotations

import numpy as np
import pytest


def gtsam_graph(path, graph=None):
    """``(graph, values)`` as ``gtsam.readG2o(path, is3D=True)`` builds them (skips without gtsam).

    For a file whose information the reader repairs (``tests.conftest.INDEFINITE_INFORMATION``),
    pass our ``graph`` of it: gtsam then gets its factors with the repaired matrices
    (:func:`posegraph.crosscheck.gtsam_bridge.graph_to_gtsam`), since ``readG2o`` would replace each indefinite
    matrix by RᵀR of a partial Cholesky factor (tests/io/test_against_gtsam.py compares the rest).
    """
    gtsam = pytest.importorskip("gtsam")
    factors, values = gtsam.readG2o(str(path), True)
    if graph is not None and _needs_repair(path):
        from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam

        factors = graph_to_gtsam(graph)
    return factors, values


def _needs_repair(path) -> bool:
    from pathlib import Path

    from tests.conftest import INDEFINITE_INFORMATION

    return Path(path).name in INDEFINITE_INFORMATION


def values_from_poses(ids, poses):
    """``gtsam.Values`` with ``Pose3(poses[k])`` at key ``ids[k]`` (gtsam.readG2o keys by vertex id)."""
    import gtsam

    values = gtsam.Values()
    for key, pose in zip(np.asarray(ids).tolist(), poses):
        values.insert(int(key), gtsam.Pose3(pose))
    return values


def perturbed_poses(poses, rng, rotation_scale=1.0, translation_scale=1.0):
    """Poses times a random SE(3) motion (large rotations included), without the project's Lie code;
    SE(2) poses ``(n, 3, 3)`` times a random planar motion (angle about z, translation in the plane)."""
    from scipy.spatial.transform import Rotation

    n = poses.shape[0]
    if poses.shape[-1] == 3:
        angle = rng.normal(size=n) * rotation_scale
        motion = np.tile(np.eye(3), (n, 1, 1))
        motion[:, :2, :2] = np.stack([np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle)], -1).reshape(n, 2, 2)
        motion[:, :2, 2] = rng.normal(size=(n, 2)) * translation_scale
        return poses @ motion
    motion = np.tile(np.eye(4), (n, 1, 1))
    motion[:, :3, :3] = Rotation.from_rotvec(rng.normal(size=(n, 3)) * rotation_scale).as_matrix()
    motion[:, :3, 3] = rng.normal(size=(n, 3)) * translation_scale
    return poses @ motion


def read_shared_file(path):
    """``read_g2o(path)``; with ``repair_information=True`` for the files that need it
    (``tests.conftest.INDEFINITE_INFORMATION``: cubicle.g2o, which the reader refuses by default)."""
    from posegraph.io.g2o import read_g2o

    return read_g2o(path, repair_information=_needs_repair(path))
