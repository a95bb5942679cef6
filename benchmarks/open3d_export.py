"""``python -m benchmarks.open3d_export``: Open3D's optimiser on our export, edges certain vs uncertain.

For each dataset (default: three 3D shared datasets on which Open3D finishes in seconds), the graph is exported
from the file's poses (:func:`posegraph.io.export_open3d.to_open3d_pose_graph`) once with every edge
certain (the default) and once with loop closures uncertain (``--uncertain-loop-closures``), and
Open3D's ``global_optimization`` (Levenberg-Marquardt, its default criteria, the tutorial's
options, reference node = our gauge anchor) is run on each. Printed: our cost ½ Σ eᵀΩe at the
file's poses, at Open3D's two results and at our optimum, and the number of edges Open3D kept.
Figures are recorded in ``docs/interop.md``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "datasets"
DEFAULT = ("tinyGrid3D", "smallGrid3D", "parking-garage")  # sphere2500: Open3D did not finish in 5 min


def open3d_optimise(o3d, pose_graph, reference_node: int) -> tuple[np.ndarray, float]:
    """Run Open3D's global optimisation in place; ``(poses (n, 4, 4), seconds)``."""
    reg = o3d.pipelines.registration
    option = reg.GlobalOptimizationOption(
        max_correspondence_distance=0.1, edge_prune_threshold=0.25, reference_node=reference_node
    )
    start = time.perf_counter()
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(
            pose_graph, reg.GlobalOptimizationLevenbergMarquardt(), reg.GlobalOptimizationConvergenceCriteria(), option
        )
    return np.array([node.pose for node in pose_graph.nodes]), time.perf_counter() - start


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.open3d_export", description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="*", default=list(DEFAULT), help="names in ../shared/datasets or paths")
    args = parser.parse_args(argv)
    from posegraph.io.export_open3d import require_open3d, to_open3d_pose_graph
    from posegraph.model.graph import component_anchors
    from posegraph.io.g2o import read_g2o
    from posegraph.solve import optimize
    from posegraph.solve.residuals import cost

    o3d = require_open3d()
    print(f"{'dataset':<16}{'file':>14}{'certain':>14}{'uncertain':>14}{'optimum':>14}  edges kept (uncertain)")
    for name in args.datasets:
        path = Path(name) if Path(name).exists() else SHARED / f"{name}.g2o"
        graph = read_g2o(path)
        anchor = int(component_anchors(graph)[0])
        costs = []
        for uncertain in (False, True):
            pose_graph = to_open3d_pose_graph(graph, uncertain_loop_closures=uncertain)
            poses, _ = open3d_optimise(o3d, pose_graph, anchor)
            costs.append(cost(graph, poses))
            kept = len(pose_graph.edges)
        optimum = optimize(graph).final_cost
        print(f"{path.stem:<16}{cost(graph):>14.6g}{costs[0]:>14.6g}{costs[1]:>14.6g}{optimum:>14.6g}"
              f"  {kept}/{graph.num_edges}")


if __name__ == "__main__":
    main()
