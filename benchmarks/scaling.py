"""Scaling study: seconds and peak memory per phase against the number of edges.

    python -m benchmarks.scaling [--shapes sphere slab cube] [--sizes 1000 ... 200000] [--out docs/]

For every (shape, size) the parent process generates a synthetic graph (:mod:`datasets.synthetic`,
seed 0, default noise), writes it to a temporary g2o file and runs one *worker* process on it
(``python -m benchmarks.scaling --worker IN.g2o --report R.json``) that reads, initialises
(chordal), optimises (default parameters) and writes, timing each phase and its peak resident
memory: before a phase the worker resets the kernel's high-water mark (``/proc/self/clear_refs``
← 5) and after it reads ``VmHWM`` from ``/proc/self/status``. The optimiser's own split
(linearise, assemble, factorise, solve per iteration; symbolic setup once) comes from
:class:`posegraph.solve.OptimizeResult`. The parent adds the whole-process wall time and
``ru_maxrss``.

Fill-in: the solver does not expose CHOLMOD's factor, so the parent analyses the same sparsity at
the vertex level (one scalar per pose, an SPD matrix with the graph's adjacency) with CHOLMOD's
AMD and METIS orderings and reports ``nnz(L)`` and the factorisation flops ``Σ_j c_j²`` of the
column counts ``c_j``. Each 6×6 block of the real system multiplies them by 36 (nnz) and 216
(flops). That is what grows faster than linearly: roughly ``n log n`` for a sphere or a
few-layer slab (planar-like graphs, separators ~ √n) and ``n^{4/3}`` nnz / ``n²`` flops for a
full 3D lattice (separators ~ n^{2/3}).

Shapes: ``sphere`` (rings × nodes, as g2o's create_sphere), ``slab`` (a 3D grid 8 layers high:
a multi-storey building) and ``cube`` (a full 3D grid, the worst case for fill-in; sizes above
~30,000 poses take minutes per factorisation, so it stops there by default).

Writes ``scaling.json`` and ``scaling.png`` (matplotlib, Agg) into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SLAB_LAYERS = 8
DEFAULT_SIZES = {
    "sphere": (1000, 2000, 5000, 10000, 20000, 50000, 100000, 200000),
    "slab": (1000, 2000, 5000, 10000, 20000, 50000, 100000, 200000),
    "cube": (1000, 3375, 8000, 15625, 27000),
}
MACHINE_MEMORY_GB = 24


# --------------------------------------------------------------------------------------------
# Worker (runs in its own process)


def _high_water_mark() -> int:
    """Peak resident memory of this process since the last reset, bytes (``VmHWM``)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def _reset_high_water_mark() -> bool:
    """Reset ``VmHWM`` to the current resident size (Linux ≥ 4.0); False if not allowed."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def worker(source: str, report_path: str, output: str) -> int:
    """Read, initialise, optimise and write ``source``; time and measure each phase; write a JSON report."""
    started = time.perf_counter()
    from posegraph.init import initialize
    from posegraph.io.g2o import read_g2o, write_g2o
    from posegraph.solve import optimize

    seconds, peak = {"import": time.perf_counter() - started}, {}
    resettable = _reset_high_water_mark()

    def phase(name, function):
        _reset_high_water_mark()
        t = time.perf_counter()
        value = function()
        seconds[name] = time.perf_counter() - t
        peak[name] = _high_water_mark()
        return value

    graph = phase("read", lambda: read_g2o(source))
    start = phase("initialize", lambda: initialize(graph, method="chordal"))
    result = phase("optimize", lambda: optimize(graph, initial=start))
    phase("write", lambda: write_g2o(output, graph, result.poses))
    records = result.records
    report = {
        "vertices": graph.num_vertices,
        "edges": graph.num_edges,
        "seconds": seconds,
        "peak_bytes": peak,
        "peak_per_phase_measured": resettable,
        "initial_cost": result.initial_cost,
        "final_cost": result.final_cost,
        "iterations": result.iterations,
        "factorizations": int(sum(r.attempts for r in records)),
        "termination": result.termination,
        "converged": result.converged,
        "linear_solver": result.linear_solver,
        "optimize_split": {
            "setup": result.seconds_setup,
            "linearize": result.seconds_linearize,
            "assemble": result.seconds_assemble,
            "factorize": result.seconds_factorize,
            "solve": result.seconds_solve,
        },
    }
    Path(report_path).write_text(json.dumps(report, indent=1))
    return 0


# --------------------------------------------------------------------------------------------
# Parent


def make_dataset(shape: str, size: int, seed: int = 0):
    """The synthetic graph of one scaling point."""
    from datasets.synthetic import generate, shape_arguments

    if shape == "sphere":
        return generate("sphere", size, seed=seed)
    if shape == "cube":
        return generate("grid", size, seed=seed)
    if shape == "slab":
        side = max(2, round((size / SLAB_LAYERS) ** 0.5))
        return generate("grid", None, seed=seed, nx=side, ny=side, nz=SLAB_LAYERS)
    raise ValueError(f"unknown scaling shape {shape!r}")


def fill_in(graph) -> dict:
    """Vertex-level CHOLMOD analysis of the graph's normal-equation sparsity, AMD and METIS.

    Returns per ordering ``nnz_L`` (vertex level), ``flops`` (``Σ c_j²``), and the scalar
    estimates ``nnz_L_scalar`` = 36·``nnz_L`` and ``flops_scalar`` = 216·``flops``; plus
    ``nnz_H`` (lower triangle, vertex level) of the matrix itself.
    """
    import scipy.sparse as sp
    from sksparse import cholmod

    n = graph.num_vertices
    i, j = graph.edge_from, graph.edge_to
    lower = sp.coo_matrix((np.ones(len(i)), (np.maximum(i, j), np.minimum(i, j))), shape=(n, n)).tocsc()
    lower.sum_duplicates()
    lower.data[:] = -0.1  # only the pattern matters
    degree = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
    matrix = (lower + lower.T + sp.diags(degree + 1.0)).tocsc()  # strictly diagonally dominant: SPD
    out = {"nnz_H": int(sp.tril(matrix).nnz)}
    for ordering in ("amd", "metis"):
        factor = cholmod.cholesky(matrix, ordering_method=ordering)
        L = factor.L()
        counts = np.diff(L.indptr).astype(np.float64)
        out[ordering] = {
            "nnz_L": int(L.nnz),
            "flops": float(np.sum(counts**2)),
            "nnz_L_scalar": int(36 * L.nnz),
            "flops_scalar": float(216 * np.sum(counts**2)),
        }
    return out


def run_point(shape: str, size: int, timeout: float, log=print) -> dict:
    """Generate one graph, analyse its fill-in, and measure one worker process on it."""
    from benchmarks.harness import ROOT, run_process
    from datasets.synthetic import write_dataset

    t = time.perf_counter()
    dataset = make_dataset(shape, size)
    graph = dataset.graph
    seconds_generate = time.perf_counter() - t
    fill = fill_in(graph)
    with tempfile.TemporaryDirectory(prefix="posegraph-scaling-") as tmp:
        source = Path(tmp) / f"{dataset.name}.g2o"
        write_dataset(source, dataset)
        report_path = Path(tmp) / "report.json"
        output = Path(tmp) / "out.g2o"
        file_bytes = source.stat().st_size
        command = [sys.executable, "-m", "benchmarks.scaling", "--worker", str(source), "--report", str(report_path), "--write", str(output)]
        process = run_process(command, timeout=timeout, cwd=ROOT)
        if process.returncode != 0 or not report_path.is_file():
            tail = process.stderr.strip().splitlines()[-1:] or [f"exit {process.returncode}"]
            log(f"  {dataset.name}: worker failed: {tail[0]}")
            return {"shape": shape, "size": size, "name": dataset.name, "error": tail[0], "wall": process.wall}
        report = json.loads(report_path.read_text())
    point = {
        "shape": shape,
        "size": size,
        "name": dataset.name,
        "file_bytes": file_bytes,
        "seconds_generate": seconds_generate,
        "wall": process.wall,
        "max_rss": process.max_rss,
        "cpu": process.cpu,
        "fill": fill,
        **report,
    }
    s = report["seconds"]
    log(
        f"  {dataset.name}: {report['vertices']} poses, {report['edges']} edges: wall {process.wall:.2f} s "
        f"(read {s['read']:.2f}, init {s['initialize']:.2f}, optimise {s['optimize']:.2f} in {report['iterations']} it, "
        f"write {s['write']:.2f}), peak {process.max_rss / 2**30:.2f} GB, nnz(L)≈{fill['amd']['nnz_L_scalar']:.3g} (AMD)"
    )
    return point


def log_log_slope(x, y) -> float | None:
    """Least-squares slope of log y against log x (the exponent of a power law)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = (x > 0) & (y > 0)
    if keep.sum() < 2:
        return None
    return float(np.polyfit(np.log(x[keep]), np.log(y[keep]), 1)[0])


def slopes(points: list[dict], top: int = 4) -> dict:
    """Power-law exponents vs edges over the ``top`` largest sizes of each shape, per quantity."""
    out = {}
    for shape in sorted({p["shape"] for p in points}):
        pts = sorted((p for p in points if p["shape"] == shape and "error" not in p), key=lambda p: p["edges"])[-top:]
        if len(pts) < 2:
            continue
        edges = [p["edges"] for p in pts]
        split = lambda key: [p["optimize_split"][key] for p in pts]  # noqa: E731
        per_iteration = lambda key: [p["optimize_split"][key] / max(1, p["iterations"]) for p in pts]  # noqa: E731
        out[shape] = {
            "edges": edges,
            "read": log_log_slope(edges, [p["seconds"]["read"] for p in pts]),
            "initialize": log_log_slope(edges, [p["seconds"]["initialize"] for p in pts]),
            "optimize": log_log_slope(edges, [p["seconds"]["optimize"] for p in pts]),
            "write": log_log_slope(edges, [p["seconds"]["write"] for p in pts]),
            "linearize+assemble per iteration": log_log_slope(
                edges, [a + b for a, b in zip(per_iteration("linearize"), per_iteration("assemble"))]
            ),
            "factorize per factorisation": log_log_slope(edges, [p["optimize_split"]["factorize"] / max(1, p["factorizations"]) for p in pts]),
            "nnz(L) AMD": log_log_slope(edges, [p["fill"]["amd"]["nnz_L"] for p in pts]),
            "flops AMD": log_log_slope(edges, [p["fill"]["amd"]["flops"] for p in pts]),
            "peak memory": log_log_slope(edges, [p["max_rss"] for p in pts]),
        }
        del split
    return out


def plot(points: list[dict], path: Path) -> None:
    """Four panels against edges (log-log): phase seconds, optimiser split per iteration, peak memory, fill-in."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shapes = sorted({p["shape"] for p in points})
    markers = dict(zip(("sphere", "slab", "cube"), ("o", "s", "^")))
    styles = dict(zip(("sphere", "slab", "cube"), ("-", "--", ":")))
    fig, axes = plt.subplots(2, 2, figsize=(13, 10))

    def series(shape, value):
        pts = sorted((p for p in points if p["shape"] == shape and "error" not in p), key=lambda p: p["edges"])
        return np.array([p["edges"] for p in pts], float), np.array([value(p) for p in pts], float)

    def reference(ax, x_all, y_anchor, label, exponent=1.0):
        if len(x_all) == 0:
            return
        x = np.array([min(x_all), max(x_all)])
        ax.plot(x, y_anchor * (x / x[0]) ** exponent, color="0.6", lw=1, ls="-.", label=label)

    colours = {"read": "C0", "initialize": "C1", "optimize": "C2", "write": "C3", "wall": "k"}
    ax = axes[0, 0]
    for shape in shapes:
        for key in ("read", "initialize", "optimize", "write"):
            x, y = series(shape, lambda p, k=key: p["seconds"][k])
            ax.plot(x, y, marker=markers[shape], ls=styles[shape], color=colours[key], label=f"{shape}: {key}")
        x, y = series(shape, lambda p: p["wall"])
        ax.plot(x, y, marker=markers[shape], ls=styles[shape], color="k", label=f"{shape}: whole process")
    all_x = [p["edges"] for p in points if "error" not in p]
    reference(ax, all_x, min((p["seconds"]["read"] for p in points if "error" not in p), default=1e-3), "∝ edges")
    ax.set(xscale="log", yscale="log", xlabel="edges", ylabel="seconds", title="Seconds per phase (one process per point)")
    ax.legend(fontsize=6, ncol=2)

    ax = axes[0, 1]
    for shape in shapes:
        x, lin = series(shape, lambda p: (p["optimize_split"]["linearize"] + p["optimize_split"]["assemble"]) / max(1, p["iterations"]))
        ax.plot(x, lin, marker=markers[shape], ls=styles[shape], color="C4", label=f"{shape}: linearise + assemble / iteration")
        x, fac = series(shape, lambda p: p["optimize_split"]["factorize"] / max(1, p["factorizations"]))
        ax.plot(x, fac, marker=markers[shape], ls=styles[shape], color="C5", label=f"{shape}: factorise / factorisation")
        x, setup = series(shape, lambda p: p["optimize_split"]["setup"])
        ax.plot(x, setup, marker=markers[shape], ls=styles[shape], color="C7", label=f"{shape}: symbolic setup (once)")
    firsts = [(p["optimize_split"]["linearize"] + p["optimize_split"]["assemble"]) / max(1, p["iterations"]) for p in points if "error" not in p]
    reference(ax, all_x, min(firsts, default=1e-3), "∝ edges")
    ax.set(xscale="log", yscale="log", xlabel="edges", ylabel="seconds", title="Inside the optimiser")
    ax.legend(fontsize=6)

    ax = axes[1, 0]
    for shape in shapes:
        for key in ("read", "initialize", "optimize", "write"):
            x, y = series(shape, lambda p, k=key: p["peak_bytes"][k] / 2**30)
            ax.plot(x, y, marker=markers[shape], ls=styles[shape], color=colours[key], label=f"{shape}: {key}")
    ax.axhline(MACHINE_MEMORY_GB, color="r", lw=1)
    ax.text(min(all_x, default=1), MACHINE_MEMORY_GB * 0.8, f"{MACHINE_MEMORY_GB} GB (this machine)", color="r", fontsize=8)
    ax.set(xscale="log", yscale="log", xlabel="edges", ylabel="peak resident memory during the phase (GiB)", title="Peak memory per phase")
    ax.legend(fontsize=6, ncol=2)

    ax = axes[1, 1]
    for shape in shapes:
        for ordering, colour in (("amd", "C8"), ("metis", "C9")):
            x, y = series(shape, lambda p, o=ordering: p["fill"][o]["nnz_L_scalar"] / (36 * p["fill"]["nnz_H"]))
            ax.plot(x, y, marker=markers[shape], ls=styles[shape], color=colour, label=f"{shape}: nnz(L)/nnz(H), {ordering.upper()}")
    ax.set(xscale="log", yscale="log", xlabel="edges", ylabel="fill-in factor nnz(L) / nnz(H)",
           title="Why: Cholesky fill-in (CHOLMOD analysis, vertex level)")
    ax.legend(fontsize=6)

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.scaling", description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", choices=sorted(DEFAULT_SIZES), default=["sphere", "slab", "cube"])
    parser.add_argument("--sizes", nargs="+", type=int, help="poses per point (default: per shape, up to 200,000)")
    parser.add_argument("--max-size", type=int, default=None, help="skip default sizes above this")
    parser.add_argument("--timeout", type=float, default=3600, help="seconds before one worker is killed")
    parser.add_argument("--out", default="docs", help="folder for scaling.json and scaling.png (default docs/)")
    parser.add_argument("--merge", action="store_true", help="keep points of scaling.json in --out not re-run now")
    parser.add_argument("--worker", metavar="IN.g2o", help=argparse.SUPPRESS)
    parser.add_argument("--report", help=argparse.SUPPRESS)
    parser.add_argument("--write", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        return worker(args.worker, args.report, args.write)

    from benchmarks.harness import machine_info

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    json_path = out / "scaling.json"
    previous = json.loads(json_path.read_text())["points"] if args.merge and json_path.is_file() else []
    points = []
    for shape in args.shapes:
        sizes = args.sizes or DEFAULT_SIZES[shape]
        for size in sizes:
            if args.max_size and size > args.max_size:
                continue
            print(f"{shape} {size}", flush=True)
            points.append(run_point(shape, size, args.timeout, log=lambda s: print(s, flush=True)))
    done = {(p["shape"], p["size"]) for p in points}
    points = sorted([p for p in previous if (p["shape"], p["size"]) not in done] + points, key=lambda p: (p["shape"], p["size"]))
    result = {"machine": machine_info(), "points": points, "slopes_vs_edges": slopes(points)}
    json_path.write_text(json.dumps(result, indent=1, default=str) + "\n")
    plot(points, out / "scaling.png")
    print(json.dumps(result["slopes_vs_edges"], indent=1))
    print(f"wrote {json_path} and {out / 'scaling.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
