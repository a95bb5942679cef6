"""Incremental replay, side by side with gtsam's ISAM2: ``python -m benchmarks.bench_incremental``.

Each graph is replayed in vertex-id order, one new pose per update with every edge to a pose already
in, by both tools, each run in a fresh process (its peak memory is that process's ``ru_maxrss``),
the tools alternating from round to round:

* ours: :func:`posegraph.incremental.replay.replay` with default settings (``tolerance=1e-7``, ``DEFAULT_TOLERANCE``),
  or ``--tolerance T``;
* gtsam: ``ISAM2`` with default ``ISAM2Params`` (QR factorisation when Cholesky throws, as the issue's
  reference runs did in 2D), one ``update`` per new pose and the estimates it reads (the new pose's, and the
  pose a new one is composed from: ``calculateEstimatePose2/3``; the whole ``calculateEstimate`` costs
  O(variables) a call, and runs before git 5173593 called it every update), a tight prior on
  the first pose in place of our anchor (a loose one, ``LOOSE_PRIOR_SIGMA``, on a pose with no edge to the
  poses already in), a new pose's initial value composed from the estimate of the pose its first edge
  comes from;
* gtsam-converged (``--tools``): the same ISAM2 brought to the accuracy ours keeps, its relinearisation
  threshold ``--isam2-threshold`` (every variable whose delta passes it relinearised at each step), and
  after an update that adds more than one factor further ``update()`` calls until one lowers the whole
  graph's error by at most CONVERGED_TOLERANCE of it (the whole-graph error is part of its time, as ours
  evaluates the whole graph to know it is at the optimum).

Per graph: total replay seconds (the updates only), per-update mean/p99/max, peak memory, and the cost
excess of the estimate over the batch optimum of the same prefix (LM from the estimate, relative
tolerance 1e-12) at every ``--check-every``-th pose and at the end (checks are not timed). Figures:
``docs/incremental.md``; JSON with ``--json``, figure with ``--plot``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "datasets"
SESYNC = Path("/work/data-sesync")
EXTRA = Path("/work/data-incr")
"""Graphs fetched for this benchmark, outside the repository."""
TOOLS = ("posegraph", "gtsam", "gtsam-converged")
GRAPHS = ("intel", "manhattan", "city10000", "w10000", "sphere2500", "parking-garage", "torus3D", "synthetic100k")
TARGET_RATIO = 0.5
LOOSE_PRIOR_SIGMA = 1e4
"""σ of the prior ISAM2 gets on a pose with no edge to the poses already in (ours anchors it as a component
of its own until an edge joins it): its information 1e-8 adds ≲ 1e-8·d²/2 to the cost at distances d."""
CONVERGED_THRESHOLD = 1e-4
"""ISAM2's relinearisation threshold in the ``gtsam-converged`` runs (``--isam2-threshold``; ISAM2's
default is 0.1): a variable whose delta passes it is relinearised. Measured on parking-garage:800, 1e-3
leaves an excess of 3.5e-4, 1e-4 of 1.4e-7 and 1e-5 of 9e-11 (2.26, 2.49 and 3.35 s)."""
CONVERGED_TOLERANCE = 1e-7
"""``gtsam-converged`` stops iterating an update when a step lowers the error by at most this share of it."""
CONVERGED_STEPS = 20
COST_FLOOR = 1e-9
"""Relative excesses are divided by at least this: an odometry-only prefix has cost ~1e-27 (roundoff), not 0."""


def graph_path(name: str) -> Path | None:
    for folder in (SHARED, SESYNC, EXTRA):
        path = folder / f"{name}.g2o"
        if path.exists():
            return path
    return _gtsam_example(f"{name}.graph")


def _gtsam_example(filename: str) -> Path | None:
    """A file of the data gtsam's wheel bundles (TORO ``w10000.graph``), or None."""
    try:
        import gtsam

        path = Path(gtsam.findExampleDataFile("example.graph")).parent / filename
    except (ImportError, RuntimeError):
        return None
    return path if path.exists() else None


def load(name: str):
    """The graph ``name`` (one of GRAPHS); ``NAME:N``, its first ``N`` vertices in id order (:func:`prefix`)."""
    from posegraph.io.g2o import read_g2o

    if ":" in name:
        name, count = name.split(":")
        return prefix(load(name), int(count))
    if name == "synthetic100k":
        sys.path.insert(0, str(ROOT))
        from datasets.synthetic import generate

        return generate("manhattan", 100_000, seed=0).graph
    path = graph_path(name)
    if path is None:
        raise FileNotFoundError(f"{name}.g2o in neither {SHARED} nor {SESYNC}, nor {name}.graph in gtsam's data")
    return read_g2o(path, repair_information=True)


def prefix(graph, count: int):
    """The graph of the first ``count`` vertices in id order (edges among them)."""
    from dataclasses import replace

    order = np.argsort(graph.ids, kind="stable")[:count]
    keep = np.zeros(graph.num_vertices, bool)
    keep[order] = True
    edges = keep[graph.edge_from] & keep[graph.edge_to]
    index = np.full(graph.num_vertices, -1)
    index[order] = np.arange(count)
    return replace(graph, ids=graph.ids[order], poses=graph.poses[order], fixed=graph.fixed[order],
                   edge_from=index[graph.edge_from[edges]], edge_to=index[graph.edge_to[edges]],
                   measurements=graph.measurements[edges], information=graph.information[edges],
                   edge_source=None, edge_lines=None, priors=None, kept_lines=())


def batch_excess(graph, poses) -> tuple[float, float]:
    """``(cost at poses, relative excess over LM from them)`` for a graph whose first vertex is the anchor."""
    from posegraph.solve import SolverParams, optimize
    from posegraph.solve.residuals import cost

    ours = cost(graph, poses)
    params = SolverParams(relative_tolerance=1e-12, absolute_tolerance=0.0, max_iterations=200)
    best = min(optimize(graph, initial=poses, params=params).final_cost, ours)
    return ours, (ours - best) / max(best, COST_FLOOR)


def run_ours(graph, check_every: int, tolerance: float | None = None) -> dict:
    from posegraph.incremental import IncrementalOptimizer
    from posegraph.incremental.replay import replay

    checks = []

    def progress(result, number):
        n = int(result.poses_after[-1])
        if n % check_every == 0 or n == graph.num_vertices:
            opt = result.optimizer
            checks.append((n,) + batch_excess(prefix(graph, n), opt.poses))

    opt = IncrementalOptimizer(graph.group) if tolerance is None else IncrementalOptimizer(graph.group, tolerance=tolerance)
    result = replay(graph, 1, optimizer=opt, progress=progress)
    kinds = {k: result.kinds.count(k) for k in set(result.kinds)}
    return {"seconds": result.seconds.tolist(), "checks": checks, "analyses": opt._whole.analyses,
            "factorizations": opt._whole.factorizations, "kinds": kinds}


def _gtsam_types(graph):
    import gtsam

    if graph.group.name == "SE2":
        from posegraph.lie import se2

        def pose(m):
            x, y, t = se2.to_xytheta(m)
            return gtsam.Pose2(float(x), float(y), float(t))

        return gtsam.Pose2, gtsam.BetweenFactorPose2, gtsam.PriorFactorPose2, pose, lambda p: p.matrix()
    return gtsam.Pose3, gtsam.BetweenFactorPose3, gtsam.PriorFactorPose3, lambda m: gtsam.Pose3(m), lambda p: p.matrix()


def run_gtsam(graph, check_every: int, threshold: float | None = None) -> dict:
    """ISAM2 with default params, or (``threshold`` given) converged at every update with that
    relinearisation threshold (:func:`_converged_isam2`); when Cholesky throws (``IndeterminantLinearSystem``),
    the whole replay again with QR."""
    try:
        return dict(_run_isam2(graph, check_every, None, threshold), factorization="CHOLESKY")
    except RuntimeError as err:
        if "ndetermin" not in str(err):  # gtsam says "Indeterminate linear system"
            raise
        return dict(_run_isam2(graph, check_every, "QR", threshold), factorization="QR", cholesky_error=str(err).splitlines()[0])


def _isam2(factorization, threshold: float | None):
    import gtsam

    params = gtsam.ISAM2Params()
    if factorization is not None:
        params.setFactorization(factorization)
    if threshold is not None:
        params.setRelinearizeThreshold(threshold)
        params.relinearizeSkip = 1
    return gtsam.ISAM2(params)


def _converged_isam2(isam, estimate):
    """ISAM2 brought to posegraph's stopping rule after an update: further ``update()`` calls (each
    relinearises the variables whose delta passed the threshold and takes one Gauss-Newton step)
    until one lowers the whole graph's error by at most CONVERGED_TOLERANCE of it (the check is timed:
    an exact answer needs it), at most CONVERGED_STEPS of them. Returns ``(estimate, steps)``."""
    factors = isam.getFactorsUnsafe()
    cost = factors.error(estimate)
    for step in range(1, CONVERGED_STEPS + 1):
        isam.update()
        estimate = isam.calculateEstimate()
        now = factors.error(estimate)
        done = cost - now <= CONVERGED_TOLERANCE * now
        cost = now
        if done:
            return estimate, step
    return estimate, CONVERGED_STEPS


def _run_isam2(graph, check_every: int, factorization, threshold: float | None = None) -> dict:
    import gtsam

    _, between, prior, to_gtsam, to_matrix = _gtsam_types(graph)
    isam, converged = _isam2(factorization, threshold), threshold is not None
    order = np.argsort(graph.ids, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.shape[0])
    later = np.maximum(rank[graph.edge_from], rank[graph.edge_to])
    by_vertex = np.argsort(later, kind="stable")
    bounds = np.searchsorted(later[by_vertex], np.arange(order.shape[0] + 1))
    noise = [gtsam.noiseModel.Gaussian.Information(w) for w in graph.information]
    seconds, checks, extra = [], [], []
    for r, v in enumerate(order.tolist()):
        edges = by_vertex[bounds[r]:bounds[r + 1]]
        start = time.perf_counter()
        factors, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        guess = graph.poses[v]
        for e in edges.tolist():
            i, j = int(graph.edge_from[e]), int(graph.edge_to[e])
            factors.add(between(i, j, to_gtsam(graph.measurements[e]), noise[e]))
        for e in edges.tolist():
            i, j = int(graph.edge_from[e]), int(graph.edge_to[e])
            if i != v and isam.valueExists(i):
                guess = to_matrix(_estimate_of(isam, graph, i)) @ graph.measurements[e]
                break
            if j != v and isam.valueExists(j):
                guess = to_matrix(_estimate_of(isam, graph, j)) @ np.linalg.inv(graph.measurements[e])
                break
        values.insert(v, to_gtsam(guess))
        if r == 0:
            factors.add(prior(v, to_gtsam(guess), gtsam.noiseModel.Isotropic.Sigma(graph.group.dim, 1e-6)))
        elif edges.size == 0:  # no edge to a pose already in (w10000 after its EQUIV merges): ISAM2 needs a factor
            factors.add(prior(v, to_gtsam(guess), gtsam.noiseModel.Isotropic.Sigma(graph.group.dim, LOOSE_PRIOR_SIGMA)))
        isam.update(factors, values)
        if converged and edges.size > 1:  # one edge to a new pose leaves the optimum as it was: nothing to iterate
            extra.append(_converged_isam2(isam, isam.calculateEstimate())[1])
        else:
            _estimate_of(isam, graph, v)  # the new pose's estimate, what a front end reads each update
        seconds.append(time.perf_counter() - start)
        if (r + 1) % check_every == 0 or r + 1 == len(order):
            last = isam.calculateEstimate()
            poses = np.array([to_matrix(_at(last, graph, u)) for u in order[: r + 1].tolist()])
            checks.append((r + 1,) + batch_excess(prefix(graph, r + 1), poses))
    return {"seconds": seconds, "checks": checks, **({"extra_updates": int(np.sum(extra))} if converged else {})}


def _estimate_of(isam, graph, key):
    """ISAM2's estimate of one pose (``calculateEstimate()`` of every variable costs O(variables) a call)."""
    return isam.calculateEstimatePose2(key) if graph.group.name == "SE2" else isam.calculateEstimatePose3(key)


def _at(values, graph, key):
    return values.atPose2(key) if graph.group.name == "SE2" else values.atPose3(key)


def worker(tool: str, name: str, check_every: int, tolerance: float | None = None, threshold: float = CONVERGED_THRESHOLD) -> dict:
    """One tool's replay of ``name``: ``posegraph``, ``gtsam`` (ISAM2 defaults) or ``gtsam-converged``
    (ISAM2 at the relinearisation ``threshold``, iterated to posegraph's stopping rule at every update)."""
    graph = load(name)
    if tool == "posegraph":
        data = run_ours(graph, check_every, tolerance)
    else:
        data = run_gtsam(graph, check_every, threshold if tool == "gtsam-converged" else None)
    s = np.asarray(data["seconds"])
    ex = np.array([c[2] for c in data["checks"]])
    return {
        "tool": tool, "graph": name, "poses": graph.num_vertices, "edges": graph.num_edges,
        "total": float(s.sum()), "mean": float(s.mean()), "p99": float(np.percentile(s, 99)), "max": float(s.max()),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "excess_mean": float(ex.mean()), "excess_max": float(ex.max()), "excess_end": float(ex[-1]),
        "checks": data["checks"], "per_update": s.tolist(),
        **{k: data[k] for k in ("factorization", "cholesky_error", "analyses", "factorizations", "kinds", "extra_updates") if k in data},
    }


def spawn(tool: str, name: str, check_every: int, timeout: float, tolerance: float | None = None,
          threshold: float = CONVERGED_THRESHOLD, module: str = "benchmarks.bench_incremental") -> dict:
    """One tool's replay of ``name`` in a child process (``module``'s ``--worker``): its JSON row, or
    ``{tool, graph, error}``."""
    command = [sys.executable, "-m", module, "--worker", tool, name, "--check-every", str(check_every),
               "--isam2-threshold", repr(threshold)]
    command += [] if tolerance is None else ["--tolerance", repr(tolerance)]
    try:
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"tool": tool, "graph": name, "error": f"timed out after {timeout:.0f} s"}
    if done.returncode != 0:
        return {"tool": tool, "graph": name, "error": done.stderr.strip().splitlines()[-1] if done.stderr.strip()
                else f"exit status {done.returncode}, no message"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _line(row: dict) -> str:
    if "error" in row:
        return f"{row['graph']:>15} {row['tool']:>9}: {row['error']}"
    return (f"{row['graph']:>15} {row['tool']:>9}: total {row['total']:8.2f} s, mean {1e3 * row['mean']:7.2f} ms, "
            f"p99 {1e3 * row['p99']:8.2f} ms, max {1e3 * row['max']:8.1f} ms, peak {row['peak_rss_mib']:6.0f} MiB, "
            f"excess mean {row['excess_mean']:.2g} max {row['excess_max']:.2g} end {row['excess_end']:.2g}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graphs", nargs="*", default=list(GRAPHS))
    parser.add_argument("--worker", nargs=2, metavar=("TOOL", "GRAPH"), help=argparse.SUPPRESS)
    parser.add_argument("--check-every", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--tolerance", type=float, default=None, help="ours: IncrementalOptimizer(tolerance=T)")
    parser.add_argument("--tools", nargs="+", default=["posegraph", "gtsam"], choices=TOOLS,
                        help="tools to alternate (default: posegraph gtsam; gtsam-converged: ISAM2 iterated to our stopping rule)")
    parser.add_argument("--isam2-threshold", type=float, default=CONVERGED_THRESHOLD,
                        help=f"gtsam-converged's relinearisation threshold (default {CONVERGED_THRESHOLD:g})")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds per process")
    parser.add_argument("--json", metavar="PATH")
    parser.add_argument("--plot", metavar="PNG")
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(*args.worker, args.check_every, args.tolerance, args.isam2_threshold)))
        return 0
    rows = []
    for name in args.graphs:
        if name.split(":")[0] != "synthetic100k" and graph_path(name.split(":")[0]) is None:
            print(f"{name:>15}: skipped (no {name}.g2o in {SHARED} or {SESYNC})", flush=True)
            continue
        for repeat in range(args.repeats):
            tools = args.tools if repeat % 2 == 0 else args.tools[::-1]
            for tool in tools:
                rows.append(spawn(tool, name, args.check_every, args.timeout, args.tolerance, args.isam2_threshold))
                print(_line(rows[-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps([{k: v for k, v in r.items() if k != "per_update"} for r in rows], indent=1))
    if args.plot:
        _plot(rows, args.plot)
    return 0


def _plot(rows, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = [r for r in rows if "error" not in r]
    names = sorted({r["graph"] for r in done})
    fig, axes = plt.subplots(len(names), 2, figsize=(11, 3 * len(names)), squeeze=False)
    for row_axes, name in zip(axes, names):
        for r in (r for r in done if r["graph"] == name):
            s = np.asarray(r["per_update"])
            row_axes[0].semilogy(np.arange(1, s.size + 1), 1e3 * np.maximum(s, 1e-6), ".", markersize=1, label=r["tool"])
            checks = np.array([(c[0], max(c[2], 1e-17)) for c in r["checks"]])
            row_axes[1].semilogy(checks[:, 0], checks[:, 1], "-", label=r["tool"])
        row_axes[0].set_ylabel(f"{name}\nupdate ms")
        row_axes[1].set_ylabel("cost excess")
        row_axes[1].axhline(1e-6, color="r", linestyle="--", linewidth=1)
        row_axes[0].legend()
    axes[-1][0].set_xlabel("poses")
    axes[-1][1].set_xlabel("poses")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


if __name__ == "__main__":
    sys.exit(main())
