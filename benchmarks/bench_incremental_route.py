"""A long synthetic route, one long loop closure, and the latest pose's covariance: ``python -m benchmarks.bench_incremental_route``.

Three measurements of :class:`posegraph.incremental.IncrementalOptimizer` (each in a fresh process, its
peak memory that process's ``ru_maxrss``):

* ``route N``: a planar route of ``N`` poses (``datasets.synthetic`` manhattan, loop closures removed:
  odometry only) added one pose per update; per-update time by decile of the route (flat or not), peak
  memory; then **one update adding a loop closure from the first to the last pose** (its measurement
  the true relative pose), against ``posegraph.solve.optimize`` of the same final graph from the same
  start (``batch N`` gives the batch solve's own peak memory), after one small warm-up solve (imports), each
  timed solve ordering its graph itself (the cache of the last order, ``cholmod._LAST_ORDERS``, cleared:
  the batch solve after a drastic update, itself a batch solve, would otherwise reuse its order); the
  batch solve with default settings runs before the update, the one at the optimiser's tolerance after.
* ``covariance N``: what a front end pays for the latest pose's marginal covariance
  (``marginal_covariance``) on the manhattan graph of ``N`` poses (loop closures kept): all but the last
  pose put in at once (a solve), the first call after it and a repeated one; then the last pose by its
  odometry edge alone (an ``exact`` update) and the first call after it; then a loop closure from it to
  the pose 199 back (a solve) and the first call after it, and a pair's joint covariance. Then a replay
  of the last 500 poses one per update (each with its edges, loop closures included) from the rest put
  in at once, asking the latest pose's covariance after every update (median / p99 of the call) and
  again without asking (the totals side by side). Each covariance compared with
  ``posegraph.analysis.covariance.marginal_covariances`` of the same graph (relative max difference).
* ``covariance_gtsam N``: the same replay with gtsam's ISAM2 (default params, a prior of σ = 1e-6 on pose
  0) and ``isam.marginalCovariance`` of the latest pose after every update.
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


def _closed(graph, truth):
    """``graph`` with the long loop closure added: first pose to last, its true relative pose, the first
    edge's information."""
    n = graph.num_vertices
    z = graph.group.between(truth[:1], truth[-1:])
    return replace(graph, edge_from=np.r_[graph.edge_from, 0], edge_to=np.r_[graph.edge_to, n - 1],
                   measurements=np.concatenate([graph.measurements, z]),
                   information=np.concatenate([graph.information, graph.information[:1]]))


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
    replay_peak = _peak()  # before the batch solves below raise the process's high-water mark
    deciles = [float(1e3 * part.mean()) for part in np.array_split(s, 10)]
    start = opt.graph()
    closed = replace(_closed(start, truth), fixed=opt.held())
    z, info = closed.measurements[-1:], closed.information[-1:]
    _LAST_ORDERS.clear()  # each solve below orders its graph itself (none reuses another's order)
    began = time.perf_counter()  # one batch solve before the update, one after: neither tool always goes first
    batch = optimize(closed, initial=start.poses)
    batch_seconds = time.perf_counter() - began
    opt.add_edges(opt.ids[:1], opt.ids[-1:], z, info)
    _LAST_ORDERS.clear()
    began = time.perf_counter()
    update = opt.update()
    update_seconds = time.perf_counter() - began
    _LAST_ORDERS.clear()
    began = time.perf_counter()  # again, to the optimiser's own tolerance (the same accuracy as the update's)
    tight = optimize(closed, initial=start.poses, params=SolverParams(relative_tolerance=opt.tolerance))
    tight_seconds = time.perf_counter() - began
    return {"poses": n, "total": float(s.sum()), "mean_ms": float(1e3 * s.mean()), "p99_ms": float(1e3 * np.percentile(s, 99)),
            "max_ms": float(1e3 * s.max()), "decile_mean_ms": deciles, "peak_rss_mib": replay_peak,
            "peak_rss_mib_with_solves": _peak(),
            "loop_update_s": update_seconds, "loop_update_kind": update.kind, "loop_update_cost": update.cost,
            "batch_s": batch_seconds, "batch_cost": float(batch.final_cost),
            "batch_at_tolerance_s": tight_seconds, "batch_at_tolerance_cost": float(tight.final_cost)}


def _warm_up() -> None:
    """One small batch solve: the modules the solves below import (the orderings', the solver's) are then
    loaded before any of them is timed."""
    from posegraph.solve import optimize

    closed = _closed(*_route(300, loops=False))
    optimize(closed, initial=closed.poses)


def batch_memory(n: int) -> dict:
    from posegraph.solve import optimize

    closed = _closed(*_route(n, loops=False))
    began = time.perf_counter()
    result = optimize(closed, initial=closed.poses)
    return {"poses": n, "batch_s": time.perf_counter() - began, "batch_cost": float(result.final_cost), "peak_rss_mib": _peak()}


def _optimizer_with(graph, count: int):
    """An optimiser holding the first ``count`` poses of ``graph`` and the edges among them, put in at once."""
    from posegraph.incremental import IncrementalOptimizer

    opt = IncrementalOptimizer(graph.group)
    keep = np.maximum(graph.edge_from, graph.edge_to) < count
    opt.add_vertices(graph.ids[:count], graph.poses[:count], graph.fixed[:count])
    opt.add_edges(graph.ids[graph.edge_from[keep]], graph.ids[graph.edge_to[keep]], graph.measurements[keep],
                  graph.information[keep])
    opt.update()
    return opt


def _timed(call, *args) -> tuple[float, object]:
    began = time.perf_counter()
    value = call(*args)
    return time.perf_counter() - began, value


def _difference(opt, ours: np.ndarray) -> float:
    """Relative max difference of the latest pose's covariance against ``marginal_covariances`` of the same graph."""
    from posegraph.analysis.covariance import marginal_covariances

    held = replace(opt.graph(), fixed=opt.held())
    reference = marginal_covariances(held, held.poses, np.array([held.num_vertices - 1]))[0]
    return float(np.abs(ours - reference).max() / np.abs(reference).max())


def _replay_tail(graph, start: int, ask: bool) -> dict:
    """Poses ``start..n−1`` one per update (each with its edges to the poses in), the latest pose's
    covariance asked after every update when ``ask``: per-call seconds by the kind of the update before it."""
    opt = _optimizer_with(graph, start)
    later = np.maximum(graph.edge_from, graph.edge_to)
    updates, calls, kinds = [], [], []
    for v in range(start, graph.num_vertices):
        edges = np.flatnonzero(later == v)
        began = time.perf_counter()
        opt.add_vertices(graph.ids[v : v + 1], graph.poses[v : v + 1])
        opt.add_edges(graph.ids[graph.edge_from[edges]], graph.ids[graph.edge_to[edges]], graph.measurements[edges],
                      graph.information[edges])
        kinds.append(opt.update().kind)
        updates.append(time.perf_counter() - began)
        if ask:
            calls.append(_timed(opt.marginal_covariance, int(graph.ids[v]))[0])
    out = {"updates": len(updates), "update_total_s": float(np.sum(updates)), "kinds": {k: kinds.count(k) for k in set(kinds)}}
    if ask:
        c, exact = 1e3 * np.array(calls), np.array([k == "exact" for k in kinds])
        out.update(call_total_s=float(c.sum() / 1e3), call_median_ms=float(np.median(c)), call_p99_ms=float(np.percentile(c, 99)),
                   call_max_ms=float(c.max()), after_exact_median_ms=float(np.median(c[exact])),
                   after_solve_median_ms=float(np.median(c[~exact])) if (~exact).any() else None,
                   factorizations=opt._covariances.factorizations,
                   final_relative_difference=_difference(opt, opt.marginal_covariance(int(graph.ids[-1]))))
    return out


def covariance(n: int) -> dict:
    """What a front end pays for the latest pose's covariance at ``n`` poses (module docstring)."""
    graph, truth = _route(n, loops=True)
    opt = _optimizer_with(graph, n - 1)  # all but the last pose at once (a solve)
    last = int(opt.ids[-1])
    first_after_solve, _ = _timed(opt.marginal_covariance, last)
    repeated = [_timed(opt.marginal_covariance, last)[0] for _ in range(5)]
    later = np.maximum(graph.edge_from, graph.edge_to)
    odometry = np.flatnonzero((later == n - 1) & (np.abs(graph.edge_from - graph.edge_to) == 1))
    opt.add_vertices(graph.ids[-1:], graph.poses[-1:])  # (a) the last pose by its odometry edge alone
    opt.add_edges(graph.ids[graph.edge_from[odometry]], graph.ids[graph.edge_to[odometry]], graph.measurements[odometry],
                  graph.information[odometry])
    exact_kind = opt.update().kind
    first_after_odometry, ours = _timed(opt.marginal_covariance, n - 1)
    odometry_difference = _difference(opt, ours)
    z = graph.group.between(truth[n - 200 : n - 199], truth[n - 1 :])  # (b) a loop closure to a pose 199 back
    opt.add_edges(graph.ids[n - 200 : n - 199], graph.ids[n - 1 :], z, graph.information[:1])
    loop_update_s, info = _timed(opt.update)
    first_after_loop, ours = _timed(opt.marginal_covariance, n - 1)
    pair_s, _ = _timed(opt.joint_covariance, [n - 1, n - 200])
    result = {"poses": n, "first_call_after_bulk_solve_ms": 1e3 * first_after_solve,
              "repeated_call_ms": 1e3 * float(np.median(repeated)), "odometry_update_kind": exact_kind,
              "first_call_after_odometry_ms": 1e3 * first_after_odometry, "odometry_relative_difference": odometry_difference,
              "loop_update_kind": info.kind, "loop_update_s": loop_update_s, "first_call_after_loop_ms": 1e3 * first_after_loop,
              "pair_after_loop_ms": 1e3 * pair_s, "loop_relative_difference": _difference(opt, ours)}
    tail = min(500, n // 4)
    result["replay_asking"] = _replay_tail(graph, n - tail, ask=True)
    result["replay_not_asking"] = _replay_tail(graph, n - tail, ask=False)
    result["peak_rss_mib"] = _peak()
    return result


def covariance_gtsam(n: int) -> dict:
    """ISAM2 on the same graph: all but the last 500 poses in one update, then one pose per update with
    ``marginalCovariance`` of the latest after each (Cholesky; QR when it throws, as bench_incremental)."""
    try:
        return dict(_isam2_tail(n, None), factorization="CHOLESKY")
    except RuntimeError as err:
        if "ndetermin" not in str(err):
            raise
        return dict(_isam2_tail(n, "QR"), factorization="QR")


def _isam2_tail(n: int, factorization) -> dict:
    import gtsam

    from benchmarks.bench_incremental import _gtsam_types

    graph, _ = _route(n, loops=True)
    _, between, prior, to_gtsam, _ = _gtsam_types(graph)
    params = gtsam.ISAM2Params()
    if factorization is not None:
        params.setFactorization(factorization)
    isam = gtsam.ISAM2(params)
    later = np.maximum(graph.edge_from, graph.edge_to)
    noise = [gtsam.noiseModel.Gaussian.Information(w) for w in graph.information]
    start = n - min(500, n // 4)

    def batch(vertices, edges):
        factors, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for e in edges.tolist():
            factors.add(between(int(graph.edge_from[e]), int(graph.edge_to[e]), to_gtsam(graph.measurements[e]), noise[e]))
        for v in vertices:
            values.insert(v, to_gtsam(graph.poses[v]))
        if vertices[0] == 0:
            factors.add(prior(0, to_gtsam(graph.poses[0]), gtsam.noiseModel.Isotropic.Sigma(graph.group.dim, 1e-6)))
        isam.update(factors, values)

    batch(list(range(start)), np.flatnonzero(later < start))
    updates, calls = [], []
    for v in range(start, n):
        began = time.perf_counter()
        batch([v], np.flatnonzero(later == v))
        isam.calculateEstimate()
        updates.append(time.perf_counter() - began)
        calls.append(_timed(isam.marginalCovariance, v)[0])
    repeated = [_timed(isam.marginalCovariance, n - 1)[0] for _ in range(5)]
    c = 1e3 * np.array(calls)
    return {"poses": n, "updates": len(updates), "update_total_s": float(np.sum(updates)), "call_total_s": float(c.sum() / 1e3),
            "call_median_ms": float(np.median(c)), "call_p99_ms": float(np.percentile(c, 99)), "call_max_ms": float(c.max()),
            "repeated_call_ms": 1e3 * float(np.median(repeated)), "peak_rss_mib": _peak()}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--worker":
        what, n = argv[1], int(argv[2])
        jobs = {"route": route, "batch": batch_memory, "covariance": covariance, "covariance_gtsam": covariance_gtsam}
        print(json.dumps(jobs[what](n)))
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
