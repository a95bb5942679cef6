"""Marginal covariances of every pose: posegraph against ``gtsam.Marginals``, and scaling.

    python -m benchmarks.bench_covariance compare [--datasets sphere2500 torus3D] [--repeats 3]
    python -m benchmarks.bench_covariance scaling [--sizes 2500 10000 50000 200000] [--shape sphere]

``compare``: per dataset, one process reads the file and optimises it (``posegraph.optimize``);
at those poses it then alternates, ``repeats`` rounds after one warm-up round of each,
:func:`posegraph.analysis.covariance.marginal_covariances` for all vertices and gtsam's
``Marginals(graph + σ = 1e-6 priors on the held vertices, values)`` followed by
``marginalCovariance`` for every key — the order of the two swapped every round, so that a slow
spell of the shared machine hits both. Reports the median seconds of each, their ratio, and the
largest per-block relative difference ``max|ours − gtsam| / max|gtsam|`` over the free vertices
(held vertices: ours are zero, gtsam's carry the prior's σ² = 1e-12).

``scaling``: per size, a fresh worker process generates the synthetic shape (:mod:`datasets.synthetic`,
seed 0) and computes all covariances at the ground-truth poses (linearising there instead of at
the optimum saves the optimisation, which is not what is measured; the factor's pattern is the
same), timing each step (Hessian, ordering, Cholesky, cut into blocks, selected inversion) and the
peak resident memory of the covariance computation alone (the kernel's high-water mark reset just
before, ``/proc/self/clear_refs``, read after from ``VmHWM``), beside the process's ``ru_maxrss``.

Figures and commands: ``docs/covariances.md``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED_DATASETS = ROOT.parent / "shared" / "datasets"


def gtsam_all_marginals(graph, poses) -> np.ndarray:
    """``(n, 6, 6)`` from ``gtsam.Marginals`` with tight priors on the held vertices (what is timed)."""
    import gtsam

    from posegraph.crosscheck.gtsam_bridge import gauge_priors, graph_to_gtsam, poses_to_values

    factors = graph_to_gtsam(graph)
    factors.push_back(gauge_priors(graph, poses))
    marginals = gtsam.Marginals(factors, poses_to_values(graph.ids, poses))
    return np.stack([marginals.marginalCovariance(int(key)) for key in graph.ids.tolist()])


def compare(name: str, repeats: int) -> dict:
    """Side-by-side timing and agreement on one shared dataset."""
    import posegraph
    from posegraph.analysis.covariance import marginal_covariances
    from posegraph.model.graph import held_vertices

    graph = posegraph.read_g2o(SHARED_DATASETS / f"{name}.g2o")
    poses = posegraph.optimize(graph).poses
    tools = {
        "posegraph": lambda: marginal_covariances(graph, poses),
        "gtsam": lambda: gtsam_all_marginals(graph, poses),
    }
    seconds: dict[str, list[float]] = {tool: [] for tool in tools}
    results = {}
    for round_ in range(repeats + 1):
        order = list(tools) if round_ % 2 == 0 else list(tools)[::-1]
        for tool in order:
            start = time.perf_counter()
            results[tool] = tools[tool]()
            if round_ > 0:  # round 0 warms up both
                seconds[tool].append(time.perf_counter() - start)
    held = held_vertices(graph)
    ours, theirs = results["posegraph"], results["gtsam"]
    difference = np.abs(ours - theirs).max(axis=(1, 2)) / np.abs(theirs).max(axis=(1, 2))
    ours_s, gtsam_s = statistics.median(seconds["posegraph"]), statistics.median(seconds["gtsam"])
    return {
        "dataset": name,
        "poses": graph.num_vertices,
        "edges": graph.num_edges,
        "posegraph_seconds": ours_s,
        "gtsam_seconds": gtsam_s,
        "ratio": ours_s / gtsam_s,
        "max_relative_block_difference": float(difference[~held].max()),
        "held_vertices": int(held.sum()),
        "rounds": seconds,
    }


def routes(name: str, chunks: int = 3) -> dict:
    """Seconds of the alternative routes to all marginals on one dataset, at our optimum.

    ``selected_inversion``: :func:`marginal_covariances`. ``superlu_factor``: the same with the
    SuperLU fallback backend (``linear_solver="scipy"``). ``block_solves``: the CHOLMOD factor, then ``6`` right-hand sides per
    pose through ``cvxopt.cholmod.solve`` in chunks of 100 poses; ``chunks`` of them are timed and
    the total extrapolated (all of them would be ``p / 100``). ``gtsam``: as in :func:`compare`.
    """
    from cvxopt import cholmod, matrix, spmatrix

    import posegraph
    from posegraph.analysis import covariance as cv

    graph = posegraph.read_g2o(SHARED_DATASETS / f"{name}.g2o")
    poses = posegraph.optimize(graph).poses
    out = {"dataset": name}
    start = time.perf_counter()
    cv.marginal_covariances(graph, poses)
    out["selected_inversion"] = time.perf_counter() - start
    with cv._one_blas_thread():
        start = time.perf_counter()
        setup = cv._factorise(graph, poses, solver="scipy")
        cv.selected_inverse(setup.factor)
        out["superlu_factor"] = time.perf_counter() - start
        start = time.perf_counter()
        pattern, data = cv.hessian_at(graph, poses)
        n = pattern.dimension
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(pattern.indptr))
        A = spmatrix(matrix(data), matrix(pattern.indices.astype(np.int64)), matrix(cols), (n, n))
        F = cholmod.symbolic(A, uplo="L")
        cholmod.numeric(A, F)
        setup = time.perf_counter() - start
        per_chunk, width = [], 100 * 6
        for chunk in range(chunks):
            start = time.perf_counter()
            rhs = np.zeros((n, width))
            rhs[chunk * width + np.arange(width), np.arange(width)] = 1.0
            B = matrix(rhs)
            cholmod.solve(F, B)
            solved = np.asarray(B).reshape(width, n).T  # cvxopt is column-major
            _ = solved[chunk * width : (chunk + 1) * width].reshape(100, 6, 100, 6)[np.arange(100), :, np.arange(100), :]
            per_chunk.append(time.perf_counter() - start)
        out["block_solves"] = setup + statistics.median(per_chunk) * n / width
    start = time.perf_counter()
    gtsam_all_marginals(graph, poses)
    out["gtsam"] = time.perf_counter() - start
    return out


def _peak_reset() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _peak_bytes() -> int | None:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return None


def worker(shape: str, size: int) -> dict:
    """One scaling point, in this (fresh) process: seconds per step and peak memory."""
    import resource
    from dataclasses import replace

    from datasets.synthetic import generate
    from posegraph.analysis import covariance as cv
    from posegraph.linalg.cholmod import auto_ordering

    dataset = generate(shape, size, seed=0)
    graph, poses = dataset.graph, dataset.ground_truth
    d = graph.group.dim
    reset = _peak_reset()
    steps, start = {}, time.perf_counter()
    with cv._one_blas_thread():
        pattern, data = cv.hessian_at(graph, poses)
        ordering = auto_ordering(pattern.num_variables)
        steps["hessian"] = time.perf_counter() - start
        L, _ = cv.factor_hessian(pattern, data)  # ordering, analysis, numeric factorisation, getfactor
        del pattern, data
        steps["cholesky"] = time.perf_counter() - start - sum(steps.values())
        nnz = int(L.data.shape[0])
        factor = cv.block_factor(L, d)
        factor = replace(factor, scalar=None)  # as marginal_covariances: only the blocks are kept
        del L
        steps["blocks"] = time.perf_counter() - start - sum(steps.values())
        sigma = cv.selected_inverse(factor)
        steps["selected_inversion"] = time.perf_counter() - start - sum(steps.values())
    total = time.perf_counter() - start
    assert np.all(np.isfinite(sigma[factor.indptr[:-1]]))
    return {
        "shape": shape,
        "poses": graph.num_vertices,
        "edges": graph.num_edges,
        "ordering": ordering,
        "nnz_L": nnz,
        "blocks_L": factor.num_blocks,
        "supernodes": int(cv.supernodes(factor).shape[0] - 1),
        "seconds": total,
        "steps": steps,
        "peak_bytes_covariance": _peak_bytes() if reset else None,
        "ru_maxrss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
    }


def scaling(shape: str, sizes: list[int], timeout: float) -> list[dict]:
    rows = []
    for size in sizes:
        command = [sys.executable, "-m", "benchmarks.bench_covariance", "--worker", shape, str(size)]
        try:
            done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            print(f"{shape} {size}: over {timeout:.0f} s, stopped", file=sys.stderr)
            break
        if done.returncode != 0:
            print(f"{shape} {size}: failed (exit status {done.returncode})\n{done.stderr}", file=sys.stderr)
            break
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append(row)
        peak = row["peak_bytes_covariance"]
        print(
            f"{row['shape']:7s} {row['poses']:8d} poses  {row['seconds']:8.2f} s  "
            f"peak {peak / 2**20 if peak else float('nan'):8.0f} MiB  nnz(L) {row['nnz_L']:>11,d}  "
            + "  ".join(f"{k} {v:.2f}" for k, v in row["steps"].items()),
            flush=True,
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_covariance", description=__doc__.split("\n\n")[0])
    parser.add_argument("--worker", nargs=2, metavar=("SHAPE", "SIZE"), help=argparse.SUPPRESS)
    sub = parser.add_subparsers(dest="command")
    side = sub.add_parser("compare", help="posegraph against gtsam.Marginals on shared datasets")
    side.add_argument("--datasets", nargs="+", default=["sphere2500", "torus3D"])
    side.add_argument("--repeats", type=int, default=3)
    alternatives = sub.add_parser("routes", help="seconds of the alternative routes on one dataset")
    alternatives.add_argument("--dataset", default="sphere2500")
    scale = sub.add_parser("scaling", help="time and peak memory against the number of poses")
    scale.add_argument("--shape", default="sphere")
    scale.add_argument("--sizes", nargs="+", type=int, default=[2500, 10000, 50000, 200000])
    scale.add_argument("--timeout", type=float, default=600.0)
    for each in (side, scale, alternatives):
        each.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker[0], int(args.worker[1]))))
        return 0
    if args.command == "compare":
        rows = []
        for name in args.datasets:
            row = compare(name, args.repeats)
            rows.append(row)
            print(
                f"{name:15s} posegraph {row['posegraph_seconds']:7.3f} s  gtsam {row['gtsam_seconds']:7.3f} s  "
                f"ratio {row['ratio']:.4f} (1/{1 / row['ratio']:.0f})  max rel block diff {row['max_relative_block_difference']:.1e}",
                flush=True,
            )
    elif args.command == "routes":
        rows = [routes(args.dataset)]
        print("  ".join(f"{k} {v:.3f} s" if isinstance(v, float) else str(v) for k, v in rows[0].items()))
    elif args.command == "scaling":
        rows = scaling(args.shape, args.sizes, args.timeout)
    else:
        parser.print_help()
        return 2
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
