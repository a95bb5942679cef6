"""Scaling study: seconds and peak memory per phase against the number of edges.

    python -m benchmarks.scaling [--shapes sphere slab cube] [--sizes 1000 ... 200000] [--out docs/]

For every (shape, size) the parent process generates a synthetic graph (:mod:`datasets.synthetic`,
seed 0, default noise), writes it to a temporary g2o file and runs one *worker* process on it
(``python -m benchmarks.scaling --worker IN.g2o --report R.json``) that reads, initialises
(chordal), optimises (default parameters) and writes, timing each phase and its peak resident
memory: before a phase the worker resets the kernel's high-water mark (``/proc/self/clear_refs``
← 5) and after it reads ``VmHWM`` from ``/proc/self/status``. The optimiser's own split
(linearise, assemble, factorise, solve per iteration; symbolic setup once) comes from
:class:`posegraph.solve.OptimizeResult`. The parent adds the whole-process wall time; the
process's peak memory is the largest phase peak (resetting the high-water mark also resets the
``ru_maxrss`` the kernel reports at exit).

Fill-in: the solver does not expose CHOLMOD's factor, so the parent analyses the same sparsity at
the vertex level (one scalar per pose, an SPD matrix with the graph's adjacency) with CHOLMOD's
AMD, METIS and nested-dissection orderings (``used``: the one the solver's ``"auto"`` picks, AMD
below 10,000 poses, nested dissection above) and reports ``nnz(L)`` and the factorisation flops ``Σ_j c_j²`` of the
column counts ``c_j``. Each 6×6 block of the real system multiplies them by 36 (nnz) and 216
(flops); each 3×3 block of a 2D graph by 9 and 27. That is what grows faster than linearly: roughly ``n log n`` for a sphere or a
few-layer slab (planar-like graphs, separators ~ √n) and ``n^{4/3}`` nnz / ``n²`` flops for a
full 3D lattice (separators ~ n^{2/3}).

Shapes: ``manhattan`` (2D, SE(2): a walk on a street lattice like M3500, up to 10⁶ poses),
``sphere`` (rings × nodes, as g2o's create_sphere), ``slab`` (a 3D grid 4 layers high:
a multi-storey building) and ``cube`` (a full 3D grid, the worst case for fill-in: at 200,000 poses
its factor alone would need ~30 GB, so it stops at 27,000 by default). An 8-layer slab of 200,000
poses already needs ~13 GB for the factor and ~10¹³ flops per factorisation (AMD).

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

SLAB_LAYERS = 4
DEFAULT_SIZES = {
    "sphere": (1000, 2000, 5000, 10000, 20000, 50000, 100000, 200000),
    "slab": (1000, 2000, 5000, 10000, 20000, 50000, 100000, 200000),
    "cube": (1000, 3375, 8000, 15625, 27000),
    "manhattan": (1000, 3000, 10000, 30000, 100000, 300000, 1000000),
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


def worker(source: str, report_path: str, output: str, ordering: str = "auto") -> int:
    """Read, initialise, optimise and write ``source``; time and measure each phase; write a JSON report."""
    started = time.perf_counter()
    from posegraph.init import initialize
    from posegraph.io.g2o import read_g2o, write_g2o
    from posegraph.solve import SolverParams, optimize

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
    result = phase("optimize", lambda: optimize(graph, initial=start, params=SolverParams(ordering=ordering)))
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
        "ordering": ordering,
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
    from datasets.synthetic import generate

    if shape == "sphere":
        return generate("sphere", size, seed=seed)
    if shape == "cube":
        return generate("grid", size, seed=seed)
    if shape == "slab":
        side = max(2, round((size / SLAB_LAYERS) ** 0.5))
        return generate("grid", None, seed=seed, nx=side, ny=side, nz=SLAB_LAYERS)
    if shape == "manhattan":
        return generate("manhattan", size, seed=seed)
    raise ValueError(f"unknown scaling shape {shape!r}")


def fill_in(graph) -> dict:
    """Vertex-level CHOLMOD factorisation of the graph's normal-equation sparsity under AMD, METIS and nested dissection.

    Returns per ordering ``nnz_L`` (vertex level), ``flops`` (``Σ c_j²``), and the scalar
    estimates ``nnz_L_scalar`` = d²·``nnz_L`` and ``flops_scalar`` = d³·``flops`` (d = 6 for SE(3),
    3 for SE(2): the block size); plus
    ``nnz_H`` (lower triangle, vertex level) of the matrix itself. ``"metis"`` and ``"nesdis"``
    are both METIS nested dissection (pymetis) in :mod:`posegraph.linalg.cholmod`.
    """
    from posegraph.linalg import cholmod

    n = graph.num_vertices
    i, j = graph.edge_from, graph.edge_to
    rows, cols = np.maximum(i, j), np.minimum(i, j)
    keys = np.unique(np.concatenate([np.arange(n) * (n + 1), cols * n + rows]))  # lower triangle, diagonal included
    cols, rows = keys // n, keys % n
    indptr = np.concatenate([[0], np.cumsum(np.bincount(cols, minlength=n))])
    # strictly diagonally dominant on the pattern: SPD, only the pattern matters
    degree = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
    values = np.where(rows == cols, degree[cols] + 1.0, -0.1)
    out = {"nnz_H": int(keys.size), "used": cholmod.auto_ordering(n)}
    d = graph.group.dim
    for ordering in ("amd", "metis", "nesdis"):
        factor = cholmod.SparseCholesky(indptr, rows, n, ordering)
        factor.factorize(values)
        counts = np.diff(factor.factor()[0]).astype(np.float64)
        out[ordering] = {
            "nnz_L": int(counts.sum()),
            "flops": float(np.sum(counts**2)),
            "nnz_L_scalar": int(d * d * counts.sum()),
            "flops_scalar": float(d**3 * np.sum(counts**2)),
        }
    return out


def run_point(shape: str, size: int, timeout: float, log=print, ordering: str = "auto") -> dict:
    """Generate one graph, analyse its fill-in, and measure one worker process on it."""
    from benchmarks.harness import ROOT, git_state, run_process
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
        command = [sys.executable, "-m", "benchmarks.scaling", "--worker", str(source), "--report", str(report_path), "--write", str(output), "--ordering", ordering]
        process = run_process(command, timeout=timeout, cwd=ROOT)
        if process.returncode != 0 or not report_path.is_file():
            tail = process.stderr.strip().splitlines()[-1:] or [f"exit {process.returncode}"]
            log(f"  {dataset.name}: worker failed: {tail[0]}")
            return {"shape": shape, "size": size, "ordering": ordering, "name": dataset.name, "error": tail[0], "wall": process.wall}
        report = json.loads(report_path.read_text())
    point = {
        "shape": shape,
        "size": size,
        "name": dataset.name,
        "file_bytes": file_bytes,
        "seconds_generate": seconds_generate,
        "git": git_state(),
        "wall": process.wall,
        # Resetting VmHWM also resets what the kernel reports as ru_maxrss at exit: the process's
        # peak is the largest of the phases' peaks (ru_maxrss is the last phase's, or more).
        "max_rss": max([process.max_rss, *report["peak_bytes"].values()]),
        "cpu": process.cpu,
        "fill": fill,
        **report,
    }
    s = report["seconds"]
    log(
        f"  {dataset.name}: {report['vertices']} poses, {report['edges']} edges: wall {process.wall:.2f} s "
        f"(read {s['read']:.2f}, init {s['initialize']:.2f}, optimise {s['optimize']:.2f} in {report['iterations']} it, "
        f"write {s['write']:.2f}), peak {point['max_rss'] / 2**30:.2f} GB, nnz(L)≈{fill[fill['used']]['nnz_L_scalar']:.3g} ({fill['used']})"
    )
    return point


def log_log_slope(x, y) -> float | None:
    """Least-squares slope of log y against log x (the exponent of a power law)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = (x > 0) & (y > 0)
    if keep.sum() < 2:
        return None
    return float(np.polyfit(np.log(x[keep]), np.log(y[keep]), 1)[0])


def slopes(points: list[dict], top: int = 3) -> dict:
    """Power-law exponents vs edges over the ``top`` largest sizes of each shape, per quantity."""
    out = {}
    for shape in sorted({series_key(p) for p in points}):
        pts = sorted((p for p in points if series_key(p) == shape and "error" not in p), key=lambda p: p["edges"])[-top:]
        if len(pts) < 2:
            continue
        edges = [p["edges"] for p in pts]
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
            "nnz(L) nested dissection": log_log_slope(edges, [p["fill"]["nesdis"]["nnz_L"] for p in pts]),
            "flops AMD": log_log_slope(edges, [p["fill"]["amd"]["flops"] for p in pts]),
            "flops nested dissection": log_log_slope(edges, [p["fill"]["nesdis"]["flops"] for p in pts]),
            "peak memory": log_log_slope(edges, [p["max_rss"] for p in pts]),
        }
    return out


def series_key(point: dict) -> str:
    """The plotted series of a point: its shape, plus the ordering when not the default."""
    ordering = point.get("ordering", "auto")
    return point["shape"] if ordering == "auto" else f"{point['shape']} ({ordering})"


def plot(points: list[dict], path: Path) -> None:
    """Four panels against edges (log-log): phase seconds, inside the optimiser, peak memory, fill-in.

    Colour is the quantity, marker and line style the series (shape, and ordering if not the default).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    good = [p for p in points if "error" not in p]
    keys = sorted({series_key(p) for p in good})
    looks = dict(zip(keys, [("o", "-"), ("s", "--"), ("^", ":"), ("D", "-."), ("v", (0, (1, 3))), ("P", (0, (5, 1)))]))
    fig, axes = plt.subplots(2, 2, figsize=(13, 10))
    for ax, panel in zip(axes.flat, _panels(good)):
        _draw_panel(ax, good, keys, looks, *panel)
    ax = axes[1, 0]
    ax.axhline(MACHINE_MEMORY_GB, color="r", lw=1)
    ax.text(min((p["edges"] for p in good), default=1), MACHINE_MEMORY_GB * 0.75, f"{MACHINE_MEMORY_GB} GB: this machine", color="r", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _per_iteration(p: dict, *keys) -> float:
    return sum(p["optimize_split"][k] for k in keys) / max(1, p["iterations"])


def _panels(good: list[dict]) -> list[tuple]:
    """``(quantities, title, ylabel, reference, legend place)`` of the four panels, row by row;
    ``quantities``: ``(label, colour, value of a point)``; ``reference``: a line ∝ edges from there."""
    phases = [
        ("read", "C0", lambda p: p["seconds"]["read"]),
        ("initialise (chordal)", "C1", lambda p: p["seconds"]["initialize"]),
        ("optimise", "C2", lambda p: p["seconds"]["optimize"]),
        ("write", "C3", lambda p: p["seconds"]["write"]),
        ("whole process", "k", lambda p: p["wall"]),
    ]
    inside = [
        ("linearise + assemble, per iteration", "C4", lambda p: _per_iteration(p, "linearize", "assemble")),
        ("factorise, per factorisation", "C5", lambda p: p["optimize_split"]["factorize"] / max(1, p["factorizations"])),
        ("triangular solves + cost, per iteration", "C6", lambda p: _per_iteration(p, "solve")),
        ("symbolic setup (once)", "C7", lambda p: p["optimize_split"]["setup"]),
    ]
    memory = [
        ("read", "C0", lambda p: p["peak_bytes"]["read"] / 2**30),
        ("initialise", "C1", lambda p: p["peak_bytes"]["initialize"] / 2**30),
        ("optimise", "C2", lambda p: p["peak_bytes"]["optimize"] / 2**30),
        ("write", "C3", lambda p: p["peak_bytes"]["write"] / 2**30),
    ]
    fill = [
        ("nnz(L) / nnz(H), AMD", "C8", lambda p: p["fill"]["amd"]["nnz_L"] / p["fill"]["nnz_H"]),
        ("nnz(L) / nnz(H), METIS", "C9", lambda p: p["fill"]["metis"]["nnz_L"] / p["fill"]["nnz_H"]),
        ("nnz(L) / nnz(H), nested dissection", "C7", lambda p: p["fill"]["nesdis"]["nnz_L"] / p["fill"]["nnz_H"]),
        ("flops / (1000·edges), AMD", "C1", lambda p: p["fill"]["amd"]["flops_scalar"] / (1000 * p["edges"])),
        ("flops / (1000·edges), nested dissection", "C4", lambda p: p["fill"]["nesdis"]["flops_scalar"] / (1000 * p["edges"])),
    ]
    smallest_read = min((p["seconds"]["read"] for p in good), default=1e-3)
    smallest_lin = min((_per_iteration(p, "linearize", "assemble") for p in good), default=1e-3)
    return [
        (phases, "Seconds per phase (one process per point)", "seconds", smallest_read, "upper left"),
        (inside, "Inside the optimiser", "seconds", smallest_lin, "upper left"),
        (memory, "Peak resident memory during each phase", "GiB", None, "lower right"),
        (fill, "Why: fill-in of the Cholesky factor (CHOLMOD analysis)", "ratio", None, "upper left"),
    ]


def _draw_panel(ax, good: list[dict], keys: list, looks: dict, quantities, title, ylabel, reference, loc) -> None:
    """One panel: each quantity of each series against edges, log-log, with its legend."""
    from matplotlib.lines import Line2D

    for key in keys:
        marker, style = looks[key]
        pts = sorted((p for p in good if series_key(p) == key), key=lambda p: p["edges"])
        x = np.array([p["edges"] for p in pts], float)
        for label, colour, value in quantities:
            if len(x):
                ax.plot(x, np.array([value(p) for p in pts], float), marker=marker, ls=style, color=colour, ms=4)
    handles = [Line2D([], [], color=c, lw=2, label=label) for label, c, _ in quantities]
    if reference is not None:
        x = np.array([min(p["edges"] for p in good), max(p["edges"] for p in good)])
        ax.plot(x, reference * x / x[0], color="0.6", lw=1, ls="-.")
        handles.append(Line2D([], [], color="0.6", lw=1, ls="-.", label="∝ edges"))
    handles += [Line2D([], [], color="k", marker=looks[k][0], ls=looks[k][1], label=k) for k in keys]
    ax.legend(handles=handles, fontsize=7, loc=loc)
    ax.set(xscale="log", yscale="log", xlabel="edges", ylabel=ylabel, title=title)
    ax.grid(True, which="major", alpha=0.3)


def markdown_table(points: list[dict]) -> str:
    """The points as a Markdown table (seconds, memory, fill-in), for docs/benchmarks.md."""
    lines = [
        "| series | poses | edges | iterations | read s | initialise s | optimise s | of which: setup / linearise+assemble per it. / factorise per fact. | write s | whole process s | peak GiB: read / initialise / optimise / write | nnz(L) AMD / METIS / nested dissection (×10⁶, est.) | flops per factorisation, ordering used (est.) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in sorted(points, key=lambda p: (series_key(p), p["edges"] if "edges" in p else 0)):
        if "error" in p:
            lines.append(f"| {series_key(p)} | {p['size']} | | failed: {p['error'][:80]} |" + " |" * 9)
            continue
        split, sec, it = p["optimize_split"], p["seconds"], max(1, p["iterations"])
        peaks = " / ".join(f"{p['peak_bytes'][k] / 2**30:.2f}" for k in ("read", "initialize", "optimize", "write"))
        lines.append(
            f"| {series_key(p)} | {p['vertices']} | {p['edges']} | {p['iterations']} | {sec['read']:.2f} | {sec['initialize']:.2f} | "
            f"{sec['optimize']:.2f} | {split['setup']:.2f} / {(split['linearize'] + split['assemble']) / it:.2f} / "
            f"{split['factorize'] / max(1, p['factorizations']):.2f} | {sec['write']:.2f} | {p['wall']:.1f} | "
            f"{peaks} | "
            f"{p['fill']['amd']['nnz_L_scalar'] / 1e6:.0f} / {p['fill']['metis']['nnz_L_scalar'] / 1e6:.0f} / "
            f"{p['fill']['nesdis']['nnz_L_scalar'] / 1e6:.0f} | "
            f"{p['fill'][p['fill']['used']]['flops_scalar']:.2g} ({p['fill']['used']}) |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.scaling", description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", choices=sorted(DEFAULT_SIZES), default=["sphere", "slab", "cube"])
    parser.add_argument("--sizes", nargs="+", type=int, help="poses per point (default: per shape, up to 200,000)")
    parser.add_argument("--max-size", type=int, default=None, help="skip default sizes above this")
    parser.add_argument("--timeout", type=float, default=3600, help="seconds before one worker is killed")
    parser.add_argument("--out", default="docs", help="folder for scaling.json and scaling.png (default docs/)")
    parser.add_argument("--merge", action="store_true", help="keep points of scaling.json in --out not re-run now")
    parser.add_argument("--replot", action="store_true", help="only redraw scaling.png (and the table) from scaling.json in --out")
    parser.add_argument("--ordering", default="auto", help="the solver's fill-reducing ordering (SolverParams.ordering; default auto)")
    parser.add_argument("--worker", metavar="IN.g2o", help=argparse.SUPPRESS)
    parser.add_argument("--report", help=argparse.SUPPRESS)
    parser.add_argument("--write", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        return worker(args.worker, args.report, args.write, args.ordering)

    from benchmarks.harness import machine_info

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    json_path = out / "scaling.json"
    previous = json.loads(json_path.read_text())["points"] if (args.merge or args.replot) and json_path.is_file() else []
    if args.replot and not previous:
        parser.error(f"--replot: no points in {json_path}")
    points = []
    for shape in [] if args.replot else args.shapes:
        sizes = args.sizes or DEFAULT_SIZES[shape]
        for size in sizes:
            if args.max_size and size > args.max_size:
                continue
            print(f"{shape} {size}", flush=True)
            points.append(run_point(shape, size, args.timeout, log=lambda s: print(s, flush=True), ordering=args.ordering))
    done = {(series_key(p), p["size"]) for p in points}
    points = sorted([p for p in previous if (series_key(p), p["size"]) not in done] + points, key=lambda p: (series_key(p), p["size"]))
    for p in points:  # points saved before the process peak was taken from the phases
        if "peak_bytes" in p:
            p["max_rss"] = max([p["max_rss"], *p["peak_bytes"].values()])
    machine = json.loads(json_path.read_text()).get("machine") if args.replot else machine_info()
    result = {"machine": machine, "points": points, "slopes_vs_edges": slopes(points)}
    json_path.write_text(json.dumps(result, indent=1, default=str) + "\n")
    plot(points, out / "scaling.png")
    print(markdown_table(points))
    print(json.dumps(result["slopes_vs_edges"], indent=1))
    print(f"wrote {json_path} and {out / 'scaling.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
