"""``posegraph optimize --robust gnc`` against gtsam's ``GncLMOptimizer`` on graphs with injected outliers.

    python -m benchmarks.bench_robust                                   # ours on all 12 cases, gtsam on sphere2500 + 20 %
    python -m benchmarks.bench_robust --gtsam all --gtsam-cap 400       # gtsam on every case, 400 s each at most
    python -m benchmarks.bench_robust --gtsam none --data /tmp/robust   # ours only, files kept in /tmp/robust
    python -m benchmarks.bench_robust --kind wrong-first --fractions 10,20,50 --gtsam smallGrid3D_20   # wrong edges on consecutive pairs

Cases: sphere2500, parking-garage and torus3D (shared datasets; smallGrid3D besides, where gtsam finishes) with 10, 20, 50 and 80 % random
outliers per real loop closure (``python -m datasets.synthetic inject … --seed 1``; indices in
``NAME.outliers.txt``). Ours: the whole process ``cli.py optimize IN -o OUT --robust gnc --report R
-q`` (interpreter start, read, robust start, TLS rounds, write), wall clock. gtsam: the whole
process ``benchmarks/gtsam_gnc.py`` (``readG2o``, prior on the first pose, ``InitializePose3``
chordal start, ``GncLMOptimizer`` with TLS and its defaults, known inliers = odometry), stopped at
``--gtsam-cap`` seconds. The gtsam runs go one at a time (the machine has 2 cores).

Columns: precision and recall of the outlier set (edges with final weight < 0.5 against the
injected ones), the cost on the *clean* graph at the result relative to the clean optimum
(``optimize(clean)``), ATE (translation RMS after rigid alignment) against the clean optimum,
seconds, and gtsam's seconds over ours. Figures are recorded in ``docs/robust.md``. Graphs without
wrong edges (what robust mode must leave alone): :mod:`benchmarks.bench_robust_clean`.

``--kind``: ``random`` (the outliers join free vertex pairs), ``parallel`` (besides, :data:`PARALLEL_SHARE`
of them each lie parallel to random odometry edges and to random loop closures, after the edge
they duplicate in file order) or ``wrong-first`` (the same, each before the edge it duplicates: the
wrong edge is then the first between its two consecutive vertices).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "datasets"
GRAPHS = ("sphere2500", "parking-garage", "torus3D", "smallGrid3D")
"""The issue's three graphs, and smallGrid3D, small enough for gtsam to finish every case."""
FRACTIONS = (10, 20, 50, 80)
HEADLINE = "sphere2500_20"


KINDS = {"random": "", "parallel": "p", "wrong-first": "w"}
"""``--kind`` values and the suffix of their case names (``sphere2500_20w``)."""
PARALLEL_SHARE = 0.02
"""Share of a ``parallel`` / ``wrong-first`` case's outliers parallel to odometry edges, and again to loop closures."""


def _case_file(data: Path, graph: str, percent: int, kind: str = "random") -> Path:
    """``data/GRAPH_PERCENT[p|w].g2o`` (and its ``.outliers.txt``), made with seed 1 when absent."""
    path = data / f"{graph}_{percent}{KINDS[kind]}.g2o"
    if not path.exists():
        argv = [sys.executable, "-m", "datasets.synthetic", "inject", str(SHARED / f"{graph}.g2o"),
                "--fraction", str(percent / 100), "--seed", "1", "-o", str(path)]  # fmt: skip
        if kind != "random":
            from posegraph.io.g2o import read_g2o

            loops = int(np.count_nonzero(~read_g2o(SHARED / f"{graph}.g2o").odometry_mask()))
            each = max(1, round(PARALLEL_SHARE * round(percent / 100 * loops)))
            argv += ["--on-odometry", str(each), "--on-loop-closures", str(each)] + (["--wrong-first"] if kind == "wrong-first" else [])
        subprocess.run(argv, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return path


def _timed(argv, cap: float | None) -> float | None:
    """Wall seconds of the process ``argv``, None when it ran past ``cap`` or failed."""
    start = time.perf_counter()
    try:
        done = subprocess.run(argv, cwd=ROOT, capture_output=True, timeout=cap)
    except subprocess.TimeoutExpired:
        return None
    return time.perf_counter() - start if done.returncode in (0, 1) else None


def run_ours(path: Path, out: Path):
    """``(seconds, outlier indices, poses)`` of ``--robust gnc`` on ``path``."""
    from posegraph.io.g2o import read_g2o

    report = out.with_suffix(".json")
    seconds = _timed([sys.executable, "cli.py", "optimize", str(path), "-o", str(out), "--robust", "gnc",
                      "--report", str(report), "-q"], None)  # fmt: skip
    return seconds, np.array(json.loads(report.read_text())["outlier_edges"], dtype=np.int64), read_g2o(out).poses


def run_gtsam(path: Path, out: Path, cap: float, reuse: bool):
    """``(seconds, outlier indices, poses in id order)`` of gtsam's GNC, or ``(None, cap, None)``
    when it ran past ``cap`` (recorded in ``out.timeout``). Seconds: the process's own, from its
    first line (imports included) to its report. ``reuse``: a report or timeout record already
    in the folder stands for the run."""
    report, poses, timeout = out.with_suffix(".json"), out.with_suffix(".npy"), out.with_suffix(".timeout")
    if not (reuse and (report.exists() or timeout.exists())):
        report.unlink(missing_ok=True)
        timeout.unlink(missing_ok=True)
        argv = [sys.executable, "benchmarks/gtsam_gnc.py", str(path), "--report", str(report), "--poses", str(poses)]
        if _timed(argv, cap) is None:
            timeout.write_text(f"{cap:g}\n")
    if not report.exists():
        return None, float(timeout.read_text()), None
    data = json.loads(report.read_text())
    return data["seconds"]["total"], np.array(data["outlier_edges"], dtype=np.int64), np.load(poses)


def _metrics(found, truth, poses, clean, reference, optimum) -> dict:
    from posegraph.analysis.evaluate import absolute_trajectory_error
    from posegraph.solve.residuals import cost

    hits = len(np.intersect1d(found, truth))
    translation, _, _ = absolute_trajectory_error(poses, reference)
    return {
        "precision": hits / max(len(found), 1),
        "recall": hits / max(len(truth), 1),
        "clean_cost_rel": (cost(clean, poses) - optimum) / optimum,
        "ate": float(np.sqrt(np.mean(translation**2))),
    }


def _cells(m: dict, seconds) -> str:
    return f"{m['precision']:.4f} | {m['recall']:.4f} | {m['clean_cost_rel']:.1e} | {m['ate']:.2g} | {seconds:.1f}"


def _gtsam_cells(outcome, seconds: float, order, args) -> tuple[str, str]:
    """The gtsam columns and the time ratio from :func:`run_gtsam`'s ``outcome``."""
    gtsam_seconds, found, poses = outcome
    if gtsam_seconds is None:  # found is the cap
        return f"— | — | — | — | not finished within {found:.0f}", f"> {found / seconds:.0f}"
    unsorted = np.empty_like(poses)
    unsorted[order] = poses  # gtsam's poses come by ascending key
    ratio = gtsam_seconds / seconds
    return _cells(_metrics(found, args[0], unsorted, *args[1:]), gtsam_seconds), f"{ratio:.0f}" if ratio >= 10 else f"{ratio:.1f}"


def run(data: Path, gtsam_cases: set, cap: float, reuse: bool, log=print, kind="random", fractions=FRACTIONS) -> None:
    from posegraph.io.g2o import read_g2o
    from posegraph.solve import optimize

    log("| case | outliers | ours: precision | recall | clean cost − opt (rel.) | ATE (m) | s "
        "| gtsam: precision | recall | clean cost − opt (rel.) | ATE (m) | s | gtsam / ours |")
    log("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in GRAPHS:
        clean = read_g2o(SHARED / f"{name}.g2o")
        reference = optimize(clean)
        order = np.argsort(clean.ids)
        for percent in fractions:
            case, path = f"{name}_{percent}{KINDS[kind]}", _case_file(data, name, percent, kind)
            truth = np.loadtxt(path.with_suffix(".outliers.txt"), dtype=np.int64)
            args = (truth, clean, reference.poses, reference.final_cost)
            seconds, found, poses = run_ours(path, data / f"ours_{case}.g2o")
            ours = _metrics(found, truth, poses, *args[1:])
            cell, ratio = "not run | | | |", "—"
            if case in gtsam_cases:
                cell, ratio = _gtsam_cells(run_gtsam(path, data / f"gtsam_{case}", cap, reuse), seconds, order, args)
            log(f"| {case} | {len(truth)} | {_cells(ours, seconds)} | {cell} | {ratio} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_robust", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("/tmp/posegraph_bench_robust"),
                        help="folder for the injected files and the outputs (default /tmp/posegraph_bench_robust)")
    parser.add_argument("--gtsam", default=HEADLINE,
                        help=f"comma-separated cases for gtsam (e.g. sphere2500_20), 'all' or 'none' (default {HEADLINE})")
    parser.add_argument("--gtsam-cap", type=float, default=400.0, help="seconds before a gtsam run is stopped (default 400)")
    parser.add_argument("--reuse-gtsam", action="store_true",
                        help="use gtsam reports already in --data (gtsam_CASE.json/.npy) instead of running gtsam again")
    parser.add_argument("--kind", choices=tuple(KINDS), default="random",
                        help="where the outliers lie (module docstring; default random)")
    parser.add_argument("--fractions", default=",".join(map(str, FRACTIONS)),
                        help=f"comma-separated outlier percentages (default {','.join(map(str, FRACTIONS))})")
    args = parser.parse_args(argv)
    args.data.mkdir(parents=True, exist_ok=True)
    fractions = tuple(int(p) for p in args.fractions.split(","))
    every = {f"{g}_{p}{KINDS[args.kind]}" for g in GRAPHS for p in fractions}
    cases = every if args.gtsam == "all" else set() if args.gtsam == "none" else set(args.gtsam.split(","))
    run(args.data, cases, args.gtsam_cap, args.reuse_gtsam, kind=args.kind, fractions=fractions)
    return 0


if __name__ == "__main__":
    sys.exit(main())
