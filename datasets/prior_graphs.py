"""Pose graphs with priors written by g2o itself (g2opy): the hidden-style verification graphs of issue #27.

    python datasets/prior_graphs.py OUT_DIR [--datasets ../shared/datasets] [--seed 0]

Writes, into ``OUT_DIR`` (outside the repository: the files are generated, never committed):

* ``sphere2500-priors.g2o`` — sphere2500 as g2o loads it, plus ``EDGE_SE3_XYZ_PRIOR`` on every
  25th vertex (GPS-like, σ = 0.5 m) and ``EDGE_SE3_PRIOR`` on every 250th (σ = 0.05 rad, 0.2 m),
  every other pose prior through a non-identity ``PARAMS_SE3OFFSET`` (a sensor mounted off the
  body frame: the prior measures ``X·O``);
* ``intel-priors.g2o`` — intel plus ``EDGE_PRIOR_SE2_XY`` on every 25th vertex (σ = 0.2 m) and
  ``EDGE_PRIOR_SE2`` on every 250th (σ = 0.02 rad, 0.1 m).

The priors measure the graph's optimum (posegraph's, without priors) moved by a random rigid
motion of the world, with Gaussian noise of those σ, and carry the matching information
``diag(1/σ²)``: a graph whose priors, not its first vertex, fix where it lies. The files are made
and saved by g2o (``SparseOptimizer.load`` / ``add_parameter`` / ``add_edge`` / ``save``), so their
layout is g2o's own. ``benchmarks/verify_priors.py`` optimises them against gtsam.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

POSITION_EVERY, POSE_EVERY = 25, 250
"""A position prior on every 25th vertex, a pose prior on every 250th (ids 0, 25, …; 0, 250, …)."""
SIGMAS = {
    3: {"position": 0.5, "rotation": 0.05, "translation": 0.2},
    2: {"position": 0.2, "rotation": 0.02, "translation": 0.1},
}
"""Noise of the priors (m, rad) per space dimension; their information is ``diag(1/σ²)``."""


def reference_poses(path: str, rng: np.random.Generator):
    """``(ids, poses)``: posegraph's optimum of ``path`` (no priors) moved by a random rigid motion."""
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.optimizer import optimize

    graph = read_g2o(path)
    poses = optimize(graph, "chordal").poses
    world = graph.group.exp(rng.normal(size=graph.group.dim) * np.r_[[1.0] * (graph.group.dim // 2), [20.0] * (graph.group.dim - graph.group.dim // 2)])
    return graph.ids, world @ poses


def _noisy_pose(group, pose: np.ndarray, rng, sigmas: dict) -> np.ndarray:
    """``pose · Exp(δ)`` with δ's rotation part of σ_rotation and translation part of σ_translation."""
    delta = np.zeros(group.dim)
    delta[list(group.rotation_axes)] = rng.normal(scale=sigmas["rotation"], size=len(group.rotation_axes))
    delta[list(group.translation_axes)] = rng.normal(scale=sigmas["translation"], size=len(group.translation_axes))
    return pose @ group.exp(delta)


def add_3d_priors(g2o, optimizer, ids, poses, rng, every=(POSITION_EVERY, POSE_EVERY)) -> None:
    """The 3D priors (module docstring) added to a loaded g2o ``optimizer``: position priors on the
    ids that are multiples of ``every[0]``, pose priors on those of ``every[1]``."""
    from posegraph.lie.group import SE3

    sigmas = SIGMAS[3]
    offset = SE3.exp(np.array([0.1, -0.2, 0.3, 0.5, 0.0, 1.2]))  # a sensor 1.3 m off the body frame
    for identifier, matrix in ((0, np.eye(4)), (1, offset)):
        parameter = g2o.ParameterSE3Offset()
        parameter.set_id(identifier)
        parameter.set_param(g2o.Isometry3d(matrix))
        optimizer.add_parameter(parameter)
    pose_information = np.diag([1 / sigmas["translation"] ** 2] * 3 + [1 / sigmas["rotation"] ** 2] * 3)  # g2o: [t; R]
    for identifier, pose in zip(ids.tolist(), poses):
        if identifier % every[0] == 0:
            edge = g2o.EdgeSE3XYZPrior()
            edge.set_vertex(0, optimizer.vertex(identifier))
            edge.set_parameter_id(0, 0)
            edge.set_measurement(pose[:3, 3] + rng.normal(scale=sigmas["position"], size=3))
            edge.set_information(np.eye(3) / sigmas["position"] ** 2)
            optimizer.add_edge(edge)
        if identifier % every[1] == 0:
            parameter = (identifier // every[1]) % 2  # every other one through the offset
            measured = _noisy_pose(SE3, pose @ (offset if parameter else np.eye(4)), rng, sigmas)
            edge = g2o.EdgeSE3Prior()
            edge.set_vertex(0, optimizer.vertex(identifier))
            edge.set_parameter_id(0, parameter)
            edge.set_measurement(g2o.Isometry3d(measured))
            edge.set_information(pose_information)
            optimizer.add_edge(edge)


def add_2d_priors(g2o, optimizer, ids, poses, rng, every=(POSITION_EVERY, POSE_EVERY)) -> None:
    """The 2D priors (module docstring) added to a loaded g2o ``optimizer`` (``every`` as in :func:`add_3d_priors`)."""
    from posegraph.lie import se2
    from posegraph.lie.group import SE2

    sigmas = SIGMAS[2]
    pose_information = np.diag([1 / sigmas["translation"] ** 2] * 2 + [1 / sigmas["rotation"] ** 2])
    for identifier, pose in zip(ids.tolist(), poses):
        if identifier % every[0] == 0:
            edge = g2o.EdgeSE2XYPrior()
            edge.set_vertex(0, optimizer.vertex(identifier))
            edge.set_measurement(pose[:2, 2] + rng.normal(scale=sigmas["position"], size=2))
            edge.set_information(np.eye(2) / sigmas["position"] ** 2)
            optimizer.add_edge(edge)
        if identifier % every[1] == 0:
            x, y, theta = se2.to_xytheta(_noisy_pose(SE2, pose, rng, sigmas))
            edge = g2o.EdgeSE2Prior()
            edge.set_vertex(0, optimizer.vertex(identifier))
            edge.set_measurement(g2o.SE2(x, y, theta))
            edge.set_information(pose_information)
            optimizer.add_edge(edge)


def make(source: str, target: str, planar: bool, seed: int) -> None:
    """Load ``source`` with g2o, add the priors, save ``target`` with g2o."""
    import g2opy as g2o

    rng = np.random.default_rng(seed)
    ids, poses = reference_poses(source, rng)
    optimizer = g2o.SparseOptimizer()
    if not optimizer.load(source):
        raise SystemExit(f"g2o could not load {source}")
    (add_2d_priors if planar else add_3d_priors)(g2o, optimizer, ids, poses, rng)
    if not optimizer.save(target):
        raise SystemExit(f"g2o could not save {target}")
    print(f"{target}: {len(optimizer.vertices())} vertices, {len(optimizer.edges())} edges and priors")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out_dir", help="folder to write into (outside the repository)")
    parser.add_argument("--datasets", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared", "datasets"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    os.makedirs(args.out_dir, exist_ok=True)
    for name, planar in (("sphere2500", False), ("intel", True)):
        make(os.path.join(args.datasets, f"{name}.g2o"), os.path.join(args.out_dir, f"{name}-priors.g2o"), planar, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
