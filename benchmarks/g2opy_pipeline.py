"""g2o's side of the landmark benchmark as one process (g2opy): load, fix the first pose, optimise, save.

    python -m benchmarks.g2opy_pipeline IN.g2o[.gz] -o OUT.g2o --report REPORT.json
    python -m benchmarks.g2opy_pipeline OUT.g2o --chi2-only --report REPORT.json

What a g2o user writes: ``SparseOptimizer.load`` (a ``.gz`` file is decompressed to a temporary file
first, as g2o reads plain text only; that is timed as part of ``read``), the pose vertex with the
smallest id held fixed, ``OptimizationAlgorithmLevenberg(BlockSolverX(LinearSolverEigenX()))``,
``optimize(1000)`` from the file's values (g2o's LM stops by itself when a step makes no progress),
``save``. χ² is g2o's: ``compute_active_errors(); active_chi2()`` (Σ eᵀΩe with g2o's error functions;
for ``EDGE_SE2`` the [x, y, θ] of Z⁻¹Xi⁻¹Xj, not its Log).

``--chi2-only`` loads a file (posegraph's output) and reports g2o's χ² of its values without optimising.
The report is JSON: ``vertices``, ``edges`` (edges g2o loaded), ``measurement_lines`` (lines of the file
with a measurement tag, :data:`MEASUREMENT_TAGS`), ``not_read`` (a reason, or null), ``initial_chi2``,
``final_chi2``, ``iterations`` and ``seconds`` per phase (``import``, ``read``, ``optimize``, ``write``).
"""

import time

_t0 = time.perf_counter()

import argparse  # noqa: E402
import gzip  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from benchmarks.child_report import write_report  # noqa: E402

MEASUREMENT_TAGS = ("EDGE", "ODOMETRY", "LANDMARK", "BR", "POINT3")
"""Tags (prefixes) of the lines that are measurements in g2o, gtsam and iSAM files."""
POSE_VERTEX_TYPES = ("VertexSE2", "VertexSE3")


def open_text(path: str):
    """The file as text, through gzip when its name ends in ``.gz``."""
    return gzip.open(path, "rt", errors="replace") if path.endswith(".gz") else open(path, errors="replace")


def measurement_lines(path: str) -> int:
    """How many lines of the file carry a measurement (their tag starts with one of :data:`MEASUREMENT_TAGS`)."""
    count = 0
    with open_text(path) as stream:
        for line in stream:
            tag = line.split(maxsplit=1)[0] if line.strip() else ""
            count += tag.startswith(MEASUREMENT_TAGS)
    return count


def plain_copy(path: str, folder: str) -> str:
    """``path`` itself, or for a ``.gz`` file its decompressed copy in ``folder``."""
    if not path.endswith(".gz"):
        return path
    target = os.path.join(folder, os.path.basename(path)[: -len(".gz")])
    with gzip.open(path, "rb") as source, open(target, "wb") as stream:
        shutil.copyfileobj(source, stream)
    return target


def make_optimizer(g2o):
    """A ``SparseOptimizer`` with Levenberg–Marquardt over ``BlockSolverX(LinearSolverEigenX())``."""
    optimizer = g2o.SparseOptimizer()
    optimizer.set_algorithm(g2o.OptimizationAlgorithmLevenberg(g2o.BlockSolverX(g2o.LinearSolverEigenX())))
    return optimizer


def fix_first_pose(optimizer) -> int | None:
    """Hold the pose vertex with the smallest id (SE2/SE3); returns its id (None: no pose vertex)."""
    vertices = optimizer.vertices()
    poses = [i for i, v in vertices.items() if type(v).__name__ in POSE_VERTEX_TYPES]
    if not poses:
        return None
    first = min(poses)
    vertices[first].set_fixed(True)
    return first


def chi2(optimizer) -> float:
    """g2o's χ² of the active edges at the current values."""
    optimizer.compute_active_errors()
    return float(optimizer.active_chi2())


def run(args, seconds: dict) -> dict:
    """Load, (optimise, save), and the report's fields."""
    t = time.perf_counter()
    import g2opy as g2o

    seconds["import"] = time.perf_counter() - t
    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="g2opy-") as tmp:
        optimizer = make_optimizer(g2o)
        loaded = optimizer.load(plain_copy(args.input, tmp))
    seconds["read"] = time.perf_counter() - t
    lines = measurement_lines(args.input)
    edges = len(optimizer.edges())
    report = {"tool": "g2opy", "vertices": len(optimizer.vertices()), "edges": edges, "measurement_lines": lines,
              "not_read": None if loaded and edges == lines else f"g2o loaded {edges} of {lines} measurement lines"}
    first = fix_first_pose(optimizer)
    optimizer.initialize_optimization()
    report.update(fixed_vertex=first, initial_chi2=chi2(optimizer), final_chi2=None, iterations=0)
    if args.chi2_only or report["not_read"]:
        report["final_chi2"] = report["initial_chi2"]
        return report
    t = time.perf_counter()
    report["iterations"] = int(optimizer.optimize(args.max_iterations))
    seconds["optimize"] = time.perf_counter() - t
    report["final_chi2"] = chi2(optimizer)
    t = time.perf_counter()
    optimizer.save(args.output)
    seconds["write"] = time.perf_counter() - t
    return report


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.g2opy_pipeline", description=__doc__.splitlines()[0])
    parser.add_argument("input")
    parser.add_argument("-o", "--output")
    parser.add_argument("--report", required=True)
    parser.add_argument("--chi2-only", action="store_true", help="load and report g2o's χ² of the file's values")
    parser.add_argument("--max-iterations", type=int, default=1000)
    args = parser.parse_args(argv)
    if not args.chi2_only and not args.output:
        parser.error("-o/--output is required unless --chi2-only")
    seconds: dict = {}
    return write_report(args.report, run(args, seconds), seconds, _t0)


if __name__ == "__main__":
    sys.exit(main())
