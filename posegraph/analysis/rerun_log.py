"""Log a pose graph and an optimisation to a Rerun recording the caller owns (``pip install "posegraph[rerun]"``).

Entities (``docs/rerun.md``), in the graph's world frame, metres, right-handed, ``z`` up (a 2D graph in
the plane ``z = 0``):

* ``world/initial/{odometry,loop_closures,poses}`` (static, grey): the graph at its start;
* ``world/estimate/{odometry,loop_closures,poses,landmarks}`` on the ``iteration`` timeline: 0 the
  start, ``k`` after the ``k``-th solver iteration (counted across every solve of a run: GNC's rounds
  too), the last one the result; odometry and loop closures are one two-point line strip per edge,
  coloured (static, at the end) by the edge's final robust weight, outliers (weight below 0.5)
  vermilion and thicker; per edge the static values ``edge`` (index in file order), ``line``,
  ``chi2``, ``weight``, ``outlier``; at the result, ``world/estimate/poses`` also holds each vertex's
  ``vertex_id``, translation ``tx, ty, tz`` and rotation ``qx, qy, qz, qw`` in float64 (what ``-o`` writes);
* ``world/chi2`` (static): every edge at the result coloured by ``χ²/d`` (viridis, log scale 0.1–100);
* ``world/headings`` (static): each pose's x axis at the result (graphs of up to 5,000 poses);
* ``world/covariance``: 1σ ellipsoids (3D) or ellipses (2D) of the positions of selected poses;
* ``metrics/{cost,lambda,step_norm}`` on ``iteration``; GNC's ``metrics/gnc/{mu,inliers,cost}`` on ``gnc_round``;
* ``summary``: the run's summary as Markdown.

Iterations are decimated for large graphs (:class:`~posegraph.analysis.rerun_scene.FrameBudget`):
the estimates logged stay under :data:`ITERATION_BUDGET` bytes.
"""

from __future__ import annotations

import numpy as np

from posegraph.analysis import rerun_scene as scene

__all__ = ["require_rerun", "IterationRecorder", "log_graph", "log_estimate", "log_result", "optimize_blueprint",
           "log_pose_values", "top_view", "strips", "edge_classes",
           "ITERATION_BUDGET", "ITERATION", "HEADINGS_MAX_POSES", "COVARIANCE_MAX_POSES"]

ITERATION = "iteration"
"""The timeline of the solver's iterations."""
ITERATION_BUDGET = 40_000_000
"""Bytes of geometry the logged iterations may take (the start and the result included)."""
HEADINGS_MAX_POSES = 5000
"""Heading arrows are drawn for graphs of at most this many poses."""
COVARIANCE_MAX_POSES = 200
"""At most this many covariance ellipsoids or ellipses, at poses spread evenly along the vertex order."""
THIN, THICK = -1.0, -2.0
"""Line radii in UI points (Rerun reads a negative radius as UI points, not metres)."""


def require_rerun():
    """The ``rerun`` module, or an :class:`ImportError` saying how to install it."""
    try:
        import rerun
    except ImportError as exc:
        raise ImportError(f"Rerun recordings need the rerun-sdk package ({exc}): pip install 'posegraph[rerun]'") from exc
    return rerun


def strips(rr, segments: np.ndarray):
    """``rr.LineStrips3D`` of ``(m, p, 3)`` strips of ``p`` points each, built as one Arrow list array
    (Rerun's own conversion of an ``(m, p, 3)`` array makes its offsets in a Python loop, ~0.1 ms per 1,000)."""
    import pyarrow as pa

    segments = np.ascontiguousarray(segments, dtype=np.float32)
    m, p = segments.shape[:2]
    kind = _strip_type(rr)
    points = pa.FixedSizeListArray.from_arrays(pa.array(segments.reshape(-1)), type=kind.value_type)
    offsets = pa.array(np.arange(0, m * p + 1, p, dtype=np.int32))
    return rr.LineStrips3D(pa.ListArray.from_arrays(offsets, points, type=kind))


def _strip_type(rr):
    """The Arrow type of Rerun's ``LineStrip3D`` component (list of fixed-size lists of three float32)."""
    global _STRIP_TYPE
    if _STRIP_TYPE is None:
        _STRIP_TYPE = rr.components.LineStrip3DBatch([np.zeros((2, 3), np.float32)]).as_arrow_array().type
    return _STRIP_TYPE


_STRIP_TYPE = None


def log_graph(rec, graph, poses=None, *, entity: str = "world/initial", colour=scene.INITIAL_COLOUR,
              static: bool = True) -> None:
    """``graph``'s vertices at ``poses`` (default its own) as points and its edges as line strips
    (``entity/odometry``, ``entity/loop_closures``), all ``colour``, static by default."""
    rr = require_rerun()
    points = scene.positions(graph.poses if poses is None else poses)
    odometry = graph.odometry_mask()
    for name, mask in (("odometry", odometry), ("loop_closures", ~odometry)):
        segments = scene.edge_segments(points, graph.edge_from[mask], graph.edge_to[mask])
        rec.log(f"{entity}/{name}", strips(rr, segments), rr.LineStrips3D.from_fields(colors=colour, radii=THIN),
                static=static)
    rec.log(f"{entity}/poses", rr.Points3D(points, colors=colour, radii=THIN), static=static)


def edge_classes(graph) -> tuple:
    """``(("odometry", from, to), ("loop_closures", from, to))``: each class's edge end indices."""
    odometry = graph.odometry_mask()
    return tuple((name, graph.edge_from[mask], graph.edge_to[mask])
                 for name, mask in (("odometry", odometry), ("loop_closures", ~odometry)))


def log_estimate(rec, graph, poses, points=None, *, entity: str = "world/estimate", classes=None) -> None:
    """The estimate ``poses`` (and landmark ``points``) at the recording's current time: vertices as
    points, edges as two-point line strips (their colours are logged static by :func:`log_result`);
    ``classes``: :func:`edge_classes` of ``graph`` when already known."""
    rr = require_rerun()
    where = scene.positions(poses)
    for name, tails, heads in classes or edge_classes(graph):
        rec.log(f"{entity}/{name}", strips(rr, scene.edge_segments(where, tails, heads)))
    rec.log(f"{entity}/poses", rr.Points3D(where))
    if points is not None and len(points):
        rec.log(f"{entity}/landmarks", rr.Points3D(_points3(points)))


def _points3(points) -> np.ndarray:
    """``(L, 3)`` float32 landmark positions (2D ones at ``z = 0``)."""
    points = np.asarray(points)
    out = np.zeros((len(points), 3), dtype=np.float32)
    out[:, : points.shape[1]] = points
    return out


def _frame_bytes(graph) -> int:
    """Bytes one logged estimate takes: a point per vertex and landmark, two per edge."""
    landmarks = 0 if graph.landmarks is None else graph.landmarks.count
    return scene.BYTES_PER_POINT * (graph.num_vertices + 2 * graph.num_edges + landmarks)


class IterationRecorder:
    """Records an optimisation on the ``iteration`` timeline; pass it as
    :attr:`~posegraph.solve.SolverParams.estimate_callback`.

    ``start(poses, points)`` logs iteration 0; each call (one per solver iteration, every solve of a run
    counted in turn) logs the cost, λ and step norm, and the estimate when the budget takes it (a solve
    on a subgraph, whose poses are not the graph's, logs scalars only); ``finish(poses, points)`` logs
    the result at the last iteration's number, replacing what was logged there.
    """

    def __init__(self, rec, graph, budget: int = ITERATION_BUDGET) -> None:
        self.rec, self.graph = rec, graph
        self.classes = edge_classes(graph)
        frame = _frame_bytes(graph)
        self.budget = scene.FrameBudget(max(budget - 2 * frame, 0), frame)  # the start and the result always
        self.iteration = 0
        self.logged = []

    def start(self, poses, points=None) -> None:
        self._log(0, poses, points)

    def __call__(self, record, poses, points=None) -> None:
        rr = require_rerun()
        self.iteration += 1
        self.rec.set_time(ITERATION, sequence=self.iteration)
        self.rec.log("metrics/cost", rr.Scalars(record.cost))
        self.rec.log("metrics/lambda", rr.Scalars(record.lambda_))
        self.rec.log("metrics/step_norm", rr.Scalars(record.step_norm))
        if np.shape(poses)[0] == self.graph.num_vertices and self.budget.take():
            self._log(self.iteration, poses, points)

    def finish(self, poses, points=None) -> int:
        """Log the result at the last iteration's number; that number."""
        self._log(self.iteration, poses, points)
        return self.iteration

    def _log(self, iteration: int, poses, points) -> None:
        self.rec.set_time(ITERATION, sequence=iteration)
        log_estimate(self.rec, self.graph, poses, points, classes=self.classes)
        self.logged.append(iteration)


def log_result(rec, graph, result, *, weights=None, covariances=None, chi2: dict | None = None,
               history=None, title: str = "") -> None:
    """The result of an optimisation of ``graph``: the final estimate (at the recording's current
    ``iteration``: call after :meth:`IterationRecorder.finish`), the edges' colours and per-edge values,
    the χ² layer, headings, covariance ellipsoids, GNC's rounds and the summary.

    ``result``: an :class:`~posegraph.solve.OptimizeResult` (``poses``, ``points``, ``final_cost``, …);
    ``weights (m,)``: the final robust weights (None: all 1); ``covariances``: ``(n, d, d)`` marginal
    covariances at ``result.poses`` (or ``{"poses": …}``), None for none; ``chi2``: the report's
    :func:`~posegraph.analysis.report.chi2_summary` (None: computed); ``history``: GNC's rounds
    (:class:`~posegraph.robust.gnc.GncIteration`), logged on the ``gnc_round`` timeline.
    """
    from posegraph.analysis.report import chi2_summary, edge_chi2

    robust = weights is not None
    weights = np.ones(graph.num_edges) if weights is None else np.asarray(weights, dtype=np.float64)
    residuals = result.final_residuals  # the solver's, when they are of this graph's edges
    known = residuals is not None and np.shape(residuals) == (graph.num_edges, graph.information.shape[-1])
    edge_values = edge_chi2(graph, result.poses, residuals if known else None)
    _log_edge_values(rec, graph, weights, edge_values)
    log_pose_values(rec, graph.ids, result.poses)
    _log_static_layers(rec, graph, result.poses, edge_values)
    if covariances is not None:
        _log_covariances(rec, result.poses, covariances["poses"] if isinstance(covariances, dict) else covariances)
    if history:
        _log_history(rec, history)
    chi2 = chi2_summary(graph, result.poses) if chi2 is None else chi2
    rec.log("summary", require_rerun().TextDocument(_summary_markdown(graph, result, weights, chi2, title, robust),
                                                    media_type="text/markdown"), static=True)


def _log_edge_values(rec, graph, weights: np.ndarray, chi2: np.ndarray) -> None:
    """Static colours, radii and per-edge values of ``world/estimate/{odometry,loop_closures}``."""
    rr = require_rerun()
    odometry = graph.odometry_mask()
    lines = np.array([-1 if v is None else int(v) for v in graph.edge_lines], dtype=np.int64) \
        if graph.edge_lines is not None else np.full(graph.num_edges, -1, dtype=np.int64)
    for name, mask, full in (("odometry", odometry, scene.ODOMETRY_COLOUR), ("loop_closures", ~odometry, scene.INLIER_COLOUR)):
        edges = np.flatnonzero(mask)
        w = weights[edges]
        outlier = w < scene.OUTLIER_WEIGHT
        rec.log(f"world/estimate/{name}",
                rr.LineStrips3D.from_fields(colors=scene.weight_colours(w, full), radii=np.where(outlier, THICK, THIN)),
                rr.AnyValues(edge=edges, line=lines[edges], chi2=chi2[edges], weight=w, outlier=outlier), static=True)


def log_pose_values(rec, ids, poses, entity: str = "world/estimate/poses") -> None:
    """Each vertex's ``vertex_id``, translation ``tx, ty, tz``, rotation ``qx, qy, qz, qw`` (Sim(3): and
    ``scale``) in float64 at the recording's current time (2D: ``tz = 0``, a rotation about z)."""
    rr = require_rerun()
    poses = np.asarray(poses, dtype=np.float64)
    k = poses.shape[-1] - 1
    rotation = np.zeros(poses.shape[:-2] + (3, 3))
    rotation[..., :k, :k] = poses[..., :k, :k]
    if k == 2:
        rotation[..., 2, 2] = 1.0
    scales = np.cbrt(np.linalg.det(rotation))  # Sim(3): s R
    from posegraph.lie import so3

    q = so3.to_quaternion(rotation / scales[:, None, None])
    t = scene.positions(poses).astype(np.float64)
    t[:, :k] = poses[:, :k, k]
    rec.log(entity, rr.AnyValues(vertex_id=np.asarray(ids, dtype=np.int64), tx=t[:, 0], ty=t[:, 1],
                                 tz=t[:, 2], qx=q[:, 0], qy=q[:, 1], qz=q[:, 2], qw=q[:, 3], scale=scales))


def _log_static_layers(rec, graph, poses, chi2: np.ndarray) -> None:
    """``world/chi2`` (edges coloured by χ²/d) and ``world/headings`` (small graphs), static."""
    rr = require_rerun()
    where = scene.positions(poses)
    segments = scene.edge_segments(where, graph.edge_from, graph.edge_to)
    rec.log("world/chi2", strips(rr, segments),
            rr.LineStrips3D.from_fields(colors=scene.chi2_colours(chi2, graph.information.shape[-1]), radii=THIN),
            static=True)
    if graph.num_vertices <= HEADINGS_MAX_POSES and graph.num_edges:
        length = 0.5 * float(np.median(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=-1)))
        rec.log("world/headings", rr.Arrows3D(origins=where, vectors=scene.headings(poses, length or 1.0),
                                              colors=(80, 80, 80, 255), radii=-0.75), static=True)


def _log_covariances(rec, poses, covariances) -> None:
    """``world/covariance``: the 1σ ellipsoids (3D) or ellipses (2D) of at most :data:`COVARIANCE_MAX_POSES` poses."""
    rr = require_rerun()
    poses = np.asarray(poses)
    chosen = scene.selected_poses(len(poses), COVARIANCE_MAX_POSES)
    if poses.shape[-1] == 3:
        outlines = scene.ellipse_outlines(poses[chosen], np.asarray(covariances)[chosen])
        rec.log("world/covariance", rr.LineStrips3D(outlines, colors=scene.COVARIANCE_COLOUR, radii=THIN), static=True)
        return
    centres, half_sizes, quaternions = scene.covariance_ellipsoids(poses[chosen], np.asarray(covariances)[chosen])
    rec.log("world/covariance", rr.Ellipsoids3D(centers=centres, half_sizes=half_sizes, quaternions=quaternions,
                                                colors=scene.COVARIANCE_COLOUR, fill_mode="MajorWireframe"), static=True)


def _log_history(rec, history) -> None:
    """GNC's outer rounds: μ, inliers and cost on the ``gnc_round`` timeline, in one call per scalar."""
    rr = require_rerun()
    rounds = rr.TimeColumn("gnc_round", sequence=np.arange(len(history)))
    for name in ("mu", "inliers", "cost"):
        values = np.array([float(getattr(h, name)) for h in history])
        rec.send_columns(f"metrics/gnc/{name}", indexes=[rounds], columns=rr.Scalars.columns(scalars=values))


def _summary_markdown(graph, result, weights: np.ndarray, chi2: dict, title: str, robust: bool = False) -> str:
    """The summary's table, labelled as the command's: with robust weights the final cost is what the
    robust solve minimised (½ Σ ρ(eᵀΩe), or GNC's ½χ² of the edges kept), beside ½ Σ eᵀΩe over every
    measurement (``chi2["every"]``, the command's) and the χ² of the edges kept; χ²/dof undefined at dof 0."""
    from posegraph.analysis.report import per_dof_text

    outliers = int(np.count_nonzero(weights < scene.OUTLIER_WEIGHT))
    odometry = int(np.count_nonzero(graph.odometry_mask()))
    rows = [
        ("poses / edges", f"{graph.num_vertices} / {graph.num_edges} ({odometry} odometry, "
                          f"{graph.num_edges - odometry} loop closures)"),
        ("initial cost", f"{result.initial_cost:.10g}"),
        ("final cost", f"{result.final_cost:.10g} " + ("(what the robust solve minimised)" if robust else "(½χ²)")),
        ("χ² of the inliers / dof" if robust else "χ² / dof",
         f"{chi2['chi2']:.10g} / {chi2['dof']} = {per_dof_text(chi2)}"),
        ("iterations", str(result.iterations)),
        ("termination", result.termination),
        ("outlier edges", f"{outliers} (weight < {scene.OUTLIER_WEIGHT})"),
    ]
    if robust and "every" in chi2:
        rows.insert(4, ("½χ², every measurement", f"{chi2['every']['cost']:.10g} (½ Σ eᵀΩe, no loss)"))
    if graph.landmarks is not None:
        rows.insert(1, ("landmarks", str(graph.landmarks.count)))
    table = "\n".join(f"| {name} | {value} |" for name, value in rows)
    return f"### {title or 'posegraph optimize'}\n\n| | |\n|---|---|\n{table}\n"


def optimize_blueprint(graph, poses=None):
    """The view an ``optimize`` recording opens on: the world (a 2D graph seen from above ``poses``,
    default its own) beside the cost per iteration and the summary, the ``iteration`` timeline selected."""
    import rerun.blueprint as rrb

    world = rrb.Spatial3DView(origin="world", name="pose graph", contents=["world/**", "- world/chi2"],
                              eye_controls=top_view(graph.poses if poses is None else poses))
    side = rrb.Vertical(rrb.TimeSeriesView(origin="metrics/cost", name="cost"),
                        rrb.TextDocumentView(origin="summary", name="summary"), row_shares=[1, 1])
    return rrb.Blueprint(rrb.Horizontal(world, side, column_shares=[3, 1]), rrb.TimePanel(timeline=ITERATION, state="collapsed", play_state="following"),
                         collapse_panels=True)


def top_view(poses):
    """The eye over 2D ``poses (n, 3, 3)``: above the middle of their positions, looking down, y up;
    None (the viewer's automatic eye) for 3D poses."""
    if np.shape(poses)[-1] != 3:
        return None
    import rerun.blueprint as rrb

    where = scene.positions(poses)
    low, high = where.min(axis=0), where.max(axis=0)
    middle = (low + high) / 2
    height = 1.2 * float(np.max(high - low)) or 1.0
    return rrb.EyeControls3D(position=(middle[0], middle[1], height), look_target=(middle[0], middle[1], 0.0),
                             eye_up=(0.0, 1.0, 0.0))
