"""A long synthetic route, one long loop closure, and the latest pose's covariance: ``python -m benchmarks.bench_incremental_route``.

Three measurements of :class:`posegraph.incremental.IncrementalOptimizer` (each in a fresh process, its
peak memory that process's ``ru_maxrss``):

* ``route N``: a planar route of ``N`` poses (``datasets.synthetic`` manhattan, loop closures removed:
  odometry only) added one pose per update; per-update time by decile of the route (flat or not), peak
  memory; then **one update adding a loop closure from the first to the last pose** (its measurement
  the true relative pose), against ``posegraph.solve.optimize`` of the same final graph from the same
  start (``batch N`` gives the batch solve's own peak memory), after one small warm-up solve (imports), each
  timed solve ordering its graph itself (the cache of the last order, ``cholmod._LAST_ORDERS``, cleared:
  the batch solve after a drastic update, itself a batch solve, would otherwise reuse its order).
* ``covariance N``: the manhattan graph of ``N`` poses (loop closures kept) put in at once, then the
  latest pose's marginal covariance (``marginal_covariance``), timed, and compared with
  ``posegraph.analysis.covariance.marginal_covariances`` of the same graph.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _route(n: int, loops: bool):
    sys.path.insert(0, str(ROOT))
    from datasets.synthetic import generate

    data = generate("manhattan", n, seed=0)
    graph = data.graph
    if not loops:
        keep = data.odometry
        graph = replace(graph, edge_from=graph.edge_from[keep], edge_to=graph.edge_to[keep],
                        measurements=graph.measurements[keep], information=graph.information[keep],
                        edge_source=None, edge_lines=None)
    return graph, data.ground_truth


def _peak() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def route(n: int) -> dict:
    from posegraph.incremental import IncrementalOptimizer
    from posegraph.incremental.replay import replay
    from posegraph.linalg.cholmod import _LAST_ORDERS
    from posegraph.solve import SolverParams, optimize

    graph, truth = _route(n, loops=False)
    _warm_up()
    opt = IncrementalOptimizer(graph.group)
    result = replay(graph, 1, optimizer=opt)
    s = result.seconds
    deciles = [float(1e3 * part.mean()) for part in np.array_split(s, 10)]
    z = graph.group.between(truth[:1], truth[-1:])
    info = graph.information[:1]
    start = opt.graph()
    opt.add_edges(opt.ids[:1], opt.ids[-1:], z, info)
    _LAST_ORDERS.clear()  # each solve below orders its graph itself (none reuses another's order)
    began = time.perf_counter()
    update = opt.update()
    update_seconds = time.perf_counter() - began
    closed = opt.graph()
    _LAST_ORDERS.clear()
    began = time.perf_counter()
    batch = optimize(replace(closed, poses=start.poses, fixed=opt.held()), initial=start.poses)
    batch_seconds = time.perf_counter() - began
    _LAST_ORDERS.clear()
    began = time.perf_counter()  # again, to the optimiser's own tolerance (the same accuracy as the update's)
    tight = optimize(replace(closed, poses=start.poses, fixed=opt.held()), initial=start.poses,
                     params=SolverParams(relative_tolerance=opt.tolerance))
    tight_seconds = time.perf_counter() - began
    return {"poses": n, "total": float(s.sum()), "mean_ms": float(1e3 * s.mean()), "p99_ms": float(1e3 * np.percentile(s, 99)),
            "max_ms": float(1e3 * s.max()), "decile_mean_ms": deciles, "peak_rss_mib": _peak(),
            "loop_update_s": update_seconds, "loop_update_kind": update.kind, "loop_update_cost": update.cost,
            "batch_s": batch_seconds, "batch_cost": float(batch.final_cost),
            "batch_at_tolerance_s": tight_seconds, "batch_at_tolerance_cost": float(tight.final_cost)}


def _warm_up() -> None:
    """One small batch solve: the modules the solves below import (the orderings', the solver's) are then
    loaded before any of them is timed."""
    from posegraph.solve import optimize

    graph, truth = _route(300, loops=False)
    z = graph.group.between(truth[:1], truth[-1:])
    closed = replace(graph, edge_from=np.r_[graph.edge_from, 0], edge_to=np.r_[graph.edge_to, 299],
                     measurements=np.concatenate([graph.measurements, z]),
                     information=np.concatenate([graph.information, graph.information[:1]]))
    optimize(closed, initial=closed.poses)


def batch_memory(n: int) -> dict:
    from posegraph.solve import optimize

    graph, truth = _route(n, loops=False)
    z = graph.group.between(truth[:1], truth[-1:])
    closed = replace(graph, edge_from=np.r_[graph.edge_from, 0], edge_to=np.r_[graph.edge_to, n - 1],
                     measurements=np.concatenate([graph.measurements, z]),
                     information=np.concatenate([graph.information, graph.information[:1]]))
    began = time.perf_counter()
    result = optimize(closed, initial=closed.poses)
    return {"poses": n, "batch_s": time.perf_counter() - began, "batch_cost": float(result.final_cost), "peak_rss_mib": _peak()}


def covariance(n: int) -> dict:
    from posegraph.analysis.covariance import marginal_covariances
    from posegraph.incremental import IncrementalOptimizer

    graph, _ = _route(n, loops=True)
    opt = IncrementalOptimizer(graph.group)
    opt.add_vertices(graph.ids, graph.poses, graph.fixed)
    opt.add_edges(graph.ids[graph.edge_from], graph.ids[graph.edge_to], graph.measurements, graph.information)
    opt.update()
    last = int(opt.ids[-1])
    opt.marginal_covariance(last)  # warm (imports)
    times = []
    for _ in range(5):
        began = time.perf_counter()
        ours = opt.marginal_covariance(last)
        times.append(time.perf_counter() - began)
    held = replace(opt.graph(), fixed=opt.held())
    reference = marginal_covariances(held, held.poses, np.array([held.num_vertices - 1]))[0]
    difference = float(np.abs(ours - reference).max() / np.abs(reference).max())
    return {"poses": n, "covariance_ms": 1e3 * float(np.median(times)), "relative_difference": difference,
            "peak_rss_mib": _peak()}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--worker":
        what, n = argv[1], int(argv[2])
        print(json.dumps({"route": route, "batch": batch_memory, "covariance": covariance}[what](n)))
        return 0
    jobs = [a.split(":") for a in argv] or [["route", "100000"], ["batch", "100000"], ["covariance", "20000"]]
    for what, n in jobs:
        command = [sys.executable, "-m", "benchmarks.bench_incremental_route", "--worker", what, n]
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=1200)
        line = done.stdout.strip().splitlines()[-1] if done.returncode == 0 else done.stderr.strip()[-400:]
        print(what, n, line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
