"""Side-by-side benchmark of posegraph and gtsam on the same g2o files, whole processes.

Each *run* is one fresh Python process doing the whole job — interpreter start, imports, read,
initialise, optimise, write — because that is what a user waits for:

* ours: ``posegraph optimize IN -o OUT --quiet --report REPORT.json --repair-information``
* gtsam: ``benchmarks/gtsam_pipeline.py IN -o OUT --report REPORT.json --method lm|gn``
  (``readG2o``, ``InitializePose3.initialize`` — ``lago.initialize`` for a 2D graph —,
  ``LevenbergMarquardtOptimizer`` / ``GaussNewtonOptimizer``, ``writeG2o``).

The harness measures the wall time around each process (fork to reaping) and its peak resident
memory (``ru_maxrss`` of that child from ``os.wait4``); each process writes a JSON report with its
own per-phase seconds and costs. Both run as installed commands do, from byte-compiled
modules (:func:`tool_command`, :func:`compile_bytecode`). Per dataset: one warm-up run of every
tool (discarded: it fills the page cache), then ``repeats`` rounds, alternating the order of the tools
from round to round so that a slow spell of a shared machine hits both. Figures are medians over
the rounds. ``other`` is the part of the wall time outside the reported phases (interpreter
start, imports, argument checks, cost evaluations and reports, process exit).

With ``--fresh-venv DIR`` (:func:`fresh_environment`) both tools run from a new virtual
environment made as a new user makes one: ``python -m venv DIR``, then the README's set-up command
``pip install .`` in the project root and ``pip install gtsam`` for the comparison; ours then runs
as the installed ``posegraph`` command. The published ratios are then the ones a user gets on a
machine with nothing installed by hand.

Run ``python -m benchmarks --help`` for the command line; :func:`run_benchmark` is the API.
"""

from __future__ import annotations

import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
"""The project root (``cli.py`` lives there)."""
SHARED_DATASETS = ROOT.parent / "shared" / "datasets"
"""``../shared/datasets``: the standard 3D and 2D benchmarks (SE-Sync's data folder)."""
GTSAM_PIPELINE = Path(__file__).resolve().parent / "gtsam_pipeline.py"

PHASES = ("read", "initialize", "optimize", "write")
"""Phases every report times; ``other`` (= wall − their sum) is added by the harness."""

TOOLS = ("posegraph", "gtsam-lm", "gtsam-gn")
REFERENCE_TOOL = "gtsam-lm"
"""The end-to-end ratio target is against gtsam's Levenberg-Marquardt, like for like with our default."""

TARGET_DATASETS = ("sphere2500", "torus3D", "parking-garage", "intel", "manhattan")
TARGET_RATIO = 0.5
"""End-to-end wall time of ours at most this times gtsam's on :data:`TARGET_DATASETS`."""
COST_TOLERANCE = 1e-6
"""Our final cost may exceed gtsam's best by at most this fraction."""
STARTUP_TARGET = 0.3
"""``import posegraph`` and ``cli.py --help``: seconds, whole process."""


# --------------------------------------------------------------------------------------------
# One process


@dataclass
class ProcessRun:
    """One measured process."""

    wall: float
    """Seconds from spawning the process to reaping it."""
    max_rss: int
    """Peak resident set size of the process, bytes."""
    cpu: float
    """User + system CPU seconds of the process (> wall when it ran threads on several cores)."""
    returncode: int
    stderr: str = ""


SPAWN = Path(__file__).resolve().parent / "spawn.py"


def run_process(command: list[str], timeout: float | None = None, cwd: Path = ROOT) -> ProcessRun:
    """Run ``command`` to completion and measure its wall time, peak memory and CPU time.

    The command is started by the tiny launcher ``benchmarks/spawn.py`` (see its docstring: a
    child forked from this big process would inherit its memory high-water mark), which times it
    and takes its resource usage from ``os.wait4`` — the usage of exactly that child, unlike
    ``getrusage(RUSAGE_CHILDREN)``, which keeps the maximum over all reaped children. On timeout
    the launcher's process group is killed and ``returncode`` is negative.
    """
    with tempfile.TemporaryDirectory(prefix="posegraph-spawn-") as tmp:
        result_path = Path(tmp) / "usage.json"
        err_path = Path(tmp) / "stderr"
        with open(err_path, "wb") as err:
            process = subprocess.Popen(
                [sys.executable, "-I", "-S", str(SPAWN), str(result_path), *command],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, cwd=cwd, start_new_session=True,
            )
            try:
                process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
                return ProcessRun(wall=float(timeout), max_rss=0, cpu=0.0, returncode=-signal.SIGKILL,
                                  stderr=f"killed after {timeout:g} s")
        stderr = err_path.read_bytes().decode(errors="replace")[-4000:]
        try:
            usage = json.loads(result_path.read_text())
        except (OSError, ValueError):
            return ProcessRun(wall=0.0, max_rss=0, cpu=0.0, returncode=process.returncode or -1, stderr=stderr)
    return ProcessRun(wall=usage["wall"], max_rss=int(usage["max_rss"]), cpu=usage["cpu"],
                      returncode=usage["returncode"], stderr=stderr)


# --------------------------------------------------------------------------------------------
# Tools


@dataclass
class Environment:
    """The Python environment the tools run in."""

    python: str = sys.executable
    """Interpreter for gtsam's pipeline and the start-up measurements."""
    posegraph: list[str] | None = None
    """The installed ``posegraph`` command, or None to run ``cli.py`` of this checkout with :attr:`python`."""
    venv: str | None = None
    """The fresh virtual environment's folder (None: the current environment)."""


ENVIRONMENT = Environment()
"""Where :func:`tool_command` runs the tools; replaced by :func:`use_environment`."""


def use_environment(environment: Environment) -> None:
    """Run the tools (and the start-up and environment measurements) in ``environment`` from now on."""
    global ENVIRONMENT
    ENVIRONMENT = environment


def fresh_environment(folder: Path, log=print) -> Environment:
    """A new virtual environment in ``folder`` set up by the README's command, plus gtsam.

    ``python -m venv folder``, ``pip install .`` (run in the project root) and ``pip install
    gtsam``; nothing else, so the solver backend is whatever a new user's ``pip install`` gives.
    """
    folder = Path(folder).resolve()
    if folder.exists():
        raise FileExistsError(f"{folder} exists; --fresh-venv wants a new folder")
    bin_dir = folder / ("Scripts" if os.name == "nt" else "bin")
    python = str(bin_dir / "python")
    log(f"fresh environment: python -m venv {folder}; pip install . ; pip install gtsam")
    for command in ([sys.executable, "-m", "venv", str(folder)], [python, "-m", "pip", "install", "-q", "."],
                    [python, "-m", "pip", "install", "-q", "gtsam"]):  # fmt: skip
        subprocess.run(command, cwd=ROOT, check=True)
    return Environment(python=python, posegraph=[str(bin_dir / "posegraph")], venv=str(folder))


def tool_command(tool: str, source: Path, output: Path, report: Path) -> list[str]:
    """The command line of one tool's run.

    Both run the way an installed command does, ``import`` of a byte-compiled module and a call
    of its ``main`` (:func:`compile_bytecode` compiles them first), not as a script that Python
    compiles afresh at every start. Ours reads with ``--repair-information``: cubicle's 5,021
    indefinite information matrices are then clipped rather than refused (gtsam reads them as
    they are); on a file whose matrices are all positive semi-definite it changes nothing.
    """
    if tool == "posegraph":
        command = ENVIRONMENT.posegraph or [ENVIRONMENT.python, "-c", _RUN_MAIN.format(folder=str(ROOT), module="cli", main="main")]
        return [*command, "optimize", str(source), "-o", str(output), "--quiet", "--report", str(report),
                "--repair-information"]  # fmt: skip
    if tool in ("gtsam-lm", "gtsam-gn"):
        method = tool.split("-")[1]
        return [ENVIRONMENT.python, "-c", _RUN_MAIN.format(folder=str(GTSAM_PIPELINE.parent), module="gtsam_pipeline", main="_main"),
                str(source), "-o", str(output), "--report", str(report), "--method", method]  # fmt: skip
    raise ValueError(f"unknown tool {tool!r}; one of {TOOLS}")


_RUN_MAIN = "import sys; sys.path.insert(0, {folder!r}); from {module} import {main}; sys.exit({main}())"
"""What a console-script entry point does: import the module from ``folder`` and exit with its ``main``."""


def compile_bytecode() -> None:
    """Byte-compile ``posegraph``, ``cli.py`` and the gtsam pipeline, as ``pip install`` does.

    Explicitly, because the warm-up run cannot be relied on for it: where ``PYTHONDONTWRITEBYTECODE``
    is set (it is on the machines here) no process writes byte-code, and every run of ours would
    compile ~9,000 lines of source first (~25 ms) — which no installed copy does.
    """
    import compileall

    compileall.compile_dir(str(ROOT / "posegraph"), quiet=1)
    for script in (ROOT / "cli.py", GTSAM_PIPELINE):
        compileall.compile_file(str(script), quiet=1)


def normalise_report(report: dict) -> dict:
    """The fields the harness uses, from either side's JSON report.

    Returns ``initial_cost``, ``final_cost``, ``iterations``, ``seconds`` (``{phase: s}`` for
    :data:`PHASES`, absent phases 0), plus ``linear_solver``, ``termination``, ``converged``,
    ``factor_nnz`` when the report has them.
    """
    timings = report.get("seconds") or report.get("timings") or report.get("phases") or {}
    aliases = {
        "read": ("read",),
        "initialize": ("initialize", "initialise", "init"),
        "optimize": ("optimize", "optimise", "solve"),
        "write": ("write",),
    }
    seconds = {}
    for phase, names in aliases.items():
        seconds[phase] = float(next((timings[n] for n in names if n in timings), 0.0) or 0.0)
    out = {
        "initial_cost": report.get("initial_cost"),
        "final_cost": report.get("final_cost"),
        "iterations": report.get("iterations"),
        "seconds": seconds,
    }
    for key in ("linear_solver", "termination", "converged", "factor_nnz", "ordering", "vertices", "edges"):
        if key in report:
            out[key] = report[key]
    return out


@dataclass
class ToolRun:
    """One repeat of one tool on one dataset."""

    tool: str
    wall: float
    max_rss: int
    cpu: float
    ok: bool
    error: str = ""
    initial_cost: float | None = None
    final_cost: float | None = None
    iterations: int | None = None
    seconds: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)


def run_tool(tool: str, source: Path, workdir: Path, timeout: float | None) -> ToolRun:
    """One process of ``tool`` on ``source``; outputs go to ``workdir`` and are deleted."""
    output = workdir / f"{tool}_out.g2o"
    report_path = workdir / f"{tool}_report.json"
    for stale in (output, report_path):
        stale.unlink(missing_ok=True)
    process = run_process(tool_command(tool, source, output, report_path), timeout=timeout)
    run = ToolRun(tool=tool, wall=process.wall, max_rss=process.max_rss, cpu=process.cpu, ok=False)
    # A non-zero exit with a report and an output is a finished run that says something (ours exits
    # non-zero when the solver stops before converging): kept, with the status in ``extra``.
    last = process.stderr.strip().splitlines()[-1:] or [f"exit status {process.returncode}"]
    last = [last[0].replace(str(source), source.name)]  # the reason, not a long path
    if process.returncode < 0:
        run.error = f"killed (signal {-process.returncode}; timeout?): {last[0][:300]}"
        return run
    try:
        report = normalise_report(json.loads(report_path.read_text()))
    except (OSError, ValueError) as error:
        run.error = last[0][:300] if process.returncode else f"no usable report: {error}"
        return run
    if not output.is_file():
        run.error = "no output file written"
        return run
    run.ok = True
    run.initial_cost = report.pop("initial_cost")
    run.final_cost = report.pop("final_cost")
    run.iterations = report.pop("iterations")
    run.seconds = report.pop("seconds")
    run.seconds["other"] = max(0.0, run.wall - sum(run.seconds[p] for p in PHASES))
    run.extra = report
    if process.returncode:
        run.extra["exit_status"] = process.returncode
    output.unlink(missing_ok=True)
    return run


# --------------------------------------------------------------------------------------------
# Datasets


def is_3d_g2o(path: Path) -> bool:
    """True when the file's first tagged line is a 3D pose (``VERTEX_SE3…``, ``EDGE_SE3…``, ``EDGE3``)."""
    return _first_tag(path).startswith(("VERTEX_SE3", "EDGE_SE3", "EDGE3", "VERTEX3"))


def is_pose_graph_g2o(path: Path) -> bool:
    """True when the file's first tagged line is a 3D pose or a 2D one (``VERTEX_SE2``, ``EDGE_SE2``)."""
    return is_3d_g2o(path) or _first_tag(path) in ("VERTEX_SE2", "EDGE_SE2")


def _first_tag(path: Path) -> str:
    """The tag of the file's first line that is neither blank nor a comment ("" if none, or unreadable)."""
    try:
        with open(path, errors="replace") as stream:
            for line in stream:
                tag = line.split(maxsplit=1)[0] if line.strip() else ""
                if tag and not tag.startswith("#"):
                    return tag
    except OSError:
        return ""
    return ""


def count_graph(path: Path) -> tuple[int, int]:
    """``(vertices, edges)`` of a g2o file by its tags (vertices: distinct ids in vertex lines, or
    in edges when the file has no vertex lines, as gtsam's EDGE3 files)."""
    vertex_ids, edge_ids, edges = set(), set(), 0
    with open(path, errors="replace") as stream:
        for line in stream:
            fields = line.split(maxsplit=3)
            if not fields:
                continue
            if fields[0].startswith("VERTEX"):
                vertex_ids.add(fields[1])
            elif fields[0].startswith("EDGE") and len(fields) >= 3:
                edges += 1
                edge_ids.update(fields[1:3])
    return len(vertex_ids or edge_ids), edges


@dataclass
class Dataset:
    name: str
    path: Path
    origin: str
    """``shared`` (../shared/datasets), ``gtsam`` (its bundled data), ``synthetic`` or ``user``."""


def shared_datasets(folder: Path = SHARED_DATASETS) -> list[Dataset]:
    """Every 3D or 2D ``.g2o`` in ``folder`` (sorted by name); empty when the folder is absent."""
    if not folder.is_dir():
        return []
    return [Dataset(p.stem, p, "shared") for p in sorted(folder.glob("*.g2o")) if is_pose_graph_g2o(p)]


def gtsam_datasets() -> list[Dataset]:
    """gtsam's bundled ``sphere2500.txt`` (EDGE3 lines, no vertices) and ``pose3example.txt``."""
    try:
        import gtsam
    except ImportError:
        return []
    found = []
    for name in ("sphere2500.txt", "pose3example.txt"):
        try:
            found.append(Dataset(f"gtsam:{Path(name).stem}", Path(gtsam.findExampleDataFile(name)), "gtsam"))
        except (RuntimeError, IndexError):
            pass
    return found


SYNTHETIC_SETS = (
    ("sphere", 2500, {}),
    ("torus", 5000, {}),
    ("grid", 1000, {}),
    ("garage", 1600, {}),
)
"""(shape, size, noise overrides) of the synthetic sets in the default run."""


def synthetic_datasets(folder: Path, sets=SYNTHETIC_SETS, seed: int = 0) -> list[Dataset]:
    """Generate the synthetic sets into ``folder`` (deterministic; reused when already there)."""
    from datasets.synthetic import NoiseParams, generate, write_dataset

    folder.mkdir(parents=True, exist_ok=True)
    found = []
    for shape, size, overrides in sets:
        dataset = generate(shape, size, noise=NoiseParams(**overrides), seed=seed)
        path = folder / f"synthetic_{dataset.name}.g2o"
        if not path.is_file():
            write_dataset(path, dataset)
        found.append(Dataset(path.stem, path, "synthetic"))
    return found


def user_datasets(paths: list[str]) -> list[Dataset]:
    """Files as given, and every 3D or 2D ``.g2o``/``.txt`` in given folders."""
    found = []
    for entry in map(Path, paths):
        if entry.is_dir():
            found += [
                Dataset(p.stem, p, "user") for p in sorted(entry.iterdir())
                if p.suffix in (".g2o", ".txt") and is_pose_graph_g2o(p)
            ]  # fmt: skip
        elif entry.is_file():
            found.append(Dataset(entry.stem, entry, "user"))
        else:
            raise FileNotFoundError(f"{entry}: no such file or folder")
    return found


# --------------------------------------------------------------------------------------------
# Runs and summaries


def _median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def summarise_tool(runs: list[ToolRun]) -> dict:
    """Medians over the successful repeats of one tool on one dataset."""
    good = [r for r in runs if r.ok]
    if not good:
        return {"ok": False, "error": runs[-1].error if runs else "not run", "repeats": 0}
    finals = [r.final_cost for r in good]
    return {
        "ok": True,
        "repeats": len(good),
        "initial_cost": good[-1].initial_cost,
        "final_cost": min(finals),
        "final_cost_spread": max(finals) - min(finals),
        "iterations": good[-1].iterations,
        "seconds": {p: _median([r.seconds[p] for r in good]) for p in PHASES + ("other",)},
        "wall": _median([r.wall for r in good]),
        "wall_min": min(r.wall for r in good),
        "cpu": _median([r.cpu for r in good]),
        "max_rss": max(r.max_rss for r in good),
        **{k: v for k, v in good[-1].extra.items() if k not in ("vertices", "edges")},
    }


def compare(dataset_name: str, tools: dict) -> dict:
    """Ratios and targets for one dataset from its per-tool summaries."""
    ours = tools.get("posegraph", {})
    out: dict = {}
    gtsam_costs = [t["final_cost"] for name, t in tools.items() if name.startswith("gtsam") and t.get("ok")]
    if gtsam_costs:
        out["gtsam_best_cost"] = min(gtsam_costs)
    if ours.get("ok"):
        for name, summary in tools.items():
            if name != "posegraph" and summary.get("ok"):
                out[f"ratio_vs_{name}"] = ours["wall"] / summary["wall"]
        if gtsam_costs:
            best = min(gtsam_costs)
            out["cost_excess"] = (ours["final_cost"] - best) / max(abs(best), 1e-300)
            out["cost_ok"] = ours["final_cost"] <= best * (1 + COST_TOLERANCE) + 1e-12
    if dataset_name in TARGET_DATASETS:
        ratio = out.get(f"ratio_vs_{REFERENCE_TOOL}")
        out["target"] = {
            "ratio": TARGET_RATIO,
            "ratio_met": ratio is not None and ratio <= TARGET_RATIO,
            "ratio_over_by": None if ratio is None else ratio / TARGET_RATIO - 1.0,
            "cost_met": bool(out.get("cost_ok")),
        }
        if ours.get("ok") and tools.get(REFERENCE_TOOL, {}).get("ok"):
            # Which of our phases would have to shrink: the seconds over budget against each phase.
            budget = TARGET_RATIO * tools[REFERENCE_TOOL]["wall"]
            out["target"]["seconds_over_budget"] = max(0.0, ours["wall"] - budget)
            phases = dict(ours["seconds"])
            out["target"]["largest_phase"] = max(phases, key=phases.get)
    return out


def benchmark_dataset(dataset: Dataset, tools=TOOLS, repeats: int = 5, warmup: int = 1, timeout: float | None = 900, log=print) -> dict:
    """Warm-up, then ``repeats`` alternating rounds of every tool on one dataset."""
    vertices, edges = count_graph(dataset.path)
    runs: dict[str, list[ToolRun]] = {t: [] for t in tools}
    with tempfile.TemporaryDirectory(prefix="posegraph-bench-") as tmp:
        workdir = Path(tmp)
        for _ in range(warmup):
            for tool in tools:
                run_tool(tool, dataset.path, workdir, timeout)
        for round_ in range(repeats):
            order = list(tools) if round_ % 2 == 0 else list(reversed(tools))
            for tool in order:
                run = run_tool(tool, dataset.path, workdir, timeout)
                runs[tool].append(run)
                if not run.ok and round_ == 0:
                    log(f"  {dataset.name}: {tool} failed: {run.error}")
    summaries = {tool: summarise_tool(r) for tool, r in runs.items()}
    return {
        "dataset": dataset.name,
        "path": str(dataset.path),
        "origin": dataset.origin,
        "vertices": vertices,
        "edges": edges,
        "tools": summaries,
        "comparison": compare(dataset.name, summaries),
        "runs": {tool: [asdict(r) for r in rs] for tool, rs in runs.items()},
    }


def measure_startup(runs: int = 10) -> dict:
    """Median whole-process seconds of ``python -c pass``, ``import posegraph``, ``cli.py --help``."""
    python = ENVIRONMENT.python
    commands = {
        "python -c pass": [python, "-c", "pass"],
        "import posegraph": [python, "-c", "import posegraph"],
        "cli.py --help": [*ENVIRONMENT.posegraph, "--help"] if ENVIRONMENT.posegraph else [python, str(ROOT / "cli.py"), "--help"],
    }
    out = {}
    for name, command in commands.items():
        run_process(command)  # warm-up
        walls = []
        for _ in range(runs):
            process = run_process(command)
            if process.returncode != 0:
                out[name] = {"error": process.stderr.strip().splitlines()[-1:] or [f"exit {process.returncode}"]}
                break
            walls.append(process.wall)
        else:
            out[name] = {"median": statistics.median(walls), "min": min(walls), "runs": runs}
    base = out.get("python -c pass", {}).get("median")
    for name in ("import posegraph", "cli.py --help"):
        if "median" in out.get(name, {}):
            out[name]["target"] = STARTUP_TARGET
            out[name]["met"] = out[name]["median"] <= STARTUP_TARGET
            if base is not None:
                out[name]["over_bare_python"] = out[name]["median"] - base
    return out


def machine_info() -> dict:
    """Cores, CPU, memory, BLAS, linear-solver backend and library versions of this machine."""
    from importlib.metadata import PackageNotFoundError, version

    info: dict = {"python": platform.python_version(), "platform": platform.platform(), "cores": os.cpu_count()}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                info["memory_gb"] = round(int(line.split()[1]) / 2**20, 1)
        info["load_average"] = Path("/proc/loadavg").read_text().split()[:3]
    except OSError:
        pass
    info.update(environment_info())
    info["git"] = git_state()
    info["threads"] = {k: os.environ[k] for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS") if k in os.environ}
    return info


_ENVIRONMENT_PROBE = """
import json, sys
from importlib.metadata import PackageNotFoundError, version
out = {"python": sys.version.split()[0]}
for package in ("numpy", "scipy", "cvxopt", "pymetis", "threadpoolctl", "gtsam"):
    try:
        out[package] = version(package)
    except PackageNotFoundError:
        out[package] = None
import numpy
try:
    blas = numpy.show_config(mode="dicts")["Build Dependencies"]["blas"]
    out["numpy_blas"] = f"{blas.get('name')} {blas.get('version')}"
except Exception:
    out["numpy_blas"] = None
from posegraph.linalg import cholmod
out["cholmod"] = "cvxopt" if cholmod.load() is not None else f"unavailable: {cholmod.unavailable_reason()}"
if cholmod.load() is not None:
    import threadpoolctl
    out["cholmod_blas"] = [f"{i.get('internal_api')} {i.get('version')} ({i.get('threading_layer')})"
                           for i in threadpoolctl.threadpool_info() if "cvxopt" in i.get("filepath", "")]
    cholmod.SparseCholesky([0, 1], [0], 1).factorize([2.0])
maps = open("/proc/self/maps").read() if sys.platform == "linux" else ""
out["system_cholmod_loaded"] = sorted({l.split()[-1] for l in maps.splitlines() if "libcholmod" in l and "cvxopt" not in l})
print(json.dumps(out))
"""
"""Run in the tools' interpreter: package versions, the CHOLMOD backend, its BLAS, and any
SuiteSparse library from the system mapped into a process that has used CHOLMOD."""


def environment_info() -> dict:
    """:data:`_ENVIRONMENT_PROBE`'s answer from :data:`ENVIRONMENT` (run outside this checkout when installed)."""
    cwd = Path(tempfile.gettempdir()) if ENVIRONMENT.posegraph else ROOT
    proc = subprocess.run([ENVIRONMENT.python, "-c", _ENVIRONMENT_PROBE], capture_output=True, text=True, cwd=cwd, timeout=120)
    if proc.returncode:
        return {"environment_error": (proc.stderr.strip().splitlines() or ["?"])[-1]}
    info = json.loads(proc.stdout)
    info["venv"] = ENVIRONMENT.venv
    return info


def git_state() -> str | None:
    """The project's commit, and whether tracked files differ from it (None outside git)."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{commit}{' + uncommitted changes' if dirty else ''}" if commit else None


def run_benchmark(
    datasets: list[Dataset],
    tools=TOOLS,
    repeats: int = 5,
    warmup: int = 1,
    timeout: float | None = 900,
    startup_runs: int = 10,
    log=print,
) -> dict:
    """Benchmark every dataset; returns the full result (what is written as JSON)."""
    started = time.time()
    info = machine_info()
    if ENVIRONMENT.posegraph is None:
        compile_bytecode()  # pip compiled the installed copy
    results = []
    for dataset in datasets:
        log(f"{dataset.name} ({dataset.path})")
        result = benchmark_dataset(dataset, tools, repeats, warmup, timeout, log)
        log(format_dataset_line(result))
        results.append(result)
    startup = measure_startup(startup_runs) if startup_runs else {}
    info["load_average_end"] = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else None
    return {
        "machine": info,
        "settings": {"tools": list(tools), "repeats": repeats, "warmup": warmup, "reference_tool": REFERENCE_TOOL},
        "started": time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(started)),
        "elapsed_seconds": time.time() - started,
        "startup": startup,
        "datasets": results,
    }


# --------------------------------------------------------------------------------------------
# Output


def _fmt_seconds(value) -> str:
    return "—" if value is None else f"{value:.3f}"


def _fmt_cost(value) -> str:
    return "—" if value is None else f"{value:.10g}"


def format_dataset_line(result: dict) -> str:
    parts = [f"  {result['dataset']}: {result['vertices']} vertices, {result['edges']} edges"]
    for tool, summary in result["tools"].items():
        if summary.get("ok"):
            parts.append(f"{tool} {summary['wall']:.3f} s cost {summary['final_cost']:.10g}")
        else:
            parts.append(f"{tool} failed ({summary.get('error', '')[:80]})")
    ratio = result["comparison"].get(f"ratio_vs_{REFERENCE_TOOL}")
    if ratio is not None:
        parts.append(f"ratio {ratio:.2f}")
    return "; ".join(parts)


RUN_COLUMNS = (
    "dataset", "vertices", "edges", "tool", "start cost", "final cost", "iterations",
    "read s", "initialise s", "optimise s", "write s", "other s", "end-to-end s", "ours/tool", "peak MB",
)
SUMMARY_COLUMNS = (
    "dataset", "vertices", "edges", "ours s", "gtsam LM s", "gtsam GN s", "ours/LM", "ours/GN",
    "ours cost", "gtsam best cost", "cost ≤ best·(1+1e-6)", "target",
)


def _table(columns, rows) -> list[str]:
    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def run_rows(results: list[dict]) -> list[list]:
    """One row per (dataset, tool): the :data:`RUN_COLUMNS`."""
    rows = []
    for result in results:
        ours = result["tools"].get("posegraph", {})
        for tool, s in result["tools"].items():
            if not s.get("ok"):
                rows.append([result["dataset"], result["vertices"], result["edges"], tool, f"failed: {s.get('error', '')[:120]}"] + ["—"] * 10)
                continue
            ratio = ours["wall"] / s["wall"] if ours.get("ok") and tool != "posegraph" else None
            rows.append(
                [
                    result["dataset"], result["vertices"], result["edges"], tool,
                    _fmt_cost(s["initial_cost"]), _fmt_cost(s["final_cost"]),
                    f"{s['iterations']}{' (not converged)' if s.get('converged') is False else ''}",
                    *(_fmt_seconds(s["seconds"][p]) for p in PHASES + ("other",)),
                    _fmt_seconds(s["wall"]), "—" if ratio is None else f"{ratio:.2f}", f"{s['max_rss'] / 2**20:.0f}",
                ]
            )
    return rows


def summary_rows(results: list[dict]) -> list[list]:
    """One row per dataset: the :data:`SUMMARY_COLUMNS`."""
    rows = []
    for result in results:
        tools, comparison = result["tools"], result["comparison"]

        def wall(tool):
            s = tools.get(tool, {})
            return _fmt_seconds(s["wall"]) if s.get("ok") else "—"

        def ratio(tool):
            value = comparison.get(f"ratio_vs_{tool}")
            return "—" if value is None else f"{value:.2f}"

        ours = tools.get("posegraph", {})
        cost_ok = comparison.get("cost_ok")
        cost_cell = "—" if cost_ok is None else ("yes" if cost_ok else f"no (+{comparison['cost_excess']:.2e})")
        target = comparison.get("target")
        if target is None:
            target_cell = ""
        elif target["ratio_met"] and target["cost_met"]:
            target_cell = "met"
        else:
            misses = []
            if not target["ratio_met"]:
                over = target["ratio_over_by"]
                misses.append("time: not measured" if over is None else f"time missed by {100 * over:.0f}% ({target.get('seconds_over_budget', 0):.3f} s over)")
            if not target["cost_met"]:
                misses.append("cost missed")
            target_cell = "; ".join(misses)
        rows.append(
            [
                result["dataset"], result["vertices"], result["edges"], wall("posegraph"), wall("gtsam-lm"), wall("gtsam-gn"),
                ratio("gtsam-lm"), ratio("gtsam-gn"), _fmt_cost(ours.get("final_cost")),
                _fmt_cost(comparison.get("gtsam_best_cost")), cost_cell, target_cell,
            ]
        )
    return rows


def to_markdown(benchmark: dict) -> str:
    """The result as Markdown: machine, summary table, per-tool table, start-up times."""
    m = benchmark["machine"]
    s = benchmark["settings"]
    lines = [
        "# Benchmark results (generated by `python -m benchmarks`)",
        "",
        f"Taken {benchmark['started']} on {m.get('cpu', '?')}, {m.get('cores')} cores, {m.get('memory_gb', '?')} GB; "
        f"Python {m.get('python')}, numpy {m.get('numpy')} (BLAS {m.get('numpy_blas')}), scipy {m.get('scipy')}, "
        f"cvxopt {m.get('cvxopt')} (CHOLMOD {m.get('cholmod')}, BLAS {m.get('cholmod_blas')}), pymetis {m.get('pymetis')}, "
        f"gtsam {m.get('gtsam')}; system SuiteSparse loaded: {m.get('system_cholmod_loaded') or 'none'}"
        f"{'; fresh venv ' + m['venv'] + ' (pip install . ; pip install gtsam)' if m.get('venv') else ''}. "
        f"Load average at start {' '.join(m.get('load_average') or [])}, at end {' '.join(m.get('load_average_end') or [])}. "
        f"posegraph at git {m.get('git')}.",
        "",
        f"Whole processes, {s['warmup']} warm-up + {s['repeats']} alternating rounds per dataset, medians; "
        f"ratios are ours / the other tool's end-to-end wall time. Target on {', '.join(TARGET_DATASETS)}: "
        f"ours/gtsam-LM ≤ {TARGET_RATIO} with final cost ≤ gtsam's best × (1 + {COST_TOLERANCE:g}).",
        "",
        "## Summary",
        "",
        *_table(SUMMARY_COLUMNS, summary_rows(benchmark["datasets"])),
        "",
        "## Per tool (median seconds per phase; other = wall − phases: interpreter start, imports, checks, exit)",
        "",
        *_table(RUN_COLUMNS, run_rows(benchmark["datasets"])),
        "",
    ]
    solvers = sorted({str(r["tools"]["posegraph"].get("linear_solver")) for r in benchmark["datasets"] if r["tools"].get("posegraph", {}).get("ok")})
    if solvers:
        lines += [f"Our linear solver: {', '.join(solvers)}.", ""]
    if benchmark.get("startup"):
        lines += ["## Start-up (whole process, median)", "", "| command | seconds | over bare python | target | met |", "|---|---|---|---|---|"]
        for name, value in benchmark["startup"].items():
            if "median" not in value:
                lines.append(f"| `{name}` | error: {value.get('error')} | | | |")
                continue
            over = value.get("over_bare_python")
            lines.append(
                f"| `{name}` | {value['median']:.3f} | {'' if over is None else f'{over:.3f}'} | "
                f"{value.get('target', '')} | {'' if 'met' not in value else ('yes' if value['met'] else 'no')} |"
            )
        lines.append("")
    return "\n".join(lines)


def write_outputs(benchmark: dict, folder: Path, stem: str = "benchmark_results") -> tuple[Path, Path]:
    """Write ``stem.json`` and ``stem.md`` into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    json_path = folder / f"{stem}.json"
    md_path = folder / f"{stem}.md"
    json_path.write_text(json.dumps(benchmark, indent=1, default=str) + "\n")
    md_path.write_text(to_markdown(benchmark))
    return json_path, md_path
