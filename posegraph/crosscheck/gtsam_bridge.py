"""Run gtsam on our graphs: conversions and a timed reference optimisation.

gtsam (``pip install "posegraph[gtsam]"``) is optional and imported only inside these functions.
It is the reference this project is checked against: the same factors (``BetweenFactorPose3``
with a full Gaussian noise model from Ω, as ``gtsam.readG2o`` builds them), the same cost
``½ Σ eᵀ Ω e`` (``NonlinearFactorGraph.error``), the same ``[ω; v]`` tangent order; for 2D graphs
``Pose2``, ``BetweenFactorPose2`` and ``PriorFactorPose2`` (tangent ``[x, y, θ]``); for Sim(3) graphs
``Similarity3``, ``BetweenFactorSimilarity3`` and ``PriorFactorSimilarity3`` (tangent ``[ω; υ; λ]``, the
same as :mod:`posegraph.lie.sim3`; gtsam's cost is the exact log's, not g2o's first-order one, so a
graph read from a g2o Sim(3) file is compared as :data:`~posegraph.lie.group.SIM3`).

Gauge. Our solver holds every ``FIX`` vertex and one anchor per free connected component constant
and adds nothing to the cost (``posegraph.model.graph.component_anchors``). gtsam needs the gauge fixed
too, so :func:`run_gtsam` adds a tight prior (σ = :data:`ANCHOR_SIGMA`) on exactly those vertices
at their initial poses — the usual way gtsam's own examples optimise a g2o file — and reports
costs of the edges alone, which is the quantity our solver minimises. For a graph without ``FIX``
vertices the anchors' priors are satisfied exactly at the optimum, so the costs are comparable
to the last digit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "INSTALL_HINT",
    "ANCHOR_SIGMA",
    "require_gtsam",
    "poses_to_values",
    "values_to_poses",
    "graph_to_gtsam",
    "gauge_priors",
    "GtsamResult",
    "run_gtsam",
]

INSTALL_HINT = 'pip install "posegraph[gtsam]" (or pip install gtsam)'

ANCHOR_SIGMA = 1e-6
"""Standard deviation of the priors fixing the gauge in gtsam. Tight enough that the anchors move by
~1e-12, loose enough (information 1e12 against edge information ≲ 1e6 in the standard datasets) that
Cholesky keeps full precision for the other variables."""


def require_gtsam():
    """Import and return ``gtsam``, or raise ImportError with the install command."""
    try:
        import gtsam
    except ImportError as exc:
        raise ImportError(f"this command needs gtsam, which is not installed; install it: {INSTALL_HINT}") from exc
    return gtsam


def _is_planar(poses_or_graph) -> bool:
    """Whether poses ``(…, 3, 3)`` (or a graph's group) are SE(2), gtsam's ``Pose2``."""
    group = getattr(poses_or_graph, "group", None)
    if group is not None:
        return group.matrix_size == 3
    return np.shape(poses_or_graph)[-1] == 3


def _gtsam_pose(gtsam, matrix: np.ndarray):
    """``Pose3(T)`` of a ``(4, 4)`` matrix, ``Pose2(x, y, θ)`` of a ``(3, 3)`` one."""
    if matrix.shape[-1] == 3:
        from posegraph.lie import se2

        return gtsam.Pose2(*se2.to_xytheta(matrix).tolist())
    return gtsam.Pose3(matrix)


def _gtsam_similarity(gtsam, matrix: np.ndarray):
    """``Similarity3(R, t/s, s)`` of a Sim(3) matrix ``[[s R, t], [0, 1]]`` (gtsam's is ``[[R, t/s], [0, 1/s]]``)."""
    from posegraph.lie import sim3

    s = float(sim3.scale(matrix))
    return gtsam.Similarity3(gtsam.Rot3(sim3.rotation(matrix)), matrix[:3, 3] / s, s)


def _is_similarity(group) -> bool:
    return group is not None and bool(group.scale_axes)


def _element(gtsam, matrix: np.ndarray, group):
    """gtsam's element of ``group`` (None: by the matrix's shape) for one matrix."""
    return _gtsam_similarity(gtsam, matrix) if _is_similarity(group) else _gtsam_pose(gtsam, matrix)


def _factor_class(gtsam, graph, kind: str):
    """``gtsam.<kind>FactorPose3`` / ``…Pose2`` / ``…Similarity3`` for ``graph``'s group (``kind``: Between, Prior)."""
    if _is_similarity(graph.group):
        return getattr(gtsam, f"{kind}FactorSimilarity3")
    return getattr(gtsam, f"{kind}FactorPose2" if _is_planar(graph) else f"{kind}FactorPose3")


def poses_to_values(ids: np.ndarray, poses: np.ndarray, group=None):
    """``gtsam.Values`` holding ``Pose3(poses[k])`` (``Pose2`` for SE(2) poses) under key ``ids[k]``.

    ``ids`` ``(n,)`` integer vertex ids (used as gtsam keys, as ``readG2o`` does); ``poses`` ``(n, 4, 4)``
    or ``(n, 3, 3)``.
    """
    gtsam = require_gtsam()
    values = gtsam.Values()
    for key, pose in zip(np.asarray(ids).tolist(), np.asarray(poses, dtype=np.float64)):
        values.insert(key, _element(gtsam, pose, group))
    return values


def values_to_poses(values, ids: np.ndarray, group=None) -> np.ndarray:
    """Poses ``(n, 4, 4)`` — ``(n, 3, 3)`` when ``values`` holds ``Pose2``, Sim(3) matrices for a Sim(3)
    ``group`` — of ``ids`` read from ``gtsam.Values`` (KeyError if a key is absent)."""
    gtsam = require_gtsam()
    ids = np.asarray(ids, dtype=np.int64)
    if _is_similarity(group):  # no extractSimilarity3: one element at a time
        missing = [key for key in ids.tolist() if not values.exists(key)]
        if missing:
            raise KeyError(f"vertex ids not in gtsam values: {missing[:5]}")
        elements = [values.atSimilarity3(key) for key in ids.tolist()]
        return np.array([element.scale() * element.matrix() for element in elements]).reshape(-1, 4, 4)
    keys = np.asarray(list(values.keys()), dtype=np.int64)
    # extractPose3 returns one row per Pose3 in key order: R row-major (9), then t (3); extractPose2
    # one row per Pose2: x, y, θ.
    rows = gtsam.utilities.extractPose3(values)
    planar = rows.shape[0] == 0 and keys.size > 0
    if planar:
        rows = gtsam.utilities.extractPose2(values)
    order = np.argsort(keys)
    pos = np.searchsorted(keys, ids, sorter=order)
    pos = np.clip(pos, 0, len(keys) - 1)
    found = order[pos]
    if not np.all(keys[found] == ids):
        raise KeyError(f"vertex ids not in gtsam values: {ids[keys[found] != ids][:5].tolist()}")
    rows = rows[found]
    if planar:
        from posegraph.lie import se2

        return se2.from_xytheta(rows)
    poses = np.zeros((len(ids), 4, 4))
    poses[:, :3, :3] = rows[:, :9].reshape(-1, 3, 3)
    poses[:, :3, 3] = rows[:, 9:12]
    poses[:, 3, 3] = 1.0
    return poses


def graph_to_gtsam(graph, *, diagonal: bool = False):
    """``gtsam.NonlinearFactorGraph`` of ``BetweenFactorPose3`` (``BetweenFactorPose2`` for an SE(2)
    graph), one per edge, keys = vertex ids.

    Each factor measures ``Pose3(Z_ij)`` with ``noiseModel.Gaussian.Information(Ω)`` (Ω is in
    ``[ω; v]`` order, gtsam's tangent order; ``[x, y, θ]``, ``Pose2``'s, in 2D), so
    ``factor_graph.error(values)`` equals our ``cost(graph, poses)``. No prior is added (see
    :func:`gauge_priors`). ``diagonal=True`` gives each edge instead a diagonal noise model with its
    marginal sigmas ``√diag(Ω⁻¹)``, as gtsam's LAGO requires (it refuses other noise models).
    """
    gtsam = require_gtsam()
    between = _factor_class(gtsam, graph, "Between")
    factors = gtsam.NonlinearFactorGraph()
    ids = graph.ids.tolist()
    if diagonal:
        sigmas = np.sqrt(np.diagonal(np.linalg.inv(graph.information), axis1=1, axis2=2))
        noises = [gtsam.noiseModel.Diagonal.Sigmas(sigma) for sigma in sigmas]
    else:
        noises = [gtsam.noiseModel.Gaussian.Information(info) for info in graph.information]
    for i, j, Z, noise in zip(graph.edge_from.tolist(), graph.edge_to.tolist(), graph.measurements, noises):
        factors.add(between(ids[i], ids[j], _element(gtsam, Z, graph.group), noise))
    if not diagonal:
        factors.push_back(prior_factors(graph))
    return factors


def prior_factors(graph):
    """The graph's priors (:mod:`posegraph.model.priors`) as gtsam factors, keys = vertex ids.

    Pose priors: ``PriorFactorPose3`` / ``PriorFactorPose2``; one with an offset ``O`` as the prior
    on ``X`` measuring ``Z O⁻¹`` with information ``Ad(O⁻¹)ᵀ Ω Ad(O⁻¹)``, the same cost exactly
    (``Log(Z⁻¹ X O) = Ad(O⁻¹) Log((Z O⁻¹)⁻¹ X)``). Position priors: ``GPSFactor`` (3D) and
    ``PoseTranslationPrior2D`` (2D), whose error is ``t(X) − z``. Empty without priors.
    """
    gtsam = require_gtsam()
    factors = gtsam.NonlinearFactorGraph()
    priors = graph.priors
    if priors is None:
        return factors
    group, planar = graph.group, _is_planar(graph)
    inverse_offsets = group.inverse(priors.pose_offsets)
    adjoint = group.adjoint(inverse_offsets)
    measurements = priors.pose_measurements @ inverse_offsets
    information = np.swapaxes(adjoint, -1, -2) @ priors.pose_information @ adjoint
    pose_prior = gtsam.PriorFactorPose2 if planar else gtsam.PriorFactorPose3
    for k, Z, omega in zip(priors.pose_vertex.tolist(), measurements, information):
        factors.add(pose_prior(int(graph.ids[k]), _gtsam_pose(gtsam, Z), gtsam.noiseModel.Gaussian.Information(omega)))
    position_prior = gtsam.PoseTranslationPrior2D if planar else gtsam.GPSFactor
    for k, z, omega in zip(priors.position_vertex.tolist(), priors.position_measurements, priors.position_information):
        factors.add(position_prior(int(graph.ids[k]), np.array(z), gtsam.noiseModel.Gaussian.Information(omega)))
    return factors


def gauge_priors(graph, poses: np.ndarray | None = None):
    """Tight ``PriorFactorPose3`` (``PriorFactorPose2``) on every ``FIX`` vertex and every component anchor, at ``poses``."""
    gtsam = require_gtsam()
    from posegraph.model.graph import component_anchors

    X = graph.poses if poses is None else poses
    held = np.union1d(np.flatnonzero(graph.fixed), component_anchors(graph))
    noise = gtsam.noiseModel.Isotropic.Sigma(graph.group.dim, ANCHOR_SIGMA)
    prior = _factor_class(gtsam, graph, "Prior")
    priors = gtsam.NonlinearFactorGraph()
    for k in held.tolist():
        priors.add(prior(int(graph.ids[k]), _element(gtsam, X[k], graph.group), noise))
    return priors


def gtsam_reference_cost(graph, start: np.ndarray, tolerance: float = 1e-14, max_iterations: int = 500) -> float:
    """A reference optimum: gtsam's LM from ``start`` with both error tolerances at ``tolerance``.

    The gauge is held by :func:`gauge_priors` at ``start``; the returned cost is that of the edges
    alone (``½ Σ eᵀΩe``, no prior), so it compares with ours.
    """
    gtsam = require_gtsam()
    factors = graph_to_gtsam(graph)
    with_priors = graph_to_gtsam(graph)
    with_priors.push_back(gauge_priors(graph, start))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(tolerance)
    params.setAbsoluteErrorTol(tolerance)
    params.setMaxIterations(max_iterations)
    optimizer = gtsam.LevenbergMarquardtOptimizer(with_priors, poses_to_values(graph.ids, start, graph.group), params)
    return float(factors.error(optimizer.optimize()))


@dataclass
class GtsamResult:
    """Outcome of :func:`run_gtsam`; costs are of the edges alone (no gauge priors)."""

    poses: np.ndarray
    """``(n, k, k)`` optimised poses in the graph's vertex order."""
    initial_poses: np.ndarray
    """``(n, k, k)`` the poses the optimiser started from."""
    initial_cost: float
    final_cost: float
    iterations: int
    converged: bool
    """True when gtsam stopped before ``max_iterations`` (its convergence test fired)."""
    method: str
    init: str
    costs: list = field(default_factory=list)
    """Cost after each iteration, from gtsam's ``iterationHook`` (this one includes the gauge priors'
    error, which stays below ~1e-12 for a graph without ``FIX`` vertices)."""
    seconds_iterations: list = field(default_factory=list)
    """Wall-clock seconds of each iteration."""
    seconds_read: float = 0.0
    """``gtsam.readG2o`` of the file, or building the factor graph from our arrays."""
    seconds_initialise: float = 0.0
    """``InitializePose3.initialize`` (3D chordal), ``lago.initialize`` (2D) or copying the start poses into ``Values``."""
    seconds_optimise: float = 0.0
    seconds_write: float = 0.0
    """``gtsam.writeG2o`` when an output path was given."""
    version: str = ""

    @property
    def seconds_total(self) -> float:
        return self.seconds_read + self.seconds_initialise + self.seconds_optimise + self.seconds_write


def run_gtsam(
    source,
    *,
    graph=None,
    init: str = "chordal",
    initial: np.ndarray | None = None,
    method: str = "lm",
    max_iterations: int = 100,
    relative_tolerance: float = 1e-5,
    absolute_tolerance: float = 1e-5,
    output: str | None = None,
) -> GtsamResult:
    """Optimise a pose graph with gtsam's LM or GN, timing each phase.

    ``source``: a g2o path (read with ``gtsam.readG2o(path, is3D)``, ``is3D`` False for a 2D file) or
    a :class:`~posegraph.model.graph.PoseGraph` (converted with :func:`graph_to_gtsam`). ``graph``: our
    model of the same file, used for vertex order, ``FIX`` flags, anchors and the dimension (read
    with ``posegraph.io.g2o.read_g2o`` when not given and ``source`` is a path).

    ``init``: ``"file"`` (the file's poses), ``"chordal"`` (gtsam's own initialiser: in 3D
    ``InitializePose3.initialize``, chordal relaxation for rotations then one Gauss-Newton step on
    full poses; in 2D ``lago.initialize``, on a copy of the graph with diagonal noise of the same
    marginal sigmas since LAGO refuses full noise models) or ``"given"`` (``initial`` ``(n, k, k)``,
    e.g. our own initialiser's output, so both optimisers share one start). The tolerances are
    gtsam's ``relativeErrorTol`` / ``absoluteErrorTol``; ``Pose2`` factors (BetweenFactorPose2,
    PriorFactorPose2) for a 2D graph.
    """
    gtsam = require_gtsam()
    if method not in ("lm", "gn"):
        raise ValueError(f"method must be 'lm' or 'gn', got {method!r}")
    if initial is not None:
        init = "given"
    if init not in ("file", "chordal", "given"):
        raise ValueError(f"init must be 'file', 'chordal' or 'given', got {init!r}")
    graph, factors, file_values, seconds_read = _read(gtsam, source, graph)
    t0 = time.perf_counter()
    values, priors = _start(gtsam, graph, factors, file_values, init, initial)
    seconds_initialise = time.perf_counter() - t0
    initial_poses = values_to_poses(values, graph.ids, graph.group)
    initial_cost = float(factors.error(values))

    full = gtsam.NonlinearFactorGraph(factors)
    full.push_back(priors)
    result, iterations, costs, seconds_iterations, seconds_optimise = _optimise(
        gtsam, full, values, method, max_iterations, relative_tolerance, absolute_tolerance
    )
    seconds_write = 0.0
    if output is not None:
        if _is_similarity(graph.group):
            raise ValueError("gtsam's writeG2o has no Sim(3) lines: write posegraph's output instead")
        t0 = time.perf_counter()
        gtsam.writeG2o(factors, result, str(output))
        seconds_write = time.perf_counter() - t0
    return GtsamResult(
        poses=values_to_poses(result, graph.ids, graph.group), initial_poses=initial_poses, initial_cost=initial_cost,
        final_cost=float(factors.error(result)), iterations=iterations,
        converged=iterations < int(max_iterations), method=method, init=init, costs=costs,
        seconds_iterations=seconds_iterations, seconds_read=seconds_read, seconds_initialise=seconds_initialise,
        seconds_optimise=seconds_optimise, seconds_write=seconds_write, version=_version(),
    )  # fmt: skip


def _read(gtsam, source, graph):
    """``(graph, gtsam factors, gtsam's file values or None, seconds)``: gtsam's reading of ``source``, timed
    (with our priors' factors: gtsam skips prior lines; our graph's factors when gtsam cannot read the file
    as we do: TORO's information order, EQUIV merges)."""
    if not (isinstance(source, (str, bytes)) or hasattr(source, "__fspath__")):
        t0 = time.perf_counter()
        factors = graph_to_gtsam(source)
        return source, factors, None, time.perf_counter() - t0
    import os

    path = os.fspath(source)
    if graph is None:
        from posegraph.io.g2o import read_g2o

        graph = read_g2o(path)  # also tells the dimension gtsam's reader must be given
    if _is_similarity(graph.group):  # gtsam.readG2o has no Sim(3) tags: from our reading, exact log
        from dataclasses import replace

        graph = replace(graph, group=replace(graph.group, residual_log=None))
        t0 = time.perf_counter()
        return graph, graph_to_gtsam(graph), None, time.perf_counter() - t0
    t0 = time.perf_counter()
    if graph.kept_lines:  # TORO's EQUIV merges, which gtsam's reader ignores: gtsam gets our reading
        return graph, graph_to_gtsam(graph), poses_to_values(graph.ids, graph.poses), time.perf_counter() - t0
    try:
        factors, file_values = gtsam.readG2o(path, not _is_planar(graph))
    except RuntimeError:  # e.g. "not G2O matrix order" (TORO's EDGE2 order, which we read): our reading
        return graph, graph_to_gtsam(graph), poses_to_values(graph.ids, graph.poses), time.perf_counter() - t0
    factors.push_back(prior_factors(graph))  # gtsam's reader skips g2o's prior lines
    return graph, factors, file_values, time.perf_counter() - t0


def _start(gtsam, graph, factors, file_values, init: str, initial):
    """``(start values, gauge priors)`` for ``init`` (see :func:`run_gtsam`)."""
    if init == "given":
        start = np.asarray(initial, dtype=np.float64)
        return poses_to_values(graph.ids, start, graph.group), gauge_priors(graph, start)
    priors = gauge_priors(graph)
    if init == "file":
        # A file without vertex lines (gtsam's sphere2500.txt, manhattan.g2o) gives gtsam no values:
        # use our model's poses.
        if file_values is not None and file_values.size():
            return file_values, priors
        return poses_to_values(graph.ids, graph.poses, graph.group), priors
    if _is_similarity(graph.group):
        from posegraph.errors import GraphError

        raise GraphError("gtsam has no Sim(3) initialiser: start gtsam from posegraph's poses (compare --gtsam-start same) "
                         "or the file's", graph.source)
    try:
        if _is_planar(graph):
            lago_graph = graph_to_gtsam(graph, diagonal=True)
            lago_graph.push_back(priors)
            return gtsam.lago.initialize(lago_graph), priors
        anchored = gtsam.NonlinearFactorGraph(factors)
        anchored.push_back(priors)
        return gtsam.InitializePose3.initialize(anchored), priors
    except (RuntimeError, IndexError) as exc:  # e.g. LAGO's "map::at" on ais2klinik, Pose3's indeterminate system
        from posegraph.errors import GraphError

        name = "lago.initialize" if _is_planar(graph) else "InitializePose3.initialize"
        raise GraphError(
            f"gtsam's {name} failed on this graph ({exc}); start gtsam from posegraph's poses instead "
            "(compare --gtsam-start same)", graph.source,
        ) from exc  # fmt: skip


def _optimise(gtsam, full, values, method, max_iterations, relative_tolerance, absolute_tolerance):
    """``(result, iterations, cost after each iteration, seconds of each, total seconds)`` of gtsam's LM or GN."""
    costs: list[float] = []
    stamps: list[float] = []

    def hook(iteration, error_before, error_after):
        stamps.append(time.perf_counter())
        costs.append(float(error_after))

    params = gtsam.LevenbergMarquardtParams() if method == "lm" else gtsam.GaussNewtonParams()
    params.setMaxIterations(int(max_iterations))
    params.setRelativeErrorTol(float(relative_tolerance))
    params.setAbsoluteErrorTol(float(absolute_tolerance))
    params.iterationHook = hook
    t0 = time.perf_counter()
    if method == "lm":
        optimizer = gtsam.LevenbergMarquardtOptimizer(full, values, params)
    else:
        optimizer = gtsam.GaussNewtonOptimizer(full, values, params)
    result = optimizer.optimize()
    seconds = time.perf_counter() - t0
    starts = [t0] + stamps[:-1]
    return result, int(optimizer.iterations()), costs, [b - a for a, b in zip(starts, stamps)], seconds


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("gtsam")
    except metadata.PackageNotFoundError:  # pragma: no cover - e.g. gtsam built from source
        return ""
