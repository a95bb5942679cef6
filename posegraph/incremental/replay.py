"""Replaying a graph as a front end would: vertices in id order, each with every edge to a vertex already in.

:func:`replay` feeds an :class:`~posegraph.incremental.optimizer.IncrementalOptimizer` ``batch_size``
new vertices per update (with their edges to vertices already in, their priors and FIX flags) and
times every update; optionally, every ``check_every`` poses, it compares the estimate's cost with a
batch solve of the same prefix (:func:`cost_excess`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from posegraph.incremental.optimizer import IncrementalOptimizer

__all__ = ["ReplayResult", "replay", "replay_batches", "cost_excess", "time_statistics"]


@dataclass
class ReplayResult:
    optimizer: IncrementalOptimizer
    seconds: np.ndarray
    """``(u,)`` wall seconds of each update."""
    poses_after: np.ndarray
    """``(u,)`` number of vertices after each update."""
    kinds: list
    checks: list = field(default_factory=list)
    """``(poses, cost, batch cost, relative excess)`` at each check."""

    @property
    def total_seconds(self) -> float:
        return float(np.sum(self.seconds))


def time_statistics(seconds) -> dict:
    """Mean, median, p99 and max of per-update seconds (and their count and sum)."""
    s = np.asarray(seconds, dtype=np.float64)
    if s.size == 0:
        return {"updates": 0, "total": 0.0, "mean": 0.0, "median": 0.0, "p99": 0.0, "max": 0.0}
    return {"updates": int(s.size), "total": float(s.sum()), "mean": float(s.mean()), "median": float(np.median(s)),
            "p99": float(np.percentile(s, 99)), "max": float(s.max())}


def replay_batches(graph, batch_size: int = 1):
    """``(vertex indices, edge indices, pose-prior indices, position-prior indices)`` per update, in id order."""
    if batch_size < 1:
        raise ValueError(f"batch size must be at least 1, got {batch_size}")
    n = graph.num_vertices
    order = np.argsort(graph.ids, kind="stable")
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    batch_of_vertex = rank // batch_size
    edge_batch = np.maximum(batch_of_vertex[graph.edge_from], batch_of_vertex[graph.edge_to])
    edges_sorted = np.argsort(edge_batch, kind="stable")
    edge_bounds = np.searchsorted(edge_batch[edges_sorted], np.arange((n + batch_size - 1) // batch_size + 1))
    priors = graph.priors
    pose_batch = batch_of_vertex[priors.pose_vertex] if priors is not None else np.zeros(0, np.int64)
    position_batch = batch_of_vertex[priors.position_vertex] if priors is not None else np.zeros(0, np.int64)
    for b, start in enumerate(range(0, n, batch_size)):
        edges = edges_sorted[edge_bounds[b]:edge_bounds[b + 1]]
        yield order[start:start + batch_size], edges, np.flatnonzero(pose_batch == b), np.flatnonzero(position_batch == b)


def _stage(opt: IncrementalOptimizer, graph, vertices, edges, pose_priors, position_priors) -> None:
    ids = graph.ids
    opt.add_vertices(ids[vertices], graph.poses[vertices], graph.fixed[vertices])
    if edges.size:
        opt.add_edges(ids[graph.edge_from[edges]], ids[graph.edge_to[edges]], graph.measurements[edges],
                      graph.information[edges])
    priors = graph.priors
    if pose_priors.size:
        opt.add_pose_priors(ids[priors.pose_vertex[pose_priors]], priors.pose_measurements[pose_priors],
                            priors.pose_information[pose_priors])
    if position_priors.size:
        opt.add_position_priors(ids[priors.position_vertex[position_priors]],
                                priors.position_measurements[position_priors],
                                priors.position_information[position_priors])


def replay(graph, batch_size: int = 1, *, optimizer: IncrementalOptimizer | None = None, check_every: int | None = None,
           check_params=None, progress=None) -> ReplayResult:
    """Replay ``graph`` into ``optimizer`` (a new default one for the graph's group if None).

    ``progress(result_so_far, update_number)`` is called after every update; ``check_every``: compare
    with a batch solve of the prefix whenever the pose count crosses a multiple of it, and at the end.
    """
    opt = IncrementalOptimizer(graph.group) if optimizer is None else optimizer
    seconds, poses_after, kinds, checks = [], [], [], []
    result = ReplayResult(opt, np.zeros(0), np.zeros(0, np.int64), kinds, checks)
    next_check = check_every
    for number, parts in enumerate(replay_batches(graph, batch_size), 1):
        start = time.perf_counter()
        _stage(opt, graph, *parts)
        info = opt.update()
        seconds.append(time.perf_counter() - start)
        poses_after.append(opt.num_vertices)
        kinds.append(info.kind)
        if next_check is not None and opt.num_vertices >= next_check:
            checks.append(cost_excess(opt, check_params))
            next_check = (opt.num_vertices // check_every + 1) * check_every
        if progress is not None:
            result.seconds, result.poses_after = np.asarray(seconds), np.asarray(poses_after)
            progress(result, number)
    if check_every is not None and (not checks or checks[-1][0] != opt.num_vertices):
        checks.append(cost_excess(opt, check_params))
    result.seconds, result.poses_after = np.asarray(seconds), np.asarray(poses_after)
    return result


def cost_excess(opt: IncrementalOptimizer, params=None) -> tuple[int, float, float, float]:
    """``(poses, cost, batch cost, (cost − batch) / max(batch, 1e-9))``: the estimate against a batch solve of the
    same graph (LM from the estimate, relative tolerance 1e-12, so it ends at the optimum nearest)."""
    from dataclasses import replace

    from posegraph.solve import SolverParams, optimize
    from posegraph.solve.objective import Objective

    graph = replace(opt.graph(), fixed=opt.held())
    ours = Objective(graph, opt.params.loss).evaluate(graph.poses).cost
    params = params or SolverParams(relative_tolerance=1e-12, absolute_tolerance=0.0, max_iterations=200,
                                    loss=opt.params.loss)
    best = optimize(graph, initial=graph.poses, params=params).final_cost
    best = min(best, ours)
    return graph.num_vertices, ours, best, (ours - best) / max(best, 1e-9)
