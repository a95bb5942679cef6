"""Memory per pose of ``posegraph optimize`` on large 3D graphs, by phase and end to end.

    python -m benchmarks.bench_memory make sphere 200000 -o /tmp/big/s200k.g2o
    python -m benchmarks.bench_memory make route 1000000 -o /tmp/big/r1m.g2o [--loop-density 0.3]
    python -m benchmarks.bench_memory phases /tmp/big/s200k.g2o [--linear-solver pcg]  # RSS per phase, one process
    python -m benchmarks.bench_memory run /tmp/big/r1m.g2o [/tmp/big/s200k.g2o …] [--linear-solver pcg]  # whole processes
    python -m benchmarks.bench_memory pcg /tmp/big/s50k.g2o           # CG iterations: three preconditioners

``make``: a synthetic graph (:mod:`datasets.synthetic`, seed 0, default noise). ``sphere``: g2o's
create_sphere layout, 4 edges a pose, a closed surface whose Cholesky factor grows as n log n.
``route``: :func:`datasets.synthetic.garage` laid out as a city route — 20 floors (separate
districts joined by a ramp), 5 laps each of ``n / 100`` poses round a 2 km × 0.5 km block, each lap
tied to the one before by loop closures (``--loop-density`` of the candidates kept): a long
trajectory with local revisits, as a lidar map of many sessions, whose factor stays small.

``phases``: one process reads, initialises (chordal) and optimises, printing its resident memory
and the peak since the last mark (the kernel's high-water mark, reset through
``/proc/self/clear_refs``) after each phase and each iteration, and the largest numpy arrays
alive at the first iteration (tracemalloc; CHOLMOD's factor is the rest).

``pcg``: conjugate gradients instead of the factorisation, which is what fills memory on a sphere:
iterations and seconds to solve the first Gauss-Newton system at the chordal start to a relative
residual of 1e-4 and 1e-8 with a block-Jacobi preconditioner and with the multigrid cycle of
``--linear-solver pcg`` (:mod:`posegraph.linalg.multigrid`), its near-null space the global motions or
identity blocks.

``run``: ``python cli.py optimize IN -o OUT --report R.json -q [--linear-solver S]`` under ``/usr/bin/time -v``:
wall seconds, peak resident memory (GiB and bytes a pose), final cost, iterations. Figures are
recorded in ``docs/benchmarks.md`` ("Memory per pose").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ROUTE_FLOORS, ROUTE_LAPS = 20, 5
"""The route's districts and laps of each: ``n / 100`` poses a lap."""


def make(shape: str, size: int, output: Path, loop_density: float) -> None:
    """Write ``shape`` of about ``size`` poses to ``output`` (g2o)."""
    from datasets import synthetic
    from posegraph.io.g2o import write_g2o

    noise = synthetic.NoiseParams(loop_closure_density=loop_density)
    if shape == "sphere":
        dataset = synthetic.generate("sphere", size, noise=noise, seed=0)
    else:
        per_lap = max(4, size // (ROUTE_FLOORS * ROUTE_LAPS))
        dataset = synthetic.garage(floors=ROUTE_FLOORS, laps_per_floor=ROUTE_LAPS, nodes_per_lap=per_lap,
                                   length=2000.0, width=500.0, floor_height=10.0, noise=noise, seed=0)  # fmt: skip
    write_g2o(output, dataset.graph)
    graph = dataset.graph
    print(f"{output}: {graph.num_vertices} poses, {graph.num_edges} edges ({graph.num_edges / graph.num_vertices:.2f} a pose)")


def _memory() -> tuple[float, float]:
    """``(resident, peak since the last reset)`` of this process, MiB."""
    fields = dict(line.split(":", 1) for line in open("/proc/self/status") if ":" in line)
    return int(fields["VmRSS"].split()[0]) / 1024, int(fields["VmHWM"].split()[0]) / 1024


def _mark(what: str, poses: int | None = None) -> None:
    resident, peak = _memory()
    per_pose = f"  ({peak * 2**20 / poses / 1000:.1f} kB a pose)" if poses else ""
    print(f"{what:32s} resident {resident:9.0f} MiB   peak {peak:9.0f} MiB{per_pose}", flush=True)
    Path("/proc/self/clear_refs").write_text("5")


def phases(path: Path, linear_solver: str = "auto") -> None:
    """Resident memory after each phase of one optimisation, in this process (module docstring)."""
    import gc
    import tracemalloc

    _mark("start")
    from posegraph.init.chordal import chordal_initialization
    from posegraph.io.g2o import read_g2o
    from posegraph.solve import SolverParams, optimize

    _mark("imports")
    graph = read_g2o(path)
    n = graph.num_vertices
    _mark(f"read ({n} poses)", n)
    start = chordal_initialization(graph, linear_solver=linear_solver)
    gc.collect()
    _mark("chordal start", n)
    tracemalloc.start(2)

    def each_iteration(record) -> None:
        if record.iteration == 1:
            _largest_arrays(tracemalloc.take_snapshot())
        _mark(f"iteration {record.iteration}", n)

    optimize(graph, initial=start, params=SolverParams(callback=each_iteration, linear_solver=linear_solver))
    _mark("optimised", n)


def _largest_arrays(snapshot, count: int = 6) -> None:
    """The numpy allocations alive, largest first, by the line that made them."""
    total = sum(stat.size for stat in snapshot.statistics("filename"))
    print(f"    numpy and Python objects alive: {total / 2**20:.0f} MiB; largest:")
    for stat in snapshot.statistics("lineno")[:count]:
        frame = stat.traceback[0]
        print(f"    {stat.size / 2**20:8.0f} MiB  {Path(frame.filename).name}:{frame.lineno}")


def pcg(path: Path) -> None:
    """CG iterations and seconds on the first Gauss-Newton system, three preconditioners (module docstring)."""
    import numpy as np
    import scipy.sparse.linalg as sla

    from posegraph.linalg import multigrid
    from posegraph.init.chordal import chordal_initialization
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.linearize import linearize
    from posegraph.solve.sparsity import analyze_pattern, gradient_values, hessian_values, symmetric_block_values, symmetric_blocks

    graph = read_g2o(path)
    d = graph.group.dim
    held = np.arange(graph.num_vertices) == 0
    pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held, d)
    poses = chordal_initialization(graph)
    blocks = linearize(poses, graph)
    layout = symmetric_blocks(pattern)
    values = symmetric_block_values(pattern, layout, hessian_values(pattern, blocks.hessian_slice))
    hessian = _block_matrix(pattern, layout, values)
    rhs = -gradient_values(pattern, blocks.gradient)
    inverse = np.linalg.inv(values[layout.diagonal_blocks])
    jacobi = sla.LinearOperator(hessian.shape, matvec=lambda v: (inverse @ v.reshape(-1, d, 1)).ravel())
    for rtol in (1e-4, 1e-8):
        _count_cg(f"{path.name}: block Jacobi", hessian, rhs, rtol, jacobi)
        for name, null in (("global motions", multigrid.pose_null_space(graph.group, poses[~held])),
                           ("identity blocks", np.tile(np.eye(d), (pattern.num_variables, 1)))):  # fmt: skip
            begin = time.perf_counter()
            solver = multigrid.MultigridCG(rtol)
            solver.factorize(hessian, null)
            solver.solve(rhs)
            print(f"{path.name}: multigrid ({name}) to relative residual {rtol:g}: {solver.iterations[-1]} iterations, "
                  f"{time.perf_counter() - begin:.1f} s with its set-up", flush=True)


def _block_matrix(pattern, layout, values):
    import scipy.sparse as sp

    return sp.bsr_matrix((values, layout.indices, layout.indptr), shape=(pattern.dimension,) * 2)


def _count_cg(name: str, matrix, rhs, rtol: float, preconditioner) -> None:
    import scipy.sparse.linalg as sla

    count = [0]
    begin = time.perf_counter()
    _, info = sla.cg(matrix, rhs, rtol=rtol, maxiter=50_000, M=preconditioner,
                     callback=lambda _: count.__setitem__(0, count[0] + 1))  # fmt: skip
    print(f"{name} to relative residual {rtol:g}: {count[0]} iterations, {time.perf_counter() - begin:.1f} s"
          + ("" if info == 0 else f" (stopped: info {info})"), flush=True)


def run(paths: list[Path], linear_solver: str = "auto") -> list[dict]:
    """Whole ``optimize`` processes under ``/usr/bin/time -v``, one after another."""
    rows = []
    for path in paths:
        with tempfile.TemporaryDirectory() as folder:
            out, report = Path(folder) / "out.g2o", Path(folder) / "r.json"
            argv = ["/usr/bin/time", "-v", sys.executable, "cli.py", "optimize", str(path), "-o", str(out),
                    "--report", str(report), "-q", "--linear-solver", linear_solver]  # fmt: skip
            begin = time.perf_counter()
            done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
            wall = time.perf_counter() - begin
            if done.returncode != 0:
                print(f"{path}: exit {done.returncode}: {done.stderr.strip().splitlines()[-1:]}")
                continue
            peak_kib = int(next(line for line in done.stderr.splitlines() if "Maximum resident" in line).split()[-1])
            data = json.loads(report.read_text())
        rows.append(_row(path, data, wall, peak_kib))
        print(json.dumps(rows[-1]), flush=True)
    return rows


def _row(path: Path, report: dict, wall: float, peak_kib: int) -> dict:
    n = report["num_vertices"]
    return {
        "file": path.name, "poses": n, "edges": report["num_edges"], "wall_s": round(wall, 1),
        "peak_gib": round(peak_kib / 2**20, 2), "kb_per_pose": round(peak_kib * 1024 / n / 1000, 1),
        "final_cost": report["final_cost"], "iterations": report["iterations"],
        "phases_s": {k: round(v, 2) for k, v in report["seconds"].items() if k != "solver"},
    }  # fmt: skip


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_memory", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    maker = commands.add_parser("make", help="write a synthetic graph")
    maker.add_argument("shape", choices=("sphere", "route"))
    maker.add_argument("size", type=int)
    maker.add_argument("-o", "--output", type=Path, required=True)
    maker.add_argument("--loop-density", type=float, default=1.0, help="share of loop-closure candidates kept")
    phase = commands.add_parser("phases", help="memory per phase in one process")
    phase.add_argument("path", type=Path)
    commands.add_parser("pcg", help="PCG instead of the factorisation: iterations").add_argument("path", type=Path)
    whole = commands.add_parser("run", help="whole optimize processes")
    whole.add_argument("paths", type=Path, nargs="+")
    for command in (phase, whole):
        command.add_argument("--linear-solver", choices=("auto", "cholmod", "scipy", "pcg"), default="auto")
    args = parser.parse_args(argv)
    if args.command == "make":
        make(args.shape, args.size, args.output, args.loop_density)
    elif args.command == "phases":
        phases(args.path, args.linear_solver)
    elif args.command == "pcg":
        pcg(args.path)
    else:
        run(args.paths, args.linear_solver)
    return 0


if __name__ == "__main__":
    sys.exit(main())
