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
    """Per update, in vertex-id order: ``(vertex indices, edge indices, pose-prior indices, position-prior
    indices, landmark indices, per landmark family its measurement indices)``.

    A landmark enters with the first pose that sees it (:func:`_landmark_batches`), each measurement
    with its pose, a point prior with its landmark; a landmark no pose sees enters with the last batch.
    """
    if batch_size < 1:
        raise ValueError(f"batch size must be at least 1, got {batch_size}")
    n = graph.num_vertices
    count = (n + batch_size - 1) // batch_size
    order = np.argsort(graph.ids, kind="stable")
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    batch_of_vertex = rank // batch_size
    priors = graph.priors
    pose_batch = batch_of_vertex[priors.pose_vertex] if priors is not None else np.zeros(0, np.int64)
    position_batch = batch_of_vertex[priors.position_vertex] if priors is not None else np.zeros(0, np.int64)
    landmark_batch, family_batches = _landmark_batches(graph, batch_of_vertex, count)
    groups = [_by_batch(b, count) for b in (np.maximum(batch_of_vertex[graph.edge_from], batch_of_vertex[graph.edge_to]),
                                             pose_batch, position_batch, landmark_batch, *family_batches)]
    for b, start in enumerate(range(0, n, batch_size)):
        edges, pose_priors, position_priors, landmarks, *families = (group(b) for group in groups)
        yield order[start:start + batch_size], edges, pose_priors, position_priors, landmarks, tuple(families)


def _by_batch(batch_of: np.ndarray, count: int):
    """``take(b)``: the indices ``i`` with ``batch_of[i] == b``, ascending (one sort, no scan per batch)."""
    ordered = np.argsort(batch_of, kind="stable")
    bounds = np.searchsorted(batch_of[ordered], np.arange(count + 1))
    return lambda b: ordered[bounds[b]:bounds[b + 1]]


def _landmark_batches(graph, batch_of_vertex: np.ndarray, count: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """``(batch of each landmark (L,), per family the batch of each measurement (q,))``: a landmark's is
    its first sighting's (the last batch if no pose sees it), a measurement's its pose's, a prior's its landmark's."""
    landmarks = graph.landmarks
    if landmarks is None:
        return np.zeros(0, np.int64), []
    first = np.full(landmarks.count, count - 1, dtype=np.int64)
    for family in landmarks.observations:
        if not family.unary:
            np.minimum.at(first, family.landmark, batch_of_vertex[family.pose])
    families = [first[f.landmark] if f.unary else batch_of_vertex[f.pose] for f in landmarks.observations]
    return first, families


def _stage(opt: IncrementalOptimizer, graph, vertices, edges, pose_priors, position_priors, landmarks=(),
           families=()) -> None:
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
    if len(landmarks) or any(len(rows) for rows in families):
        _stage_landmarks(opt, graph, landmarks, families)


def _stage_landmarks(opt: IncrementalOptimizer, graph, landmarks: np.ndarray, families: tuple) -> None:
    """The new landmarks at their file positions (kept only where their measurements leave them
    undetermined, or FIX), then each family's measurements of this update."""
    model, ids = graph.landmarks, graph.ids
    if len(landmarks):
        opt.add_landmarks(model.ids[landmarks], model.positions[landmarks], model.fixed[landmarks])
    for family, rows in zip(model.observations, families):
        if len(rows):
            offsets = None if family.offsets is None else family.offsets[rows]
            opt.add_landmark_measurements(family.kind, None if family.unary else ids[family.pose[rows]],
                                          model.ids[family.landmark[rows]], family.measurements[rows],
                                          family.information[rows], offsets=offsets, tag=family.tag)


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
    points = None if graph.landmarks is None else graph.landmarks.positions
    ours = Objective(graph, opt.params.loss).evaluate(graph.poses, points).cost
    params = params or SolverParams(relative_tolerance=1e-12, absolute_tolerance=0.0, max_iterations=200,
                                    loss=opt.params.loss)
    best = optimize(graph, initial=graph.poses, params=params, initial_points=points).final_cost
    best = min(best, ours)
    return graph.num_vertices, ours, best, (ours - best) / max(best, 1e-9)
