"""The solver's heuristics, measured: cost, iterations, factorisations and seconds per dataset.

    python benchmarks/solver_heuristics.py                       # every shared 3D file, all variants
    python benchmarks/solver_heuristics.py --datasets sphere2500 --variants default no_chord
    PYTHONPATH=/work/main python benchmarks/solver_heuristics.py --json before.json   # another tree
    python benchmarks/solver_heuristics.py --compare before.json after.json          # side by side
    python benchmarks/solver_heuristics.py --against /work/main --rounds 3            # alternating, one table

Every run starts from the chordal initialisation (computed once per dataset, outside the timing) and
uses the default parameters except for the variant's changes. Factorisations are counted by wrapping
the linear solver's ``factorize`` (not read from the records), so the count is the same whatever
code the records come from. Seconds are ``optimize()``'s wall clock, the best of ``--repeat`` runs, and the process CPU
seconds of that run (steadier than wall clock on a loaded machine: the solver runs on one thread).
The code measured is the ``posegraph`` first on ``sys.path`` (``PYTHONPATH``), so the same script
measures the tree before and after a change.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import sys
import time
from pathlib import Path

DATASETS = Path(__file__).resolve().parent.parent.parent / "shared" / "datasets"
FILES = ["sphere2500", "torus3D", "parking-garage", "smallGrid3D", "tinyGrid3D", "cubicle", "sphere_bignoise_vertex3"]
REPAIR = {"cubicle"}  # its information matrices are not all positive definite as written
VARIANTS = {
    "default": {},
    "no_chord": {"reuse_factorization": False},  # chord steps and the decrement stop off
    "no_decrement_stop": {"decrement_stop": False},  # chord steps on, decrement stop off
    "no_line_search": {"line_search": False},
}


def count_factorizations():
    """Wrap ``make_linear_solver`` wherever the solver package imported it; returns the counter."""
    import posegraph.solve as solve

    counter = {"factorize": 0}
    for info in pkgutil.iter_modules(solve.__path__):
        module = importlib.import_module(f"posegraph.solve.{info.name}")
        original = getattr(module, "make_linear_solver", None)
        if original is None or getattr(original, "_counted", False):
            continue

        def counted(*args, _original=original, **kwargs):
            solver = _original(*args, **kwargs)
            factorize = solver.factorize

            def factorize_counted(data):
                counter["factorize"] += 1
                return factorize(data)

            solver.factorize = factorize_counted
            return solver

        counted._counted = True
        setattr(module, "make_linear_solver", counted)
    return counter


def run(names, variants, repeat):
    import posegraph
    from posegraph.init import initialize
    from posegraph.io.g2o import read_g2o
    from posegraph.solve import SolverParams, optimize

    known = set(SolverParams.__dataclass_fields__)
    counter = count_factorizations()
    rows = []
    print(f"# posegraph from {Path(posegraph.__file__).parent}", file=sys.stderr)
    for name in names:
        graph = read_g2o(DATASETS / f"{name}.g2o", repair_information=name in REPAIR)
        start = initialize(graph, "chordal")
        for variant in variants:
            changes = VARIANTS[variant]
            if not set(changes) <= known:
                continue  # this tree has no such switch
            best = None
            for _ in range(repeat):
                counter["factorize"] = 0
                t0, c0 = time.perf_counter(), time.process_time()
                result = optimize(graph, initial=start, params=SolverParams(**changes))
                seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
                if best is None or seconds < best[1]:
                    best = (result, seconds, counter["factorize"], cpu)
            result, seconds, factorizations, cpu = best
            row = dict(dataset=name, variant=variant, cost=result.final_cost, iterations=result.iterations,
                       factorizations=factorizations, seconds=seconds, cpu_seconds=cpu,
                       termination=result.termination)
            rows.append(row)
            print(f"{name:24s} {variant:18s} {result.final_cost:.12g} it={result.iterations} "
                  f"fact={factorizations} {seconds:.3f}s cpu {cpu:.3f}s {result.termination}", file=sys.stderr)
    return rows


def compare(before_path, after_path):
    before = {(r["dataset"], r["variant"]): r for r in json.loads(Path(before_path).read_text())}
    after = json.loads(Path(after_path).read_text())
    print("| dataset | variant | cost before | cost after | rel. diff | iterations | factorisations | seconds | CPU seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in after:
        b = before.get((r["dataset"], r["variant"]))
        if b is None:
            print(f"| {r['dataset']} | {r['variant']} | — | {r['cost']:.12g} | — | {r['iterations']} | "
                  f"{r['factorizations']} | {r['seconds']:.3f} | {r.get('cpu_seconds', float('nan')):.3f} |")
            continue
        rel = (r["cost"] - b["cost"]) / b["cost"]
        print(f"| {r['dataset']} | {r['variant']} | {b['cost']:.12g} | {r['cost']:.12g} | {rel:.1e} | "
              f"{b['iterations']} → {r['iterations']} | {b['factorizations']} → {r['factorizations']} | "
              f"{b['seconds']:.3f} → {r['seconds']:.3f} | "
              f"{b.get('cpu_seconds', float('nan')):.3f} → {r.get('cpu_seconds', float('nan')):.3f} |")


def alternate(other_root, rounds, names, variants, repeat, out_dir):
    """Run the other tree and this one alternately, ``rounds`` times, in fresh processes (same machine
    load for both); keep each row's fastest round; print the side-by-side table."""
    import os
    import subprocess

    here = str(Path(__file__).resolve().parent.parent)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for k in range(rounds):
        for label, root in (("before", str(other_root)), ("after", here)):
            env = dict(os.environ, PYTHONPATH=root)
            command = [sys.executable, __file__, "--json", str(out_dir / f"{label}{k}.json"), "--repeat", str(repeat),
                       "--datasets", *names, "--variants", *variants]
            subprocess.run(command, env=env, check=True)
    for label in ("before", "after"):
        best = {}
        for k in range(rounds):
            for row in json.loads((out_dir / f"{label}{k}.json").read_text()):
                key = (row["dataset"], row["variant"])
                if key not in best or row["seconds"] < best[key]["seconds"]:
                    best[key] = row
        (out_dir / f"{label}.json").write_text(json.dumps(list(best.values()), indent=1))
    compare(out_dir / "before.json", out_dir / "after.json")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--datasets", nargs="+", default=FILES)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", help="write the rows here")
    parser.add_argument("--against", help="another tree's root: run it and this one alternately")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", default="solver_heuristics_runs", help="directory for --against's files")
    parser.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"), help="print two --json files side by side")
    args = parser.parse_args(argv)
    if args.compare:
        compare(*args.compare)
        return
    if args.against:
        alternate(args.against, args.rounds, args.datasets, args.variants, args.repeat, args.out)
        return
    rows = run(args.datasets, args.variants, args.repeat)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
