"""Sim(3) graphs written by g2o itself (the ``g2opy`` wheel), in both of g2o's file variants.

:func:`write_with_g2opy` builds a graph's vertices and edges as g2o's ``VertexSim3Expmap`` /
``EdgeSim3`` and saves them with ``SparseOptimizer.save``: a file no one here formatted (the current
variant, 6 significant digits as g2o's stream writes them). :func:`write_classic` rewrites such a
file in the classic variant (g2o's wheel writes only the current one; ``docs/g2o.md``)::

    python -m datasets.g2opy_sim3 --size 2500 -o /tmp/mono.g2o
    # -> /tmp/mono.g2o (by g2opy), /tmp/mono_classic.g2o, /tmp/mono_groundtruth.g2o
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.lie import sim3

__all__ = ["g2o_similarity", "lm_optimizer", "g2opy_optimizer", "g2o_chi2", "write_with_g2opy", "write_classic", "classic_path", "main"]


def g2o_similarity(g2o, matrix: np.ndarray):
    """g2o's ``Sim3(R, t, s)`` of a ``[[s R, t], [0, 1]]`` matrix."""
    s = float(sim3.scale(matrix))
    return g2o.Sim3(matrix[:3, :3] / s, np.ascontiguousarray(matrix[:3, 3]), s)


def lm_optimizer():
    """An empty ``g2o.SparseOptimizer`` with LM over ``BlockSolverSim3`` and Eigen's sparse Cholesky."""
    import g2opy as g2o

    optimizer = g2o.SparseOptimizer()
    optimizer.set_algorithm(g2o.OptimizationAlgorithmLevenberg(g2o.BlockSolverSim3(g2o.LinearSolverEigenSim3())))
    return optimizer


def g2o_chi2(path: str | Path, iterations: int = 0) -> float:
    """χ² that g2o computes for the file at ``path`` as it reads it (``load``, ``compute_active_errors``,
    ``active_chi2``), after ``iterations`` of its LM if asked."""
    optimizer = lm_optimizer()
    if not optimizer.load(str(path)):
        raise OSError(f"g2opy could not read {path}")
    optimizer.initialize_optimization()
    if iterations:
        optimizer.optimize(iterations)
    optimizer.compute_active_errors()
    return optimizer.active_chi2()


def g2opy_optimizer(graph: PoseGraph, poses: np.ndarray | None = None):
    """A ``g2o.SparseOptimizer`` (LM over ``BlockSolverSim3`` with Eigen's sparse Cholesky) holding ``graph``
    at ``poses`` (default its own): estimates ``S_i = X_i⁻¹``, measurements ``S_ji = Z⁻¹``, ``FIX`` vertices fixed."""
    import g2opy as g2o

    poses = graph.poses if poses is None else poses
    optimizer = lm_optimizer()
    for vertex_id, pose, fixed in zip(graph.ids.tolist(), sim3.inverse(poses), graph.fixed.tolist()):
        vertex = g2o.VertexSim3Expmap()
        vertex.set_id(vertex_id)
        vertex.set_estimate(g2o_similarity(g2o, pose))
        vertex.set_fixed(fixed)
        optimizer.add_vertex(vertex)
    ends = zip(graph.ids[graph.edge_from].tolist(), graph.ids[graph.edge_to].tolist())
    for (i, j), measurement, information in zip(ends, sim3.inverse(graph.measurements), graph.information):
        edge = g2o.EdgeSim3()
        edge.set_vertex(0, optimizer.vertex(i))
        edge.set_vertex(1, optimizer.vertex(j))
        edge.set_measurement(g2o_similarity(g2o, measurement))
        edge.set_information(information)
        optimizer.add_edge(edge)
    return optimizer


def write_with_g2opy(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> Path:
    """``graph`` (a Sim(3) graph) at ``poses`` saved by g2opy's ``SparseOptimizer.save`` to ``path``."""
    path = Path(path)
    if not g2opy_optimizer(graph, poses).save(str(path)):
        raise OSError(f"g2opy could not write {path}")
    return path


def classic_path(path: str | Path) -> Path:
    """``NAME_classic.g2o`` beside ``NAME.g2o``."""
    path = Path(path)
    return path.with_name(path.stem + "_classic" + path.suffix)


def write_classic(source: str | Path, target: str | Path) -> Path:
    """The Sim(3) file ``source`` (any variant) rewritten in the classic variant at ``target``."""
    from posegraph.io.g2o import read_g2o, write_g2o
    from posegraph.io.g2o_sim3 import CLASSIC, Sim3Format

    graph = read_g2o(source)
    form = graph.file_format
    write_g2o(target, replace(graph, file_format=Sim3Format(CLASSIC, form.camera_ids, form.cameras), source=None))
    return Path(target)


def main(argv: list[str] | None = None) -> int:
    from datasets.synthetic import NoiseParams, generate, groundtruth_path
    from posegraph.io.g2o import write_g2o

    parser = argparse.ArgumentParser(prog="python -m datasets.g2opy_sim3", description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=2500, help="about this many keyframes (default 2500)")
    parser.add_argument("--loop-density", type=float, default=0.3, help="fraction of candidate loop closures kept (default 0.3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-o", "--output", required=True, help="the g2opy-written file; _classic and _groundtruth go beside it")
    args = parser.parse_args(argv)
    noise = NoiseParams(odometry_translation_sigma=0.02, loop_translation_sigma=0.02, loop_closure_density=args.loop_density)
    dataset = generate("monocular", args.size, noise=noise, seed=args.seed)
    graph = replace(dataset.graph, fixed=np.arange(dataset.graph.num_vertices) == 0)
    path = write_with_g2opy(graph, args.output)
    write_classic(path, classic_path(path))
    write_g2o(groundtruth_path(path), graph, dataset.ground_truth)
    print(f"{dataset.name}: {graph.num_vertices} keyframes, {graph.num_edges} edges -> {path}, {classic_path(path)}, "
          f"{groundtruth_path(path)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
