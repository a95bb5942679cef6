"""Log a replay (:func:`posegraph.incremental.replay.replay`) to a Rerun recording the caller owns.

Entities (``docs/rerun.md``), world frame, metres, right-handed, ``z`` up (2D graphs in ``z = 0``), on
the ``pose`` timeline (the number of poses after an update):

* ``world/estimate/trajectory``: the estimate after the update, one line strip through the poses in id order;
* ``world/estimate/landmarks``: the landmarks' estimate (landmark graphs);
* ``world/loop_closures/all``: every loop closure in so far, faint; ``world/loop_closures/new``: those
  that entered since the previous logged update, highlighted (orange, thick);
* ``metrics/update_ms``, ``metrics/cost`` at every update; ``metrics/cost_excess`` at each check
  against a batch solve (``--check-every``) and at the end;
* at the last update, ``world/estimate/poses`` with each vertex's ``vertex_id``, ``tx…qw`` in float64;
* ``summary``: the replay's figures as Markdown.

The estimate is logged at every update that brings a loop closure and at every N-th other update,
N chosen before the replay (:func:`plan_frames`) so the geometry stays under :data:`REPLAY_BUDGET`
bytes (a 10,000-pose replay under ~100 MB); when the loop-closure updates alone would exceed half of
it, every j-th of them is logged (the final update always).
"""

from __future__ import annotations

import numpy as np

from posegraph.analysis import rerun_scene as scene
from posegraph.analysis.rerun_log import THICK, THIN, log_pose_values, require_rerun, strips, top_view

__all__ = ["ReplayRecorder", "plan_frames", "update_of_edges", "replay_blueprint", "REPLAY_BUDGET", "POSE"]

POSE = "pose"
"""The timeline of a replay: poses in the estimate after each update."""
REPLAY_BUDGET = 60_000_000
"""Bytes of geometry a replay's logged estimates may take."""
FRAME_LIMIT = 400
"""Updates whose estimate is logged, at most (each costs ~1 ms: the logging stays within ~10 % of a replay)."""


def update_of_edges(graph, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(rank (n,), update (m,))``: each vertex's place in the replay's order (its index in the
    incremental optimiser), and the 1-based update at which each edge enters (its later vertex's)."""
    order = np.argsort(graph.ids, kind="stable")
    rank = np.empty(graph.num_vertices, dtype=np.int64)
    rank[order] = np.arange(graph.num_vertices)
    return rank, np.maximum(rank[graph.edge_from], rank[graph.edge_to]) // batch_size + 1


def plan_frames(poses_after: np.ndarray, closures_per_update: np.ndarray, budget: int = REPLAY_BUDGET,
                limit: int = FRAME_LIMIT) -> np.ndarray:
    """``(u,)`` bool: the updates whose estimate is logged, given each update's pose count and new loop
    closures: the last; the loop-closure updates (every j-th when they would take more than half of
    ``budget`` bytes or of ``limit`` frames); every N-th other update within what is left of both.
    A frame costs a point per pose and two per loop closure in so far."""
    poses_after = np.asarray(poses_after, dtype=np.int64)
    closures = np.asarray(closures_per_update, dtype=np.int64)
    frame = scene.BYTES_PER_POINT * (poses_after + 2 * np.cumsum(closures))
    chosen = np.zeros(len(frame), dtype=bool)
    if not len(frame):
        return chosen
    chosen[-1] = True
    closing = np.flatnonzero(closures > 0)
    if closing.size:
        stride = max(int(np.ceil(frame[closing].sum() / (budget / 2))), int(np.ceil(closing.size / (limit / 2))), 1)
        chosen[closing[::stride]] = True
    bytes_left = budget - frame[chosen].sum()
    frames_left = limit - np.count_nonzero(chosen)
    others = np.flatnonzero(~chosen)
    if others.size and bytes_left > 0 and frames_left > 0:
        every = max(int(np.ceil(frame[others].sum() / bytes_left)), int(np.ceil(others.size / frames_left)), 1)
        chosen[others[every - 1::every]] = True
    return chosen


class ReplayRecorder:
    """Records a replay of ``graph`` (``batch_size`` vertices per update) to ``rec``.

    Call it as the replay's ``progress(result, number)`` after each update; then :meth:`finish`.
    """

    def __init__(self, rec, graph, batch_size: int = 1, budget: int = REPLAY_BUDGET) -> None:
        self.rec, self.graph = rec, graph
        self.rank, self.update_of = update_of_edges(graph, batch_size)
        closing = ~graph.odometry_mask()
        count = (graph.num_vertices + batch_size - 1) // batch_size
        self.closures = np.flatnonzero(closing)
        per_update = np.bincount(self.update_of[closing], minlength=count + 1)[1:]
        poses_after = np.minimum(np.arange(1, count + 1) * batch_size, graph.num_vertices)
        self.frames = plan_frames(poses_after, per_update, budget)
        self.last_frame = 0
        self.pose_counts, self.costs = [], []

    def __call__(self, result, number: int) -> None:
        opt = result.optimizer
        self.pose_counts.append(opt.num_vertices)
        self.costs.append(opt.cost())
        if number - 1 < len(self.frames) and self.frames[number - 1]:
            self._log_frame(opt, number)

    def _log_frame(self, opt, number: int) -> None:
        rr = require_rerun()
        rec = self.rec
        rec.set_time(POSE, sequence=opt.num_vertices)
        where = scene.positions(opt.poses)
        rec.log("world/estimate/trajectory", strips(rr, where[None]))
        if opt.landmark_ids.size:
            rec.log("world/estimate/landmarks", rr.Points3D(_planar(opt.landmark_positions)))
        inside = self.closures[self.update_of[self.closures] <= number]
        new = inside[self.update_of[inside] > self.last_frame]
        for name, edges in (("all", inside), ("new", new)):
            segments = scene.edge_segments(where, self.rank[self.graph.edge_from[edges]], self.rank[self.graph.edge_to[edges]])
            values = [rr.AnyValues(edge=edges)] if len(edges) else []  # Rerun refuses an empty AnyValues
            rec.log(f"world/loop_closures/{name}", strips(rr, segments), *values)
        self.last_frame = number

    def finish(self, result, costs: tuple, stats: dict, title: str = "") -> None:
        """Log the per-update scalars, the checks, the final poses, the summary and the blueprint.
        ``costs``: ``(ours, batch, excess)`` at the end; ``stats``: the per-update time statistics."""
        rr = require_rerun()
        rec, opt = self.rec, result.optimizer
        rec.log("world/loop_closures/all", rr.LineStrips3D.from_fields(colors=(0, 158, 115, 110), radii=THIN), static=True)
        rec.log("world/loop_closures/new", rr.LineStrips3D.from_fields(colors=scene.NEW_CLOSURE_COLOUR, radii=THICK),
                static=True)
        rec.log("world/estimate/trajectory", rr.LineStrips3D.from_fields(colors=scene.ODOMETRY_COLOUR, radii=THIN),
                static=True)
        poses = rr.TimeColumn(POSE, sequence=np.asarray(self.pose_counts))
        for name, values in (("update_ms", 1e3 * np.asarray(result.seconds)), ("cost", np.asarray(self.costs))):
            rec.send_columns(f"metrics/{name}", indexes=[poses], columns=rr.Scalars.columns(scalars=values))
        checks = list(result.checks) or [(opt.num_vertices, *costs)]
        if checks[-1][0] != opt.num_vertices:
            checks.append((opt.num_vertices, *costs))
        rec.send_columns("metrics/cost_excess", indexes=[rr.TimeColumn(POSE, sequence=[c[0] for c in checks])],
                         columns=rr.Scalars.columns(scalars=[c[3] for c in checks]))
        rec.set_time(POSE, sequence=opt.num_vertices)
        log_pose_values(rec, opt.ids, opt.poses)
        rec.log("summary", rr.TextDocument(_summary(self, result, costs, stats, title), media_type="text/markdown"),
                static=True)
        rec.send_blueprint(replay_blueprint(opt.poses))


def _planar(points) -> np.ndarray:
    points = np.asarray(points)
    out = np.zeros((len(points), 3), dtype=np.float32)
    out[:, : points.shape[1]] = points
    return out


def _summary(recorder: ReplayRecorder, result, costs: tuple, stats: dict, title: str) -> str:
    ours, best, excess = costs
    rows = [
        ("poses / edges", f"{recorder.graph.num_vertices} / {recorder.graph.num_edges} "
                          f"({len(recorder.closures)} loop closures)"),
        ("updates", f"{stats['updates']} in {stats['total']:.3f} s"),
        ("per update", f"mean {1e3 * stats['mean']:.3f} ms, median {1e3 * stats['median']:.3f} ms, "
                       f"p99 {1e3 * stats['p99']:.3f} ms, max {1e3 * stats['max']:.3f} ms"),
        ("final cost", f"{ours:.10g} (batch solve {best:.10g})"),
        ("excess", f"{excess:.3g} relative"),
        ("updates logged", f"{int(recorder.frames.sum())} of {len(recorder.frames)}"),
    ]
    table = "\n".join(f"| {name} | {value} |" for name, value in rows)
    return f"### {title or 'posegraph replay'}\n\n| | |\n|---|---|\n{table}\n"


def replay_blueprint(poses=None):
    """The view a replay recording opens on: the world (2D: from above ``poses``) beside the update
    time and the cost excess, the ``pose`` timeline selected."""
    import rerun.blueprint as rrb

    world = rrb.Spatial3DView(origin="world", name="estimate", eye_controls=None if poses is None else top_view(poses))
    side = rrb.Vertical(rrb.TimeSeriesView(origin="metrics/update_ms", name="update time (ms)"),
                        rrb.TimeSeriesView(origin="metrics/cost_excess", name="cost excess (relative)"),
                        rrb.TextDocumentView(origin="summary", name="summary"))
    return rrb.Blueprint(rrb.Horizontal(world, side, column_shares=[3, 1]), rrb.TimePanel(timeline=POSE, state="collapsed", play_state="following"),
                         collapse_panels=True)
