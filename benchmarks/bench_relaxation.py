"""The chordal start of landmark graphs (``posegraph/init/relaxation.py``) here against another revision.

    python -m benchmarks.bench_relaxation --before main --repeats 5

Each file is solved by whole processes, ``python -m posegraph optimize FILE -o OUT -q --report R``,
in this checkout and in ``git archive BEFORE`` (byte-compiled alike), alternating which goes first
from round to round, one warm-up round discarded. Per tree: the start's and the optimum's cost and
the LM iterations (from the report), the medians of the initialise phase and of the in-process
total (read + initialise + optimise + write, the report's own clock), and of the whole process's
wall and CPU seconds (``benchmarks/spawn.py``). Files: the public landmark files
(``benchmarks.bench_landmarks.DATA_FILES``) and two pose graphs (``sphere2500``, ``intel``), whose
start the relaxation does not touch (a check that nothing else moved).

Then, per landmark file and tree, ``relaxed_start`` alone in one process (:data:`RELAXATION_ALONE`):
the least CPU seconds of ``--calls`` calls after a first, and the start's cost with the landmarks placed
from its poses (the cost LM starts from), for the files whose own values are their start too.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks import harness
from benchmarks.bench_landmarks import DATA_DIR, DATA_FILES, THREADS, extract_revision

POSE_GRAPHS = ("sphere2500.g2o", "intel.g2o")
FIELDS = ("initial_cost", "final_cost", "iterations")
RELAXATION_ALONE = """
import json, sys, time, warnings
warnings.simplefilter("ignore")
from posegraph.io.g2o import read_g2o
from posegraph.init.landmarks import initialize_landmarks
from posegraph.init.relaxation import relaxed_start
from posegraph.solve.objective import Objective
graph = read_g2o(sys.argv[1])
poses, seconds = relaxed_start(graph), []
for _ in range(int(sys.argv[2])):
    start = time.process_time()
    relaxed_start(graph)
    seconds.append(time.process_time() - start)
cost = Objective(graph).evaluate(poses, initialize_landmarks(graph, poses)[0]).cost
print(json.dumps({"cpu": min(seconds), "start_cost": float(cost)}))
"""


def run_once(path: Path, tree: Path, workdir: Path, timeout: float) -> dict | None:
    """One whole process in ``tree``: its report's costs, iterations and phases, its wall and CPU seconds."""
    report = workdir / "report.json"
    report.unlink(missing_ok=True)
    command = [sys.executable, "-W", "ignore", "-m", "posegraph", "optimize", str(path), "-o", str(workdir / "out.g2o"),
               "-q", "--force", "--report", str(report)]  # fmt: skip
    run = harness.run_process(command, timeout=timeout, cwd=tree)
    if run.returncode != 0 or not report.exists():
        return None
    data = json.loads(report.read_text())
    seconds = data["seconds"]
    return {**{key: data[key] for key in FIELDS}, "initialise": seconds["initialise"], "in_process": seconds["total"],
            "wall": run.wall, "cpu": run.cpu}  # fmt: skip


def compare_file(path: Path, trees: dict, repeats: int, workdir: Path, timeout: float) -> dict:
    """``{label: {"runs": [...], "median": {...}}}`` over ``repeats`` alternating rounds after a warm-up."""
    runs: dict = {label: [] for label in trees}
    for round_ in range(repeats + 1):
        for label in list(trees) if round_ % 2 == 0 else list(trees)[::-1]:
            result = run_once(path, trees[label], workdir, timeout)
            if round_ and result is not None:
                runs[label].append(result)
    out = {}
    for label, results in runs.items():
        median = {key: statistics.median(r[key] for r in results) for key in ("initialise", "in_process", "wall", "cpu")} if results else {}
        out[label] = {"runs": results, "median": median, **({key: results[-1][key] for key in FIELDS} if results else {})}
    return out


def relaxation_alone(path: Path, trees: dict, calls: int, timeout: float) -> dict:
    """``{label: {"cpu", "start_cost"}}``: :data:`RELAXATION_ALONE` in each tree (None where it failed)."""
    out = {}
    for label, tree in trees.items():
        done = subprocess.run([sys.executable, "-c", RELAXATION_ALONE, str(path), str(calls)], cwd=tree,
                              capture_output=True, text=True, timeout=timeout)  # fmt: skip
        out[label] = json.loads(done.stdout) if done.returncode == 0 else None
    return out


def markdown(results: dict, before: str, repeats: int) -> str:
    """One row per file and tree, then the ratios of the medians."""
    lines = [f"`python -m benchmarks.bench_relaxation --before {before} --repeats {repeats}` (medians of {repeats} alternating rounds)", "",
             "| file | tree | start cost | final cost | LM its | initialise s | in-process s | whole wall s | whole CPU s |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for name, by_tree in results.items():
        for label, entry in by_tree.items():
            if not entry["runs"]:
                lines.append(f"| {name} | {label} | failed | | | | | | |")
                continue
            m = entry["median"]
            lines.append(f"| {name} | {label} | {entry['initial_cost']:.10g} | {entry['final_cost']:.12g} | {entry['iterations']} | "
                         f"{m['initialise']:.3f} | {m['in_process']:.3f} | {m['wall']:.3f} | {m['cpu']:.3f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def relaxation_markdown(alone: dict, calls: int) -> str:
    """One row per landmark file: each tree's least CPU seconds of ``relaxed_start`` and its start's cost."""
    labels = list(next(iter(alone.values()))) if alone else []
    lines = [f"`relaxed_start(graph)` alone, in process: least CPU seconds of {calls} calls after a first, and the cost LM starts from", "",
             "| file | " + " | ".join(f"{label} s | {label} start cost" for label in labels) + " |", "|---" * (1 + 2 * len(labels)) + "|"]  # fmt: skip
    for name, by_tree in alone.items():
        cells = [f"{e['cpu']:.3f} | {e['start_cost']:.10g}" if e else "failed | " for e in by_tree.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--before", default="main", help="the revision to compare with (default main)")
    p.add_argument("--repeats", type=int, default=5, help="measured rounds per file (default 5)")
    p.add_argument("--data", default=str(DATA_DIR), help=f"folder of the landmark files (default {DATA_DIR})")
    p.add_argument("--only", nargs="+", metavar="NAME", help="keep only files whose name contains one of these")
    p.add_argument("--calls", type=int, default=5, help="calls of relaxed_start alone per tree (default 5)")
    p.add_argument("--json", help="also write the runs here")
    p.add_argument("--timeout", type=float, default=600)
    args = p.parse_args(argv)
    os.environ.update(THREADS)
    os.environ.pop("PYTHONPATH", None)  # each tree's own posegraph: the processes run with -m from its folder
    harness.compile_bytecode()
    paths = [Path(args.data) / name for name in DATA_FILES] + [harness.SHARED_DATASETS / name for name in POSE_GRAPHS]
    paths = [path for path in paths if path.is_file() and (not args.only or any(k in path.name for k in args.only))]
    results, alone = {}, {}
    with tempfile.TemporaryDirectory(prefix="pg-relaxation-") as tmp:
        trees = {"current": harness.ROOT, args.before: extract_revision(args.before, Path(tmp) / "tree")}
        for path in paths:
            results[path.name] = compare_file(path, trees, args.repeats, Path(tmp), args.timeout)
            print(f"{path.name}: " + ", ".join(f"{label} {e['median'].get('initialise', float('nan')):.3f} s initialise, "
                                                f"{e['median'].get('wall', float('nan')):.3f} s whole" for label, e in results[path.name].items()),
                  file=sys.stderr, flush=True)  # fmt: skip
        for path in paths:
            if path.name not in POSE_GRAPHS:
                alone[path.name] = relaxation_alone(path, trees, args.calls, args.timeout)
    if args.json:
        Path(args.json).write_text(json.dumps({"processes": results, "relaxation_alone": alone}, indent=1))
    print(markdown(results, args.before, args.repeats))
    print(relaxation_markdown(alone, args.calls))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
