"""When should ``--robust gnc`` analyse the sparsity anew? ``reanalyse_fraction`` side by side.

    python -m benchmarks.bench_reanalyse                                  # 0, 0.95, 1 on the three graphs + 20 %
    python -m benchmarks.bench_reanalyse --fractions 0,0.9,1 --rounds 3 --data /tmp/reanalyse

Variants (:class:`posegraph.robust.active.ActiveEdgeSolves`): ``0`` analyses each system once
(again only if an edge outside the analysed set comes back), ``1`` re-analyses whenever the set
of edges with nonzero weight changes, values between re-analyse when that set falls below the
fraction of the analysed one. Per graph (``GRAPH + 20 %``, ``python -m datasets.synthetic
inject … --seed 1``, :func:`benchmarks.bench_robust._case_file`): the whole process ``cli.py
optimize IN -o OUT --robust gnc --report R -q --reanalyse-fraction F`` under ``/usr/bin/time``,
wall and CPU (user + sys) seconds, the variants alternating within each of ``--rounds`` rounds,
medians; precision, recall and clean-graph cost from :func:`benchmarks.bench_robust._metrics`;
the number of symbolic analyses from the same run in process (``optimize_robust``, which the CLI
calls); and whether the outlier set and the clean cost agree with the first variant's.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.bench_robust import ROOT, SHARED, _case_file, _metrics

GRAPHS = ("sphere2500", "parking-garage", "torus3D")
PERCENT = 20


def timed_cli(path: Path, out: Path, fraction: float) -> tuple[float, float, np.ndarray]:
    """``(wall s, CPU s, outlier indices)`` of one ``--robust gnc`` process (``/usr/bin/time``)."""
    report = out.with_suffix(".json")
    argv = ["/usr/bin/time", "-f", "%e %U %S", sys.executable, "cli.py", "optimize", str(path), "-o", str(out),
            "--robust", "gnc", "--report", str(report), "-q", "--reanalyse-fraction", str(fraction)]  # fmt: skip
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, check=True)
    wall, user, system = (float(x) for x in done.stderr.strip().splitlines()[-1].split())
    return wall, user + system, np.array(json.loads(report.read_text())["outlier_edges"], dtype=np.int64)


def analyses(path: Path, fraction: float) -> int:
    """Symbolic analyses of ``optimize_robust`` on ``path`` at ``fraction``."""
    from posegraph.io.g2o import read_g2o
    from posegraph.robust.pipeline import optimize_robust

    return optimize_robust(read_g2o(path), reanalyse_fraction=fraction).analyses


def run(data: Path, fractions: list, rounds: int, log=print) -> None:
    from posegraph.io.g2o import read_g2o
    from posegraph.solve import optimize

    log("| graph + 20 % | reanalyse_fraction | analyses | wall s (median) | CPU s (median) | precision | recall "
        "| clean cost − opt (rel.) | outliers as first | clean cost vs first (rel.) |")
    log("|---|---|---|---|---|---|---|---|---|---|")
    for name in GRAPHS:
        path = _case_file(data, name, PERCENT)
        clean = read_g2o(SHARED / f"{name}.g2o")
        reference = optimize(clean)
        truth = np.loadtxt(path.with_suffix(".outliers.txt"), dtype=np.int64)
        times = {f: [] for f in fractions}
        found = {}
        for _ in range(rounds):
            for f in fractions:  # alternating: the machine's load hits every variant alike
                wall, cpu, found[f] = timed_cli(path, data / f"out_{name}_{f}.g2o", f)
                times[f].append((wall, cpu))
        first = None
        for f in fractions:
            poses = read_g2o(data / f"out_{name}_{f}.g2o").poses
            m = _metrics(found[f], truth, poses, clean, reference.poses, reference.final_cost)
            first = (found[f], m["clean_cost_rel"]) if first is None else first
            same = np.array_equal(found[f], first[0])
            drift = abs(m["clean_cost_rel"] - first[1]) / (1 + first[1])  # relative to the first variant's clean cost
            wall, cpu = np.median(np.array(times[f]), axis=0)
            log(f"| {name} | {f:g} | {analyses(path, f)} | {wall:.2f} | {cpu:.2f} | {m['precision']:.4f} "
                f"| {m['recall']:.4f} | {m['clean_cost_rel']:.1e} | {'yes' if same else 'NO'} | {drift:.1e} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_reanalyse", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("/tmp/posegraph_bench_reanalyse"),
                        help="folder for the injected files and the outputs (default /tmp/posegraph_bench_reanalyse)")
    parser.add_argument("--fractions", default="0,0.95,1", help="comma-separated reanalyse_fraction values (default 0,0.95,1)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of alternating runs (default 3)")
    args = parser.parse_args(argv)
    args.data.mkdir(parents=True, exist_ok=True)
    run(args.data, [float(f) for f in args.fractions.split(",")], args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
