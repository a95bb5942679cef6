"""Landmark graphs in gtsam: the same cost as ours (:mod:`posegraph.solve.landmark_residuals`), and gtsam's LM on them.

Keys: poses under their vertex ids (as ``gtsam.readG2o`` and :mod:`posegraph.crosscheck.gtsam_bridge`
key them); landmark ``l`` (its index into ``graph.landmarks.ids``, not its file id) under
``gtsam.symbol('l', l)`` = ``ord('l')·2⁵⁶ + l``, which no pose id below 2⁵⁶ meets.

Factors, each with ``noiseModel.Gaussian.Information(Ω)`` so that ``error = ½ eᵀΩe``:

* pose edges and pose priors: :func:`posegraph.crosscheck.gtsam_bridge.graph_to_gtsam` (``BetweenFactorPose2/3``);
* ``"bearing"``: ``BearingFactor2D``; ``"bearing_range"``: ``BearingRangeFactor2D`` — both with our sign
  (gtsam's error is ``measured.localCoordinates(predicted)``: ``[wrap(θ − z_θ), r − z_r]``, order
  ``[bearing, range]``; checked in ``tests/solve/test_landmark_residuals.py``);
* ``"prior"``: ``PriorFactorPoint2`` / ``PriorFactorPoint3`` (error ``p − z``);
* ``"position"``: gtsam has no pose–point factor in its Python bindings (4.3: no ``PoseToPointFactor``;
  ``ReferenceFrameFactorPoint3Pose3`` transforms the other way), so a ``CustomFactor`` whose
  error and Jacobians are gtsam's own ``Pose2/Pose3.transformTo(p, H_pose, H_point)``:
  ``e' = X⁻¹ ⊙ p − z'``. A sensor offset ``O`` is folded into the measurement: ours is
  ``e = R_Oᵀ(X⁻¹ ⊙ p − t_O) − z = R_Oᵀ e'`` with ``z' = O ⊙ z = t_O + R_O z``, so with
  ``Ω' = R_O Ω R_Oᵀ`` the cost ``½ e'ᵀΩ'e' = ½ eᵀΩe`` is the same exactly (the residual vectors
  differ by the rotation ``R_O``).

That makes gtsam's side slow, and not for gtsam's reasons: inside gtsam's optimisers every call of a
Python factor receives a *copy* of the optimiser's ``Values`` (pybind11 copies a ``const Values&``
that has no Python owner), so each call costs O(variables) and an iteration O(position measurements
× variables) — measured here, 200 such factors: a Gauss-Newton iteration 0.014 s beside 100 variables,
1.56 s beside 10,000; DLR's ``dlr.g2o`` (14,309 positions, 3,873 variables) 30 s per iteration, where
the same linearisation, solve and error called from Python take 0.4 s. :func:`python_factor_note`
says so (``posegraph compare`` prints it before gtsam runs). The other kinds are gtsam's own factors.

Gauge: :func:`run_gtsam_landmarks` adds the bridge's tight priors on the anchors and ``FIX`` poses
(:func:`~posegraph.crosscheck.gtsam_bridge.gauge_priors`) and tight ``PriorFactorPoint`` on ``FIX``
landmarks, and reports costs without them.
"""

from __future__ import annotations

from dataclasses import dataclass

import time

import numpy as np

from posegraph.crosscheck.gtsam_bridge import ANCHOR_SIGMA, gauge_priors, graph_to_gtsam, poses_to_values, require_gtsam, values_to_poses

__all__ = [
    "landmark_key", "landmark_factors", "gtsam_landmark_graph", "gtsam_landmark_cost", "values_to_points",
    "GtsamLandmarkResult", "run_gtsam_landmarks", "python_factor_note",
]  # fmt: skip


def landmark_key(index: int) -> int:
    """gtsam key of landmark ``index``: ``gtsam.symbol('l', index)``."""
    return int(require_gtsam().symbol("l", int(index)))


def _position_error(planar: bool, measured: np.ndarray):
    """The ``CustomFactor`` error function ``X⁻¹ ⊙ p − z'`` with gtsam's ``transformTo`` Jacobians."""
    s = 2 if planar else 3

    def error(factor, values, jacobians):
        pose_key, point_key = factor.keys()
        X = values.atPose2(pose_key) if planar else values.atPose3(pose_key)
        p = values.atPoint2(point_key) if planar else values.atPoint3(point_key)
        H_pose, H_point = np.zeros((s, s + (1 if planar else 3)), order="F"), np.zeros((s, s), order="F")
        y = X.transformTo(p, H_pose, H_point)
        if jacobians is not None:
            jacobians[0], jacobians[1] = H_pose, H_point
        return y - measured

    return error


def _position_factors(gtsam, graph, family, factors) -> None:
    """``family``'s ``"position"`` measurements as CustomFactors (offsets folded in: module docstring)."""
    z, information = np.asarray(family.measurements, np.float64), np.asarray(family.information, np.float64)
    if family.offsets is not None:
        O = np.asarray(family.offsets, np.float64)
        s = z.shape[1]
        R_O, t_O = O[:, :s, :s], O[:, :s, s]
        z = t_O + np.einsum("qij,qj->qi", R_O, z)
        information = R_O @ information @ np.swapaxes(R_O, 1, 2)
    planar = graph.group.matrix_size == 3
    for i, l, measured, omega in zip(family.pose.tolist(), family.landmark.tolist(), z, information):
        noise = gtsam.noiseModel.Gaussian.Information(omega)
        keys = [int(graph.ids[i]), landmark_key(l)]
        factors.add(gtsam.CustomFactor(noise, keys, _position_error(planar, measured.copy())))


def python_factor_note(graph) -> str | None:
    """One line saying how many measurements gtsam's side runs as Python ``CustomFactor`` s and why that
    is slow (module docstring), or None when every factor is gtsam's own."""
    landmarks = graph.landmarks
    count = sum(f.count for f in landmarks.observations if f.kind == "position") if landmarks is not None else 0
    if count == 0:
        return None
    variables = graph.num_vertices + landmarks.count
    return (f"gtsam: {count:,} position measurements run as Python CustomFactors (gtsam's Python bindings have no "
            f"pose-point factor), each call copying gtsam's {variables:,} values inside its optimiser: "
            "gtsam's side costs O(measurements × variables) per iteration (minutes on thousands of poses), "
            "not its native speed")


def landmark_factors(graph):
    """``gtsam.NonlinearFactorGraph`` of the landmark measurements of ``graph`` (module docstring)."""
    gtsam = require_gtsam()
    factors = gtsam.NonlinearFactorGraph()
    if graph.landmarks is None:
        return factors
    planar = graph.group.matrix_size == 3
    for family in graph.landmarks.observations:
        if family.kind == "position":
            _position_factors(gtsam, graph, family, factors)
            continue
        noises = [gtsam.noiseModel.Gaussian.Information(omega) for omega in np.asarray(family.information, np.float64)]
        for i, l, z, noise in zip(family.pose.tolist(), family.landmark.tolist(), family.measurements, noises):
            if family.kind == "prior":
                prior = gtsam.PriorFactorPoint2 if planar else gtsam.PriorFactorPoint3
                factors.add(prior(landmark_key(l), np.array(z, dtype=np.float64), noise))
            elif family.kind == "bearing":
                factors.add(gtsam.BearingFactor2D(int(graph.ids[i]), landmark_key(l), gtsam.Rot2(float(z[0])), noise))
            else:
                factors.add(gtsam.BearingRangeFactor2D(int(graph.ids[i]), landmark_key(l), gtsam.Rot2(float(z[0])), float(z[1]), noise))
    return factors


def gtsam_landmark_graph(graph, poses: np.ndarray | None = None, points: np.ndarray | None = None):
    """``(factors, values)``: the pose edges and priors (bridge) and the landmark factors, the poses
    ``(n, k, k)`` and points ``(L, s)`` (the graph's own where None) under the module's keys."""
    poses = graph.poses if poses is None else poses
    factors = graph_to_gtsam(graph)
    factors.push_back(landmark_factors(graph))
    values = poses_to_values(graph.ids, poses, graph.group)
    if graph.landmarks is not None:
        points = graph.landmarks.positions if points is None else points
        for l, p in enumerate(np.asarray(points, dtype=np.float64)):
            values.insert(landmark_key(l), p.copy())
    return factors, values


def gtsam_landmark_cost(graph, poses: np.ndarray | None = None, points: np.ndarray | None = None) -> float:
    """gtsam's ``NonlinearFactorGraph.error`` of :func:`gtsam_landmark_graph`: ``½ Σ eᵀΩe`` over all terms."""
    factors, values = gtsam_landmark_graph(graph, poses, points)
    return float(factors.error(values))


def values_to_points(values, landmarks) -> np.ndarray:
    """Points ``(L, s)`` of ``landmarks`` read from gtsam ``values`` (keys :func:`landmark_key`)."""
    read = values.atPoint2 if landmarks.space_dim == 2 else values.atPoint3
    return np.array([read(landmark_key(l)) for l in range(landmarks.count)], dtype=np.float64).reshape(-1, landmarks.space_dim)


@dataclass
class GtsamLandmarkResult:
    """Outcome of :func:`run_gtsam_landmarks`; costs without the gauge priors."""

    poses: np.ndarray
    """``(n, k, k)`` optimised poses, in the graph's vertex order."""
    points: np.ndarray
    """``(L, s)`` optimised landmark positions."""
    initial_cost: float
    final_cost: float
    iterations: int
    converged: bool = True
    """Whether gtsam stopped before ``max_iterations``."""
    version: str = ""
    """gtsam's version."""
    seconds_read: float = 0.0
    """Building gtsam's factor graph from ours."""
    seconds_initialise: float = 0.0
    """Converting the start to ``gtsam.Values``."""
    seconds_optimise: float = 0.0
    """gtsam's optimiser."""


def run_gtsam_landmarks(
    graph, poses: np.ndarray | None = None, points: np.ndarray | None = None, *, method: str = "lm",
    max_iterations: int = 100, relative_tolerance: float = 1e-10, absolute_tolerance: float = 1e-12,
) -> GtsamLandmarkResult:  # fmt: skip
    """gtsam's Levenberg–Marquardt (``method="gn"``: Gauss–Newton) on the landmark graph from
    ``poses``/``points`` (the graph's if None)."""
    gtsam = require_gtsam()
    poses = graph.poses if poses is None else np.asarray(poses, np.float64)
    began = time.perf_counter()
    factors, values = gtsam_landmark_graph(graph, poses, points)
    built = time.perf_counter()
    full = gtsam.NonlinearFactorGraph(factors)
    full.push_back(gauge_priors(graph, poses))
    landmarks = graph.landmarks
    if landmarks is not None and landmarks.fixed.any():
        prior = gtsam.PriorFactorPoint2 if landmarks.space_dim == 2 else gtsam.PriorFactorPoint3
        noise = gtsam.noiseModel.Isotropic.Sigma(landmarks.space_dim, ANCHOR_SIGMA)
        start = values_to_points(values, landmarks)
        for l in np.flatnonzero(landmarks.fixed).tolist():
            full.add(prior(landmark_key(l), start[l], noise))
    params = gtsam.LevenbergMarquardtParams() if method == "lm" else gtsam.GaussNewtonParams()
    params.setMaxIterations(int(max_iterations))
    params.setRelativeErrorTol(float(relative_tolerance))
    params.setAbsoluteErrorTol(float(absolute_tolerance))
    optimizer = (gtsam.LevenbergMarquardtOptimizer if method == "lm" else gtsam.GaussNewtonOptimizer)(full, values, params)
    started = time.perf_counter()
    result = optimizer.optimize()
    finished = time.perf_counter()
    pose_values = gtsam.Values(result)  # the poses alone, for the bridge's reader
    for l in range(landmarks.count if landmarks is not None else 0):
        pose_values.erase(landmark_key(l))
    return GtsamLandmarkResult(
        poses=values_to_poses(pose_values, graph.ids, graph.group),
        points=values_to_points(result, landmarks) if landmarks is not None else np.zeros((0, graph.group.space_dim)),
        initial_cost=float(factors.error(values)), final_cost=float(factors.error(result)), iterations=int(optimizer.iterations()),
        converged=int(optimizer.iterations()) < int(max_iterations), version=getattr(gtsam, "__version__", ""),
        seconds_read=built - began, seconds_initialise=started - built, seconds_optimise=finished - started,
    )  # fmt: skip
