"""Landmark graphs: posegraph, g2o (g2opy) and gtsam side by side as whole processes (issue 35).

    python -m benchmarks.bench_landmarks [--data DIR] [--repeats N] [--out docs] [--pose-graphs-before REV]

Files: the public landmark files in ``--data`` (default ``../data-landmarks`` beside the checkout, :data:`DATA_FILES`) and
gtsam's bundled ones (:data:`GTSAM_FILES`); an absent file is listed with the reason. Tools, each one
process per run (interpreter start, imports, read, solve, write):

* posegraph: ``python -m posegraph optimize IN -o OUT --quiet --report R`` (cwd: this checkout); on
  iSAM/gtsam text files with ``--isam-information covariance``, which is how ``gtsam.load2D`` takes the
  numbers of ``ODOMETRY`` lines (checked: its ``BetweenFactorPose2`` noise is their inverse);
* g2opy: ``python -m benchmarks.g2opy_pipeline`` (load, fix the first pose, LM to convergence, save);
* gtsam: ``python -m benchmarks.gtsam_landmarks`` (gtsam's own reader, LM from its values, write).

Per file a probe round (discarded, it fills the page cache) decides which tools read the file (a child
that reads fewer measurements than the file has reports ``not_read``); then ``--repeats`` rounds of the
tools that read it, alternating their order; medians. g2o's χ² of posegraph's solution comes from
loading posegraph's output into g2opy (``g2opy_pipeline --chi2-only``). ``--pose-graphs-before REV``
also times ``posegraph optimize FILE -o OUT -q`` at this checkout against commit REV (extracted with
``git archive``), alternating, on :data:`POSE_GRAPH_FILES`. Writes ``landmark_results.json``/``.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness

ROOT = harness.ROOT
DATA_DIR = ROOT.parent / "data-landmarks"
"""Where the public files are fetched to, beside the checkout (as ``../shared``), never inside it:
``dlr.g2o`` from doggydoggy0101/math_project (``pose_graph_optimization/data/dlr.g2o``, the Freiburg
SLAM course's DLR set), the ``.g2o.gz`` files from grisetti/g2o_frontend (``datasets/2D/``)."""
DATA_FILES = ("dlr.g2o", "victoriaPark-full.g2o.gz", "world-1000-dense-highnoise_default.g2o.gz", "world-2000-default.g2o.gz",
              "world-2000-full.g2o.gz", "world-2000-lownoise-default.g2o.gz", "world-2000-lownoise-full.g2o.gz",
              "isam_manhattanOlson3500.txt",
              "isam_victoriaPark.txt", "isam_cityTrees10000.txt", "isam_torus2000Points.txt")  # fmt: skip
GTSAM_FILES = ("victoria_park.txt", "example.graph", "victoriaPark_reduced_1k.g2o", "edge_se3_trackxyz_example.g2o",
               "edge_se3_trackxyz_nonidentity_offset.g2o")  # fmt: skip
POSE_GRAPH_FILES = ("sphere2500.g2o", "torus3D.g2o", "intel.g2o")
TOOLS = ("posegraph", "g2opy", "gtsam")
COST_TOLERANCE = 1e-6
TARGET_RATIO = 0.5
THREADS = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def landmark_files(data: Path) -> list[dict]:
    """``{"name", "path" (None when absent), "reason"}`` for every file of the benchmark."""
    found = [{"name": name, "path": data / name} for name in DATA_FILES]
    try:
        import gtsam

        for name in GTSAM_FILES:
            try:
                found.append({"name": f"gtsam:{name}", "path": Path(gtsam.findExampleDataFile(name))})
            except (RuntimeError, IndexError):
                found.append({"name": f"gtsam:{name}", "path": None, "reason": "not in gtsam's data"})
    except ImportError:
        found += [{"name": f"gtsam:{name}", "path": None, "reason": "gtsam not installed"} for name in GTSAM_FILES]
    for entry in found:
        if entry["path"] is not None and not Path(entry["path"]).is_file():
            entry.update(path=None, reason=f"absent: {entry['path']}")
    return found


def is_g2o_file(path: Path) -> bool:
    """A g2o file by its name (``.g2o`` or ``.g2o.gz``); iSAM's and gtsam's text files are not."""
    return path.name.endswith((".g2o", ".g2o.gz"))


def tool_command(tool: str, source: Path, output: Path, report: Path) -> list[str]:
    """One tool's command line (run with cwd = the project root)."""
    python = sys.executable
    if tool == "posegraph":
        extra = [] if is_g2o_file(source) else ["--isam-information", "covariance"]
        return [python, "-m", "posegraph", "optimize", str(source), "-o", str(output), "--quiet", "--report", str(report), *extra]
    module = {"g2opy": "benchmarks.g2opy_pipeline", "gtsam": "benchmarks.gtsam_landmarks"}[tool]
    return [python, "-m", module, str(source), "-o", str(output), "--report", str(report)]


def parse_report(tool: str, report: dict) -> dict:
    """A child's JSON report as ``{not_read, cost, chi2, iterations, seconds, counts}`` (cost = ½χ², gtsam's error)."""
    seconds = {k: v for k, v in (report.get("seconds") or {}).items() if isinstance(v, (int, float))}
    out = {"not_read": report.get("not_read"), "iterations": report.get("iterations"), "seconds": seconds}
    if tool == "posegraph":
        out.update(cost=report["final_cost"], chi2=report["chi2"], converged=report.get("converged"),
                   counts={"poses": report["num_vertices"], "landmarks": report.get("num_landmarks", 0),
                           "measurements": report["num_edges"] + report.get("num_landmark_measurements", 0)})
    elif tool == "g2opy":
        chi2 = report.get("final_chi2")
        out.update(chi2=chi2, cost=None if chi2 is None else chi2 / 2)
    else:
        cost = report.get("final_cost")
        out.update(cost=cost, chi2=None if cost is None else 2 * cost, reader=report.get("reader"),
                   model_differs=report.get("model_differs"))
    return out


def run_once(tool: str, source: Path, workdir: Path, timeout: float) -> dict:
    """One process of ``tool``: ``{ok, wall, error, **parse_report}``; the output stays in ``workdir``."""
    output, report_path = workdir / f"{tool}_out.g2o", workdir / f"{tool}_report.json"
    report_path.unlink(missing_ok=True)
    process = harness.run_process(tool_command(tool, source, output, report_path), timeout=timeout, cwd=ROOT)
    run = {"tool": tool, "wall": process.wall, "max_rss": process.max_rss, "returncode": process.returncode}
    try:
        run.update(parse_report(tool, json.loads(report_path.read_text())))
    except (OSError, ValueError, KeyError) as error:
        last = (process.stderr.strip().splitlines() or [f"exit status {process.returncode}"])[-1]
        return {**run, "ok": False, "error": last.replace(str(source), source.name)[:300] or str(error)}
    run["ok"] = run["not_read"] is None and output.is_file()
    if not run["ok"] and run["not_read"] is None:
        run["error"] = "no output file written"
    return run


def g2o_chi2_of(solution: Path, timeout: float) -> dict:
    """g2o's χ² of a solution file (``g2opy_pipeline --chi2-only``): ``{chi2, not_read}`` (chi2 None on failure)."""
    with tempfile.TemporaryDirectory(prefix="g2o-chi2-") as tmp:
        report = Path(tmp) / "chi2.json"
        command = [sys.executable, "-m", "benchmarks.g2opy_pipeline", str(solution), "--chi2-only", "--report", str(report)]
        subprocess.run(command, cwd=ROOT, capture_output=True, timeout=timeout)
        try:
            data = json.loads(report.read_text())
        except (OSError, ValueError):
            return {"chi2": None, "not_read": "g2opy failed on posegraph's output"}
    return {"chi2": None if data["not_read"] else data["final_chi2"], "not_read": data["not_read"]}


def common_cost_of(solution: Path) -> float | None:
    """The common cost (posegraph's, gtsam's Log-based error ½ Σ eᵀΩe) of a solution file: its poses and
    points as written, read by posegraph; None when it cannot be read."""
    import warnings

    from posegraph.io.g2o import read_g2o
    from posegraph.solve.objective import Objective

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            graph = read_g2o(solution)
        points = None if graph.landmarks is None else graph.landmarks.positions
        return float(Objective(graph).evaluate(graph.poses, points).cost)
    except (OSError, ValueError):
        return None


def median_summary(runs: list[dict]) -> dict:
    """Medians of one tool's measured runs (wall and per-phase seconds), its last run's figures."""
    good = [r for r in runs if r["ok"]]
    if not good:
        return {"ok": False, "error": runs[-1].get("not_read") or runs[-1].get("error", "not run") if runs else "not run"}
    phases = sorted({p for r in good for p in r["seconds"]})
    last = good[-1]
    return {"ok": True, "repeats": len(good), "wall": statistics.median(r["wall"] for r in good),
            "walls": [r["wall"] for r in good], "seconds": {p: statistics.median(r["seconds"].get(p, 0.0) for r in good) for p in phases},
            **{k: last.get(k) for k in ("cost", "chi2", "iterations", "converged", "counts", "reader", "model_differs")}}


def bench_file(entry: dict, repeats: int, timeout: float, log=print) -> dict:
    """Probe round, then ``repeats`` alternating rounds of the tools that read the file; medians and g2o's χ²."""
    source = Path(entry["path"])
    with tempfile.TemporaryDirectory(prefix="bench-landmarks-") as tmp:
        workdir = Path(tmp)
        probe = {tool: run_once(tool, source, workdir, timeout) for tool in TOOLS}
        active = [t for t in TOOLS if probe[t]["ok"]]
        runs = {t: [] for t in active}
        for round_ in range(repeats):
            for tool in active if round_ % 2 == 0 else active[::-1]:
                runs[tool].append(run_once(tool, source, workdir, timeout))
        solution = workdir / "posegraph_out.g2o"
        if "posegraph" in active and is_g2o_file(source):
            g2o_view = g2o_chi2_of(solution, timeout)
        else:  # no solution, or not a g2o file: g2o's χ² is not a question
            g2o_view = {"chi2": None, "not_read": None}
        g2opy_output = workdir / "g2opy_out.g2o"
        g2opy_common = common_cost_of(g2opy_output) if "g2opy" in active and g2opy_output.is_file() else None
    tools = {t: median_summary(runs[t]) if t in active else median_summary([probe[t]]) for t in TOOLS}
    result = {"file": entry["name"], "path": str(source), "g2o_file": is_g2o_file(source), "tools": tools,
              "posegraph_g2o_chi2": g2o_view["chi2"], "posegraph_g2o_chi2_note": g2o_view["not_read"],
              "g2opy_common_cost": g2opy_common}
    result["comparison"] = compare(result)
    log(format_line(result))
    return result


ROUND_OFF = 1e-12
"""Absolute differences of χ² or cost below this count as none: on a noise-free file g2o's χ² is 0 and
ours 4e-29 (round-off), which a relative difference would make 10²⁷¹."""


def _relative(ours, theirs):
    if ours is None or theirs is None:
        return None
    return 0.0 if abs(ours - theirs) <= ROUND_OFF else (ours - theirs) / max(abs(theirs), 1e-300)


def compare(result: dict) -> dict:
    """Targets on one file: χ² vs g2opy (both definitions), cost vs gtsam, time ratios."""
    pg, g2, gt = (result["tools"][t] for t in TOOLS)
    out: dict = {}
    if pg["ok"] and g2["ok"]:
        out["chi2_excess_own"] = _relative(pg["chi2"], g2["chi2"])
        out["chi2_excess_g2o"] = _relative(result["posegraph_g2o_chi2"], g2["chi2"])
        out["chi2_met"] = out["chi2_excess_g2o"] is not None and out["chi2_excess_g2o"] <= COST_TOLERANCE
        out["common_cost_excess"] = _relative(pg["cost"], result.get("g2opy_common_cost"))
        out["common_cost_met"] = out["common_cost_excess"] is not None and out["common_cost_excess"] <= COST_TOLERANCE
        out["ratio_vs_g2opy"] = pg["wall"] / g2["wall"]
        out["ratio_met"] = out["ratio_vs_g2opy"] <= TARGET_RATIO
    if pg["ok"] and gt["ok"]:
        out["ratio_vs_gtsam"] = pg["wall"] / gt["wall"]
        out["cost_excess_vs_gtsam"] = _relative(pg["cost"], gt["cost"])
        out["gtsam_comparable"] = not gt.get("model_differs")
        if out["gtsam_comparable"]:
            out["gtsam_cost_met"] = out["cost_excess_vs_gtsam"] <= COST_TOLERANCE
    return out


def format_line(result: dict) -> str:
    """One line per file for the log."""
    parts = []
    for tool, s in result["tools"].items():
        parts.append(f"{tool} {s['wall']:.3f} s χ² {s['chi2']:.10g}" if s["ok"] else f"{tool} — ({str(s.get('error'))[:70]})")
    return f"  {result['file']}: " + "; ".join(parts)


def _f(value, spec: str = ".10g") -> str:
    return "—" if value is None else format(value, spec)


def file_table(result: dict) -> list[str]:
    """One file's Markdown table: a row per tool."""
    pg, cmp_ = result["tools"]["posegraph"], result["comparison"]
    counts = pg.get("counts") or {}
    lines = [f"### {result['file']}", "",
             f"{counts.get('poses', '?')} poses, {counts.get('landmarks', '?')} landmarks, {counts.get('measurements', '?')} measurements "
             f"(posegraph's reading). χ² = Σ eᵀΩe = 2 × cost.", "",
             "| tool | χ² (own definition) | χ² (g2o's definition) | cost (½χ², gtsam's error) | iterations | end-to-end s (median) | phases s | posegraph / tool |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for tool, s in result["tools"].items():
        if not s["ok"]:
            lines.append(f"| {tool} | {'not read' if tool != 'posegraph' else 'failed'}: {s.get('error')} | | | | | | |")
            continue
        g2o_chi2 = result["posegraph_g2o_chi2"] if tool == "posegraph" else (s["chi2"] if tool == "g2opy" else None)
        phases = ", ".join(f"{p} {v:.3f}" for p, v in s["seconds"].items() if p not in ("total",))
        ratio = cmp_.get(f"ratio_vs_{tool}")
        note = " (not converged)" if s.get("converged") is False else ""
        note += f" ({s['reader']})" if s.get("reader") else ""
        lines.append(f"| {tool}{note} | {_f(s['chi2'])} | {_f(g2o_chi2)} | {_f(s['cost'])} | {s['iterations']} | "
                     f"{s['wall']:.3f} | {phases} | {_f(ratio, '.2f')} |")  # fmt: skip
    lines += ["", *target_lines(result), ""]
    return lines


IN_PROCESS_PHASES = {"posegraph": ("read", "initialise", "optimise", "write"), "g2opy": ("import", "read", "optimize", "write")}
"""The phases each child times itself: their sum is its in-process time, the rest of its wall time is start-up and exit."""


def in_process_line(result: dict) -> str:
    """In-process seconds (the children's own phases summed) and the start-up floor of each tool."""
    parts = []
    for tool, phases in IN_PROCESS_PHASES.items():
        s = result["tools"][tool]
        inside = sum(s["seconds"].get(p, 0.0) for p in phases)
        parts.append((tool, inside, s["wall"] - inside))
    (_, pg_in, pg_floor), (_, g2_in, g2_floor) = parts
    return (f"* in process (read + start + solve + write): posegraph {pg_in:.3f} s, g2opy {g2_in:.3f} s (ratio {pg_in / g2_in:.2f}); "
            f"start-up and exit outside: posegraph {pg_floor:.3f} s, g2opy {g2_floor:.3f} s")


def target_lines(result: dict) -> list[str]:
    """The targets' verdicts on one file, as bullet lines."""
    c, gt = result["comparison"], result["tools"]["gtsam"]
    out = []
    if "chi2_met" in c:
        out.append(f"* χ² ≤ g2opy's × (1 + 1e-6), g2o's definition: {'yes' if c['chi2_met'] else 'NO'} "
                   f"(relative {_f(c['chi2_excess_g2o'], '+.3e')}; posegraph's own χ² vs g2opy's: {_f(c['chi2_excess_own'], '+.3e')})")
        out.append(f"* common cost (posegraph's, ½ Σ eᵀΩe with Log-based errors) of each answer: posegraph {_f(result['tools']['posegraph']['cost'])}, "
                   f"g2opy's output {_f(result.get('g2opy_common_cost'))}; posegraph's at or below (1e-6): "
                   f"{'yes' if c['common_cost_met'] else 'NO'} (relative {_f(c['common_cost_excess'], '+.3e')})")
        out.append(f"* end-to-end ≤ 0.5 × g2opy's: {'yes' if c['ratio_met'] else 'NO'} (ratio {c['ratio_vs_g2opy']:.2f})")
        out.append(in_process_line(result))
    if "gtsam_cost_met" in c:
        out.append(f"* cost ≤ gtsam's × (1 + 1e-6): {'yes' if c['gtsam_cost_met'] else 'NO'} (relative {c['cost_excess_vs_gtsam']:+.3e})")
    elif gt["ok"] and gt.get("model_differs"):
        out.append(f"* gtsam's cost not comparable: {gt['model_differs']} (relative difference {_f(c.get('cost_excess_vs_gtsam'), '+.3e')})")
    if result["tools"]["posegraph"]["ok"] and result.get("posegraph_g2o_chi2_note"):
        out.append(f"* g2o's χ² of posegraph's output: not computed ({result['posegraph_g2o_chi2_note']})")
    return out


def to_markdown(benchmark: dict) -> str:
    """The whole result as Markdown (command, machine, a table per file, the pose-graph check)."""
    m = benchmark["machine"]
    lines = ["# Landmark graphs: posegraph, g2o (g2opy), gtsam (generated by `python -m benchmarks.bench_landmarks`)", "",
             f"Command: `{benchmark['command']}` (threads: {benchmark['threads']}).", "",
             f"Taken {benchmark['started']} on {m.get('cpu', '?')}, {m.get('cores')} cores (shared), load average at start "
             f"{' '.join(m.get('load_average') or [])}; posegraph at git {m.get('git')}; gtsam {m.get('gtsam')}, numpy {m.get('numpy')}.", "",
             "Whole processes (interpreter start, imports, read, solve, write); a probe round first (discarded), then "
             f"{benchmark['repeats']} rounds alternating the tools' order; medians. posegraph: `python -m posegraph optimize IN -o OUT "
             "--quiet --report R` (iSAM/gtsam text: `--isam-information covariance`, how gtsam.load2D takes ODOMETRY's numbers); "
             "g2opy: `python -m benchmarks.g2opy_pipeline` (load, first pose fixed, LM BlockSolverX/LinearSolverEigenX, "
             "`optimize(1000)` from the file's values, save); gtsam: `python -m benchmarks.gtsam_landmarks` (readG2o or load2D, "
             "prior σ 1e-6 on the first pose, LM from the reader's values, writeG2o). \"g2o's definition\" of posegraph's χ²: "
             "its output file loaded into g2opy, `compute_active_errors(); active_chi2()`.", ""]  # fmt: skip
    for entry in benchmark["skipped"]:
        lines.append(f"* {entry['name']}: skipped ({entry['reason']})")
    lines += [""]
    for result in benchmark["files"]:
        lines += file_table(result)
    if benchmark.get("pose_graphs"):
        lines += pose_graph_markdown(benchmark["pose_graphs"])
    return "\n".join(lines) + "\n"


def extract_revision(rev: str, folder: Path) -> Path:
    """``git archive REV`` of this repository unpacked into ``folder`` (byte-compiled like this checkout)."""
    import compileall

    folder.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    compileall.compile_dir(str(folder / "posegraph"), quiet=1)
    return folder


def pose_graph_check(rev: str, repeats: int, timeout: float, folder: Path = harness.SHARED_DATASETS, log=print) -> dict:
    """``posegraph optimize FILE -o OUT -q`` here vs at ``rev``, alternating, one warm-up each: medians and ratio."""
    out = {"revision": rev, "repeats": repeats, "files": []}
    with tempfile.TemporaryDirectory(prefix="pg-before-") as tmp:
        trees = {"current": ROOT, rev: extract_revision(rev, Path(tmp) / "tree")}
        for name in POSE_GRAPH_FILES:
            path = folder / name
            if not path.is_file():
                out["files"].append({"file": name, "skipped": f"absent: {path}"})
                continue
            walls: dict = {label: [] for label in trees}
            for round_ in range(repeats + 1):
                for label in list(trees) if round_ % 2 == 0 else list(trees)[::-1]:
                    command = [sys.executable, "-m", "posegraph", "optimize", str(path), "-o", str(Path(tmp) / "out.g2o"), "-q"]
                    run = harness.run_process(command, timeout=timeout, cwd=trees[label])
                    if round_ and run.returncode == 0:
                        walls[label].append(run.wall)
            medians = {label: statistics.median(w) if w else None for label, w in walls.items()}
            entry = {"file": name, "walls": walls, "medians": medians,
                     "ratio": None if None in medians.values() else medians["current"] / medians[rev]}
            log(f"  pose graph {name}: current {_f(medians['current'], '.3f')} s, {rev} {_f(medians[rev], '.3f')} s")
            out["files"].append(entry)
    return out


def pose_graph_markdown(check: dict) -> list[str]:
    """The before/after table."""
    rev = check["revision"]
    lines = [f"## Pure pose graphs: this commit vs {rev}", "",
             f"`python -m posegraph optimize FILE -o OUT -q`, cwd at each tree, 1 warm-up + {check['repeats']} alternating rounds, medians.", "",
             f"| file | current s | {rev} s | current / {rev} | all runs current | all runs {rev} |", "|---|---|---|---|---|---|"]  # fmt: skip
    for entry in check["files"]:
        if "skipped" in entry:
            lines.append(f"| {entry['file']} | skipped: {entry['skipped']} | | | | |")
            continue
        m, w = entry["medians"], entry["walls"]
        lines.append(f"| {entry['file']} | {_f(m['current'], '.3f')} | {_f(m[rev], '.3f')} | {_f(entry['ratio'], '.3f')} | "
                     f"{', '.join(f'{x:.3f}' for x in w['current'])} | {', '.join(f'{x:.3f}' for x in w[rev])} |")  # fmt: skip
    return lines + [""]


def run(args, log=print) -> dict:
    """The whole benchmark as the JSON-able result."""
    os.environ.update(THREADS)
    started = time.time()
    harness.compile_bytecode()
    entries = landmark_files(Path(args.data))
    if args.only:
        entries = [e for e in entries if any(word in e["name"] for word in args.only)]
    result = {"command": "python -m benchmarks.bench_landmarks " + " ".join(args.argv), "threads": THREADS,
              "machine": harness.machine_info(), "repeats": args.repeats,
              "started": time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(started)),
              "skipped": [e for e in entries if e["path"] is None], "files": []}  # fmt: skip
    for entry in entries:
        if entry["path"] is not None:
            log(f"{entry['name']} ({entry['path']})")
            result["files"].append(bench_file(entry, args.repeats, args.timeout, log))
    if args.pose_graphs_before:
        result["pose_graphs"] = pose_graph_check(args.pose_graphs_before, args.repeats, args.timeout, log=log)
    result["elapsed_seconds"] = time.time() - started
    return result


def write_outputs(result: dict, folder: Path) -> tuple[Path, Path]:
    """``landmark_results.json`` and ``landmark_results.md`` in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    json_path, md_path = folder / "landmark_results.json", folder / "landmark_results.md"
    json_path.write_text(json.dumps(result, indent=1, default=str) + "\n")
    md_path.write_text(to_markdown(result))
    return json_path, md_path


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.bench_landmarks", description=__doc__.splitlines()[0])
    p.add_argument("--data", default=str(DATA_DIR), help=f"folder of the public landmark files (default {DATA_DIR})")
    p.add_argument("--repeats", type=int, default=3, help="measured rounds per file (default 3)")
    p.add_argument("--out", default="docs", help="folder for landmark_results.json/.md (default docs/)")
    p.add_argument("--only", nargs="+", metavar="NAME", help="keep only files whose name contains one of these")
    p.add_argument("--timeout", type=float, default=600, help="seconds before one process is killed")
    p.add_argument("--pose-graphs-before", metavar="REV", help="also time pure pose graphs here vs at REV (e.g. 49beac0)")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parser().parse_args(argv)
    if args.repeats < 1:
        parser().error("--repeats must be >= 1")
    args.argv = argv
    result = run(args)
    json_path, md_path = write_outputs(result, Path(args.out))
    print(to_markdown(result))
    print(f"wrote {json_path} and {md_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
