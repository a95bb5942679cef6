"""Landmark graphs replayed side by side with gtsam's ISAM2: ``python -m benchmarks.bench_incremental_landmarks``.

Default file: gtsam's ``victoria_park.txt`` as gtsam's own ``load2D`` reads it: odometry as ``BetweenFactorPose2``
and each ``LANDMARK`` sighting as a ``BearingRangeFactor2D`` (bearing σ 0.2, range σ √0.4), written out as a
file posegraph reads (``EDGE_SE2`` with the factors' information, gtsam's ``BR`` lines: :func:`gtsam_problem_file`),
so that both tools solve one problem (posegraph's own reading of the file's ``LANDMARK`` lines is a position
measurement, another problem). Other files are read as ``posegraph replay`` reads them. Both tools take the same batches
(:func:`posegraph.incremental.replay.replay_batches`: one pose per update with its odometry, the
landmarks it sees first and its sightings), each tool in its own process, alternating from round to round:

* ours: :func:`posegraph.incremental.replay.replay` with default settings;
* gtsam: ``ISAM2`` with default ``ISAM2Params``, one ``update`` per pose and the estimate of the new pose
  (``calculateEstimatePose2``: the whole estimate, ``calculateEstimate``, costs O(variables) a call), the
  factors of :mod:`posegraph.crosscheck.gtsam_landmarks` (``BetweenFactorPose2``, ``BearingRangeFactor2D``:
  gtsam's error equals our cost, checked in the tests), a tight prior on the first pose in place of our
  anchor, a new pose composed from its odometry, a new landmark placed from its first sighting;
* gtsam-converged (``--tools``): the same ISAM2 iterated to our stopping rule (``bench_incremental``).

Per tool: total seconds of the updates, mean/p99 per update, and the relative cost excess of the estimate over
the batch optimum of the same prefix at every ``--check-every``-th pose (default 100) and at the end, untimed
and by one function for both tools (:func:`landmark_excess`: posegraph's cost, posegraph's batch ``optimize``
of :func:`landmark_prefix` from the estimate). At each ISAM2 check the error of the factors ISAM2 holds
(without its prior) is compared with posegraph's cost of the same estimate (``cost_agreement``, the largest
relative difference: ~1e-12 when both tools solve one problem).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.bench_incremental import CONVERGED_THRESHOLD, _line, spawn

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_FILES = ("gtsam:victoria_park.txt",)
ANCHOR_SIGMA = 1e-6
"""σ of ISAM2's prior on the first pose (ours holds it): its cost at the optimum is ~0."""


def file_path(name: str) -> Path:
    """A file path, or ``gtsam:NAME`` for a file of gtsam's bundled data."""
    if name.startswith("gtsam:"):
        import gtsam

        return Path(gtsam.findExampleDataFile(name.split(":", 1)[1]))
    return Path(name)


def gtsam_problem_file(source: Path, out: Path) -> Path:
    """Write gtsam's ``load2D`` reading of ``source`` as ``VERTEX_SE2`` (its initial poses), ``EDGE_SE2``
    (each ``BetweenFactorPose2``, its noise model's information, upper triangle) and ``BR i l θ r σθ σr``
    lines (each ``BearingRangeFactor2D``, its diagonal sigmas), which posegraph reads as the same factors."""
    import gtsam

    factors, initial = gtsam.load2D(str(source))
    lines = []
    for key in initial.keys():
        if gtsam.Symbol(key).chr() == 0:
            pose = initial.atPose2(key)
            lines.append(f"VERTEX_SE2 {key} {pose.x()!r} {pose.y()!r} {pose.theta()!r}")
    for index in range(factors.size()):
        factor = factors.at(index)
        if isinstance(factor, gtsam.BetweenFactorPose2):
            z, info = factor.measured(), factor.noiseModel().information()
            upper = " ".join(repr(float(info[r, c])) for r in range(3) for c in range(r, 3))
            lines.append(f"EDGE_SE2 {factor.keys()[0]} {factor.keys()[1]} {z.x()!r} {z.y()!r} {z.theta()!r} {upper}")
        else:
            pose, point = factor.keys()
            z, sigmas = factor.measured(), factor.noiseModel().sigmas()
            lines.append(f"BR {pose} {gtsam.Symbol(point).index()} {z.bearing().theta()!r} {z.range()!r} {float(sigmas[0])!r} {float(sigmas[1])!r}")
    out.write_text("\n".join(lines) + "\n")
    return out


def load(name: str):
    """The graph of ``name``: ``gtsam:victoria_park.txt`` as gtsam reads it (module docstring), else as
    ``posegraph replay`` reads the file."""
    import tempfile

    from posegraph.io.g2o import read_g2o

    path = file_path(name)
    if name.startswith("gtsam:") and path.suffix == ".txt":
        with tempfile.TemporaryDirectory() as folder:
            return read_g2o(gtsam_problem_file(path, Path(folder) / "problem.g2o"))
    return read_g2o(path)


def landmark_prefix(graph, batches: list, count: int):
    """``(prefix graph, its vertices, its landmarks)``: the graph a replay holds after the first ``count`` of
    ``batches`` (:func:`posegraph.incremental.replay.replay_batches` of ``graph``, one pose each): the first
    ``count`` poses in id order (``bench_incremental.prefix``), the landmarks they saw first in the order they
    entered, and the measurements of those poses; vertices and landmarks as indices into ``graph``."""
    from dataclasses import replace

    from benchmarks.bench_incremental import prefix

    if graph.priors is not None:
        raise ValueError("landmark_prefix takes graphs without pose or position priors")
    kept, model = batches[:count], graph.landmarks
    vertices = np.concatenate([b[0] for b in kept]).astype(np.int64)
    landmarks = np.concatenate([np.zeros(0, np.int64)] + [b[4] for b in kept]).astype(np.int64)
    pose_index, landmark_index = np.full(graph.num_vertices, -1), np.full(model.count, -1)
    pose_index[vertices], landmark_index[landmarks] = np.arange(vertices.size), np.arange(landmarks.size)
    families = []
    for f, family in enumerate(model.observations):
        rows = np.concatenate([np.zeros(0, np.int64)] + [b[5][f] for b in kept]).astype(np.int64)
        families.append(replace(family, pose=np.where(family.pose[rows] < 0, -1, pose_index[family.pose[rows]]),
                                landmark=landmark_index[family.landmark[rows]], measurements=family.measurements[rows],
                                information=family.information[rows], lines=None, offset_ids=None, text=None,
                                offsets=None if family.offsets is None else family.offsets[rows]))
    held = replace(model, ids=model.ids[landmarks], positions=model.positions[landmarks], fixed=model.fixed[landmarks],
                   observations=tuple(families))
    return replace(prefix(graph, count), landmarks=held), vertices, landmarks


def landmark_excess(graph, poses, points) -> tuple[float, float]:
    """``(cost, relative excess over the batch optimum)`` of ``poses`` ``(n, k, k)`` and ``points`` ``(L, s)``
    on ``graph``: posegraph's cost, and posegraph's batch ``optimize`` from them (LM, relative tolerance 1e-12)
    as the optimum. The one measure of both tools' estimates."""
    from benchmarks.bench_incremental import COST_FLOOR
    from posegraph.solve import SolverParams, optimize
    from posegraph.solve.objective import Objective

    ours = Objective(graph).evaluate(poses, points).cost
    params = SolverParams(relative_tolerance=1e-12, absolute_tolerance=0.0, max_iterations=200)
    best = min(optimize(graph, initial=poses, params=params, initial_points=points).final_cost, ours)
    return ours, (ours - best) / max(best, COST_FLOOR)


def _is_check(number: int, check_every: int, total: int) -> bool:
    return number % check_every == 0 or number == total


def run_ours(graph, check_every: int) -> dict:
    """``posegraph.incremental.replay.replay`` with default settings; the checks (untimed) by
    :func:`landmark_excess` on :func:`landmark_prefix`."""
    from posegraph.incremental.replay import replay, replay_batches

    batches, checks = list(replay_batches(graph, 1)), []

    def progress(result, number):
        if _is_check(number, check_every, len(batches)):
            opt = result.optimizer
            held, _, landmarks = landmark_prefix(graph, batches, number)
            order = {int(i): r for r, i in enumerate(np.asarray(opt.landmark_ids).tolist())}
            points = np.asarray(opt.landmark_positions)[[order[int(i)] for i in graph.landmarks.ids[landmarks]]]
            checks.append((number, landmark_excess(held, opt.poses, points)[1]))

    result = replay(graph, 1, progress=progress)
    return {"seconds": result.seconds.tolist(), "checks": checks,
            "kinds": {k: result.kinds.count(k) for k in set(result.kinds)}}


def batch_factors(graph, batch, edge_factors, landmark_factors, family_offsets):
    """The gtsam factors of one replay batch: its pose edges, then its landmark measurements by family."""
    import gtsam

    _, edges, _, _, _, families = batch
    factors = gtsam.NonlinearFactorGraph()
    for e in np.asarray(edges).tolist():
        factors.add(edge_factors.at(e))
    for offset, rows in zip(family_offsets, families):
        for r in np.asarray(rows).tolist():
            factors.add(landmark_factors.at(offset + r))
    return factors


def _initial_values(graph, batch, isam, to_matrix):
    """``(values, pose)``: the batch's new pose composed from ISAM2's estimate of its first edge's other end
    (its file pose for the first one), and each new landmark placed from its first sighting in the batch."""
    import gtsam

    from posegraph.crosscheck.gtsam_landmarks import landmark_key
    from posegraph.lie import se2

    vertices, edges, _, _, landmarks, families = batch
    v = int(vertices[0])
    pose = graph.poses[v]
    for e in np.asarray(edges).tolist():
        i, j = int(graph.edge_from[e]), int(graph.edge_to[e])
        if j == v and isam.valueExists(int(graph.ids[i])):
            pose = to_matrix(isam.calculateEstimatePose2(int(graph.ids[i]))) @ graph.measurements[e]
            break
    values = gtsam.Values()
    values.insert(int(graph.ids[v]), gtsam.Pose2(*se2.to_xytheta(pose)))
    placed = {int(l): graph.landmarks.positions[l] for l in np.asarray(landmarks).tolist()}
    for family, rows in zip(graph.landmarks.observations, families):
        for r in np.asarray(rows).tolist():
            l = int(family.landmark[r])
            if l in placed and family.kind == "bearing_range" and int(family.pose[r]) == v:
                bearing, distance = family.measurements[r]
                placed[l] = (pose @ np.array([distance * np.cos(bearing), distance * np.sin(bearing), 1.0]))[:2]
    for l, p in placed.items():
        values.insert(landmark_key(l), np.asarray(p, dtype=np.float64).copy())
    return values, pose


def run_isam2(graph, check_every: int, threshold: float | None = None) -> dict:
    """ISAM2 with default params, or (``threshold`` given) iterated to posegraph's stopping rule after each
    update that adds more than one factor (``bench_incremental``'s ``gtsam-converged``). Each check (untimed):
    ``(poses, excess, agreement)``, :func:`isam2_check`."""
    import gtsam

    from benchmarks.bench_incremental import _converged_isam2, _isam2
    from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam
    from posegraph.crosscheck.gtsam_landmarks import landmark_factors
    from posegraph.incremental.replay import replay_batches

    edge_factors, measured = graph_to_gtsam(graph), landmark_factors(graph)
    offsets = np.concatenate([[0], np.cumsum([f.count for f in graph.landmarks.observations])[:-1]]).astype(int).tolist()
    isam, seconds, checks, extra = _isam2(None, threshold), [], [], []
    to_matrix = lambda p: p.matrix()  # noqa: E731
    batches = list(replay_batches(graph, 1))
    for number, batch in enumerate(batches, 1):
        start = time.perf_counter()
        factors = batch_factors(graph, batch, edge_factors, measured, offsets)
        values, pose = _initial_values(graph, batch, isam, to_matrix)
        if number == 1:
            noise = gtsam.noiseModel.Isotropic.Sigma(3, ANCHOR_SIGMA)
            prior = gtsam.PriorFactorPose2(int(graph.ids[batch[0][0]]), values.atPose2(int(graph.ids[batch[0][0]])), noise)
            factors.add(prior)
        isam.update(factors, values)
        if threshold is not None and factors.size() > 1:
            extra.append(_converged_isam2(isam, isam.calculateEstimate())[1])
        else:
            isam.calculateEstimatePose2(int(graph.ids[batch[0][0]]))  # the latest pose, what a front end reads
        seconds.append(time.perf_counter() - start)
        if _is_check(number, check_every, len(batches)):
            checks.append((number, *isam2_check(graph, batches, number, isam, prior)))
    return {"seconds": seconds, "checks": checks, **({"extra_updates": int(np.sum(extra))} if threshold is not None else {})}


def isam2_check(graph, batches: list, count: int, isam, prior) -> tuple[float, float]:
    """``(excess, agreement)`` of ISAM2's estimate after ``count`` updates: its :func:`landmark_excess` on
    :func:`landmark_prefix`, and ``|gtsam error − posegraph cost| / posegraph cost`` at that estimate, gtsam's
    error being that of the factors ISAM2 holds without the anchoring ``prior`` (the two tools solve one problem
    when it is ~1e-12)."""
    from posegraph.crosscheck.gtsam_landmarks import landmark_key

    estimate = isam.calculateEstimate()
    held, vertices, landmarks = landmark_prefix(graph, batches, count)
    poses = np.stack([estimate.atPose2(int(graph.ids[v])).matrix() for v in vertices.tolist()])
    points = np.array([estimate.atPoint2(landmark_key(l)) for l in landmarks.tolist()]).reshape(-1, 2)
    cost, excess = landmark_excess(held, poses, points)
    error = isam.getFactorsUnsafe().error(estimate) - prior.error(estimate)
    return excess, abs(error - cost) / max(cost, 1e-300)


def worker(tool: str, name: str, check_every: int, threshold: float | None = None) -> dict:
    """One tool's replay: ``posegraph``, ``gtsam`` (ISAM2 defaults) or ``gtsam-converged`` (at ``threshold``)."""
    graph = load(name)
    if tool == "posegraph":
        data = run_ours(graph, check_every)
    else:
        data = run_isam2(graph, check_every, threshold if tool == "gtsam-converged" else None)
    s, excess = np.asarray(data["seconds"]), np.array([c[1] for c in data["checks"]])
    agreement = {"cost_agreement": max(c[2] for c in data["checks"])} if tool != "posegraph" else {}
    return {"tool": tool, "graph": name, "poses": graph.num_vertices, "landmarks": graph.landmarks.count,
            "measurements": int(graph.landmarks.num_measurements), "total": float(s.sum()), "mean": float(s.mean()),
            "p99": float(np.percentile(s, 99)), "max": float(s.max()), "excess_mean": float(excess.mean()),
            "excess_max": float(excess.max()), "excess_end": float(excess[-1]), "checks": data["checks"], **agreement,
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            **{k: data[k] for k in ("kinds", "extra_updates") if k in data}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", default=list(DEFAULT_FILES), help="landmark files (gtsam:NAME: gtsam's bundled data)")
    parser.add_argument("--worker", nargs=2, metavar=("TOOL", "FILE"), help=argparse.SUPPRESS)
    parser.add_argument("--check-every", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds per process")
    parser.add_argument("--json", metavar="PATH")
    parser.add_argument("--tools", nargs="+", default=["posegraph", "gtsam"], choices=("posegraph", "gtsam", "gtsam-converged"))
    parser.add_argument("--isam2-threshold", type=float, default=CONVERGED_THRESHOLD, help="gtsam-converged's relinearisation threshold")
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(*args.worker, args.check_every, args.isam2_threshold)))
        return 0
    rows = []
    for name in args.files:
        for repeat in range(args.repeats):
            for tool in args.tools if repeat % 2 == 0 else args.tools[::-1]:
                rows.append(spawn(tool, name, args.check_every, args.timeout, threshold=args.isam2_threshold,
                                  module="benchmarks.bench_incremental_landmarks"))
                print(_line(rows[-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
