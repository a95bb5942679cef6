"""Initialisation: posegraph's chordal and odometry starts against gtsam's InitializePose3, side by side.

    python -m benchmarks.bench_init                         # sphere2500, torus3D, smallGrid3D, parking-garage
    python -m benchmarks.bench_init --repeat 9 --optimize   # also solve from each start
    python -m benchmarks.bench_init --weights               # start cost under other rotation weights
    python -m benchmarks.bench_init path/to/other.g2o

For each file the initialisers run alternately, ``--repeat`` times each (after one untimed warm-up
of each), so that all see the same machine load; the table gives the best and the median time and
the ratio of medians to gtsam's. gtsam's start is made as in the issue: ``gtsam.readG2o`` of the
file, a prior σ = 1e-6 on the first pose, ``InitializePose3.initialize`` (chordal rotations, then
one Gauss-Newton iteration on the full poses); its cost is ``graph.error`` *without* the prior.
Costs are ½ Σ eᵀΩe of the start (``posegraph.solve.residuals.cost``, equal to gtsam's error).
With ``--optimize`` Levenberg-Marquardt runs from our chordal start and from gtsam's and the final
costs are printed next to the reference optimum. With ``--weights`` the chordal start's cost is
also printed for other scalar rotation weights than ours (``tr(Ω_ωω)/3``): the smallest eigenvalue
of ``Ω_ωω``, ``3/tr(Ω_ωω⁻¹)``, 1 for every edge, and gtsam's ``√Ω[0,0]``. Figures are recorded in
docs/initialisation.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from posegraph.errors import InputError, InputWarning
from posegraph.model.graph import PoseGraph
from posegraph.init import (
    chordal_initialization,
    chordal_rotations,
    odometry_initialization,
    translations_given_rotations,
)
from posegraph.io.g2o import read_g2o
from posegraph.solve import SolverParams, optimize
from posegraph.solve.residuals import cost

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "datasets"
DEFAULT_FILES = ["sphere2500.g2o", "torus3D.g2o", "smallGrid3D.g2o", "parking-garage.g2o"]
REFERENCE_OPTIMUM = {
    "tinyGrid3D": 9.313909433544,
    "smallGrid3D": 517.925332360,
    "sphere2500": 675.700962926,
    "parking-garage": 0.634192399632,
    "torus3D": 12117.6368794,
}


def _timed(function, *args, **kwargs):
    start = time.perf_counter()
    value = function(*args, **kwargs)
    return time.perf_counter() - start, value


def _gtsam_initializer(gtsam, path: Path):
    """``run() -> Values`` for gtsam's InitializePose3 on the file, and the prior-free factor graph."""
    factors, initial = gtsam.readG2o(str(path), True)
    with_prior = factors.clone()
    first = min(int(key) for key in initial.keys())
    prior = gtsam.PriorFactorPose3(first, initial.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6))
    with_prior.add(prior)
    return (lambda: gtsam.InitializePose3.initialize(with_prior)), factors


ROTATION_WEIGHTS = {
    "tr(Ω_ωω)/3 (ours)": lambda block: np.trace(block, axis1=1, axis2=2) / 3,
    "λ_min(Ω_ωω)": lambda block: np.linalg.eigvalsh(block)[:, 0],
    "3/tr(Ω_ωω⁻¹)": lambda block: 3 / np.trace(np.linalg.inv(block), axis1=1, axis2=2),
    "1": lambda block: np.ones(block.shape[0]),
    "√Ω[0,0] (gtsam)": lambda block: np.sqrt(block[:, 0, 0]),
}


def start_cost_with_rotation_weight(graph: PoseGraph, weight) -> float:
    """Chordal start cost when the rotation stage weighs edges by ``weight(Ω_ωω)`` instead.

    The rotation stage sees only ``tr(Ω_ωω)/3``, so it is run on a copy whose ``Ω_ωω`` is
    ``weight · I``; the translations then use the real information, as always.
    """
    information = graph.information.copy()
    information[:, :3, :3] = weight(graph.information[:, :3, :3])[:, None, None] * np.eye(3)
    proxy = PoseGraph(graph.ids, graph.poses, graph.edge_from, graph.edge_to, graph.measurements, information,
                      graph.fixed)
    rotations = chordal_rotations(proxy)
    poses = np.zeros_like(graph.poses)
    poses[:, :3, :3] = rotations
    poses[:, :3, 3] = translations_given_rotations(graph, rotations)
    poses[:, 3, 3] = 1.0
    return cost(graph, poses)


def bench_file(path: Path, repeat: int, gtsam, solve: bool, weights: bool = False) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        try:
            graph = read_g2o(path)
        except InputError as err:
            print(f"{path.name}: skipped, not readable: {err}")
            return
    runs = {
        "chordal": lambda: chordal_initialization(graph),
        "chordal (scipy)": lambda: chordal_initialization(graph, linear_solver="scipy"),
        "odometry (bfs)": lambda: odometry_initialization(graph, "bfs"),
        "odometry (max_information)": lambda: odometry_initialization(graph, "max_information"),
    }
    if gtsam is not None:
        gtsam_run, factors = _gtsam_initializer(gtsam, path)
        try:
            gtsam_run()
            runs["gtsam InitializePose3"] = gtsam_run
        except RuntimeError as err:
            print(f"{path.name}: gtsam InitializePose3 raised: {str(err).strip().splitlines()[0]}")
    starts = _print_timings(path, graph, runs, repeat, factors if gtsam is not None else None)

    if weights:
        print("  chordal start cost by rotation weight:")
        for name, weight in ROTATION_WEIGHTS.items():
            print(f"    {name:20s} {start_cost_with_rotation_weight(graph, weight):14.7e}")

    if solve:
        _print_solves(path, graph, starts)


def _print_timings(path: Path, graph, runs: dict, repeat: int, factors) -> dict:
    """Run each start of ``runs`` once (its start) and ``repeat`` times alternating (its seconds);
    print cost, best and median seconds and the ratio to gtsam's median; return the starts."""
    times = {name: [] for name in runs}
    starts = {name: run() for name, run in runs.items()}  # warm-up, and the starts themselves
    for _ in range(repeat):
        for name, run in runs.items():
            times[name].append(_timed(run)[0])

    costs = {name: cost(graph, start) for name, start in starts.items() if not name.startswith("gtsam")}
    costs["file"] = cost(graph, graph.poses)
    if "gtsam InitializePose3" in starts:
        costs["gtsam InitializePose3"] = factors.error(starts["gtsam InitializePose3"])
    gtsam_median = statistics.median(times["gtsam InitializePose3"]) if "gtsam InitializePose3" in times else None

    print(f"\n{path.name}: {graph.num_vertices} vertices, {graph.num_edges} edges, repeat {repeat}")
    print(f"  {'start':28s} {'cost':>14s} {'best s':>9s} {'median s':>9s} {'/ gtsam':>8s}")
    for name in list(runs) + ["file"]:
        if name in times:
            best, median = min(times[name]), statistics.median(times[name])
            ratio = f"{median / gtsam_median:8.3f}" if gtsam_median else f"{'-':>8s}"
            print(f"  {name:28s} {costs[name]:14.7e} {best:9.4f} {median:9.4f} {ratio}")
        else:
            print(f"  {name:28s} {costs[name]:14.7e}")
    return starts


def _print_solves(path: Path, graph, starts: dict) -> None:
    """LM from the chordal start and from gtsam's, with the cost against the reference optimum."""
    reference = REFERENCE_OPTIMUM.get(path.stem)
    params = SolverParams(method="lm")
    starts_to_solve = {"chordal": starts["chordal"]}
    if "gtsam InitializePose3" in starts:
        from posegraph.crosscheck.gtsam_bridge import values_to_poses

        starts_to_solve["gtsam InitializePose3"] = values_to_poses(starts["gtsam InitializePose3"], graph.ids)
    for name, start in starts_to_solve.items():
        seconds, result = _timed(optimize, graph, initial=start, params=params)
        relative = f"{(result.final_cost - reference) / reference:+.2e}" if reference else "n/a"
        print(
            f"  LM from {name}: {result.final_cost:.12g} in {result.iterations} iterations, "
            f"{seconds:.2f} s ({result.termination}); relative to reference {relative}"
        )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path, help="g2o files (default: the shared benchmark graphs)")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs of each initialiser (default 5)")
    parser.add_argument("--optimize", action="store_true", help="also run LM from our start and from gtsam's")
    parser.add_argument("--weights", action="store_true", help="also compare scalar rotation weights")
    args = parser.parse_args(argv)
    files = args.files or [SHARED / name for name in DEFAULT_FILES]
    try:
        import gtsam
    except ImportError:
        gtsam = None
        print("gtsam is not installed: timing posegraph alone")
    np.set_printoptions(precision=4)
    for path in files:
        if not path.is_file():
            print(f"{path}: skipped, no such file")
            continue
        bench_file(path, args.repeat, gtsam, args.optimize, args.weights)
    return 0


if __name__ == "__main__":
    sys.exit(main())
