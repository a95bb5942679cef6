"""The ``posegraph`` command: optimise, compare with gtsam, verify Jacobians, inspect, evaluate, plot, export.

``python cli.py …`` and the installed ``posegraph …`` are the same program (``posegraph = "cli:main"``).
Only the standard library is imported at start-up; numpy, scipy and the project's modules are
imported by the subcommand that needs them, and gtsam, Open3D and matplotlib only by the
subcommands and options that use them, so ``posegraph --help`` answers at once.

Exit status: 0 success (optimiser converged; compare agreed; every Jacobian check within
tolerance); 1 the run finished but did not meet that bar (iteration cap hit — the result is still
written, with a warning —, costs disagree, a check over tolerance); 2 bad input or usage (one line
``posegraph: error: file:line: reason`` on stderr, nothing written); 130 interrupted by Ctrl-C
(nothing written).
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
import warnings

PROG = "posegraph"

EXIT_OK = 0
EXIT_NOT_CONVERGED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

OPTIONAL_MODULES = frozenset({"gtsam", "open3d", "matplotlib", "mpl_toolkits", "sksparse"})
"""Packages some commands or options need; their absence is a usage error, not a crash."""

MAX_WARNINGS_SHOWN = 20
"""Warnings beyond this many are counted, not printed (a file can repeat one repair per line)."""


# --------------------------------------------------------------------------------------------
# messages


class _UsageError(Exception):
    """A command-line mistake found after parsing (e.g. conflicting outputs)."""


class _ArgumentParser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line and lets main() choose the exit status."""

    def error(self, message):
        raise _UsageError(f"{message} (see '{self.prog} --help')")


def _error(message: str) -> None:
    print(f"{PROG}: error: {message}", file=sys.stderr, flush=True)


def _warn(message: str) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr, flush=True)


class _WarningPrinter:
    """``warnings.showwarning`` replacement: one line per warning, without source lines."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self, message, category, filename, lineno, file=None, line=None):
        self.count += 1
        if self.count <= MAX_WARNINGS_SHOWN:
            text = " ".join(str(message).split())
            if not _is_input_warning(category):
                text = f"{category.__name__}: {text}"
            _warn(text)

    def finish(self) -> None:
        if self.count > MAX_WARNINGS_SHOWN:
            _warn(f"{self.count - MAX_WARNINGS_SHOWN} more warnings not shown")


def _is_input_warning(category) -> bool:
    from posegraph.errors import InputWarning

    return issubclass(category, InputWarning)


class _Status:
    """Progress and phase lines on stderr, silenced by ``--quiet``."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet

    def __call__(self, message: str) -> None:
        if not self.quiet:
            print(message, file=sys.stderr, flush=True)


class _Ticker:
    """While a long phase runs, an elapsed-time line on an interactive stderr (redrawn in place).

    Reading, initialising and writing report no fraction done, so the line shows the phase and its
    seconds so far; it appears only after :data:`TICKER_DELAY` seconds and only on a terminal, so
    quick runs, pipes and log files see just the final phase line.
    """

    def __init__(self, status: "_Status", label: str) -> None:
        self.label = label
        self.enabled = not status.quiet and sys.stderr.isatty()
        self._done = None

    def __enter__(self):
        if self.enabled:
            import threading

            self._done = threading.Event()
            self._start = time.perf_counter()
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        if self._done.wait(TICKER_DELAY):
            return
        while not self._done.wait(0.25):
            sys.stderr.write(f"\r{self.label} … {time.perf_counter() - self._start:.1f} s")
            sys.stderr.flush()

    def __exit__(self, *exc) -> None:
        if self._done is not None:
            self._done.set()
            self._thread.join()
            sys.stderr.write("\r\033[K")  # clear the ticker line before the final message
            sys.stderr.flush()


TICKER_DELAY = 1.0


class _Timer:
    def __enter__(self):
        self.start = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.start


def _fmt_cost(x: float) -> str:
    return f"{x:.12g}"


# --------------------------------------------------------------------------------------------
# paths


def _check_output(path: str, *, inputs=(), allow_input: bool = False, what: str = "output") -> None:
    """Fail before any work if ``path`` cannot be written as asked."""
    from posegraph.errors import OutputError

    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise OutputError(f"cannot write the {what}: folder {folder} does not exist", path=path)
    if os.path.isdir(path):
        raise OutputError(f"cannot write the {what}: it is a folder", path=path)
    for source in inputs:
        if _same_file(path, source) and not allow_input:
            hint = " (pass --force to overwrite it)" if what == "result" else ""
            raise OutputError(f"the {what} would overwrite the input {source}{hint}", path=path)


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _check_distinct(paths) -> None:
    paths = [p for p in paths if p]
    for k, a in enumerate(paths):
        for b in paths[k + 1 :]:
            if _same_file(a, b):
                raise _UsageError(f"two outputs are the same file: {a} and {b}")


_UNUSED_NUMPY_SUBMODULES = frozenset({"f2py", "testing", "ma", "polynomial", "ctypeslib", "rec", "char", "strings", "core", "test"})
"""Lazily loaded numpy submodules nothing on the optimise path uses (see :func:`_import_scipy_sparse`)."""


def _import_scipy_sparse() -> None:
    """``import scipy.sparse`` without the ~0.1 s scipy 1.17 spends importing numpy.f2py and friends.

    scipy's private array-API namespace (``scipy._lib.array_api_compat.numpy``, imported by
    ``scipy.sparse``) clones numpy with ``from numpy import *`` plus a ``getattr`` of every name in
    ``dir(numpy)``, which imports each of numpy's lazily loaded submodules — ``numpy.f2py`` (with
    charset_normalizer), ``numpy.testing``, ``numpy.ma``, ``numpy.polynomial`` … — none of which
    the solver, scipy.sparse or CHOLMOD use; in those few milliseconds they cost more than the
    reading of a 10,000-edge file. So numpy's ``__all__`` and ``__dir__`` leave them out while
    that clone is made, and are put back right after: numpy itself is untouched, the submodules
    still import on first use, and scipy's clone merely lacks them (scipy reaches ``xp.testing``
    only for CuPy and PyTorch arrays). Done by the command-line program only, never by the
    library, and skipped (a plain import) if numpy is not laid out as expected.
    """
    if "scipy.sparse" in sys.modules:
        return
    import numpy

    namespace = vars(numpy)
    lazy = _UNUSED_NUMPY_SUBMODULES & set(getattr(numpy, "__numpy_submodules__", ()))
    saved_all, saved_dir = namespace.get("__all__"), namespace.get("__dir__")
    if not lazy or not isinstance(saved_all, list) or not callable(saved_dir):
        import scipy.sparse  # noqa: F401

        return
    try:
        numpy.__all__ = [name for name in saved_all if name not in lazy]
        numpy.__dir__ = lambda: [name for name in saved_dir() if name not in lazy]
        import scipy.sparse  # noqa: F401
    finally:
        numpy.__all__, numpy.__dir__ = saved_all, saved_dir


_MALLOC_SETTINGS = {-3: 32 * 2**20, -1: 256 * 2**20, -2: 64 * 2**20}
"""glibc ``mallopt`` settings of :func:`_keep_freed_memory`: M_MMAP_THRESHOLD (−3) 32 MiB,
M_TRIM_THRESHOLD (−1) 256 MiB, M_TOP_PAD (−2) 64 MiB."""

_MALLOC_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "GLIBC_TUNABLES")


def _keep_freed_memory() -> bool:
    """Let glibc's malloc reuse freed memory for numpy's arrays instead of returning it to the system.

    By default glibc serves each allocation above a threshold (128 kB, raised as large blocks are
    freed, up to 32 MiB) with its own ``mmap`` and gives it back with ``munmap`` when freed, so the
    next array of that size is new memory again, and touching it page-faults all over (each fault
    costly on a virtual machine). A solver run allocates the same few-MB arrays every iteration:
    keeping blocks below 32 MiB in the heap, and freed heap memory up to 256 MiB in the process,
    makes later arrays reuse memory already mapped. Measured on parking-garage, whole `posegraph
    optimize` processes, 15 each, alternating: 272–281 ms without, 260–274 ms with. Arrays above
    32 MiB (large graphs) are still mapped and unmapped one by one, so peak memory does not grow.
    Done by the command-line program only (it is process-wide), only with glibc, and not when the
    user set malloc's environment variables. Returns whether it was applied.
    """
    if any(name in os.environ for name in _MALLOC_VARIABLES) or not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        if not hasattr(libc, "gnu_get_libc_version") or not hasattr(libc, "mallopt"):
            return False  # not glibc (musl's mallopt ignores these)
        return all(libc.mallopt(ctypes.c_int(key), ctypes.c_int(value)) == 1 for key, value in _MALLOC_SETTINGS.items())
    except (OSError, AttributeError):
        return False


def _single_threaded_blas() -> None:
    """Make OpenBLAS start with one thread in this process, unless ``OPENBLAS_NUM_THREADS`` is set.

    Must run before numpy is imported (OpenBLAS reads the variable when it loads). Both OpenBLAS
    builds in the process — numpy's bundled one and the system one under CHOLMOD — otherwise
    start a worker thread per core at load, which busy-waits for work while the main thread goes
    on importing: on the 2-core machine here ``import numpy`` took 0.14 s against 0.09 s with one
    thread, and a whole ``posegraph optimize`` ~30 ms longer. Nothing on this path wants more:
    numpy only multiplies small matrices, and the solver runs CHOLMOD's BLAS on one thread anyway
    (``SolverParams.blas_threads``).
    """
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _import_solver_modules() -> None:
    """Import what the read / initialise / optimise phases use, so that their timings are work,
    not first-use imports. Only those: scipy.sparse.linalg (SuperLU) and scipy.sparse.csgraph
    (odometry start) import on first use, as they are needed only off the default path. With the
    system CHOLMOD usable directly (:mod:`posegraph.cholmod`) that path needs no scipy at all,
    and scipy and scikit-sparse are not imported (~0.14 s less per run)."""
    import contextlib

    _single_threaded_blas()
    _keep_freed_memory()
    from posegraph import cholmod

    if cholmod.load() is None:
        _import_scipy_sparse()
        with contextlib.suppress(ImportError):
            import sksparse.cholmod  # noqa: F401

    import posegraph.init  # noqa: F401
    import posegraph.io.g2o  # noqa: F401
    import posegraph.solve  # noqa: F401

    # The ~30,000 objects these imports made live as long as the process. Frozen (moved out of the
    # garbage collector's generations), they are no longer traversed by every full collection, nor
    # collected one by one when the interpreter shuts down: that teardown took ~30 ms of every
    # `posegraph optimize` on torus3D, ~12 ms frozen. Objects made later are collected as usual.
    gc.freeze()


def _read(path: str, status: _Status, *, require_edges: bool = True, repair_information: bool = False):
    from posegraph.io.g2o import read_g2o

    with _Ticker(status, f"reading {path}"), _Timer() as t:
        graph = read_g2o(path, require_edges=require_edges, repair_information=repair_information)
    status(f"read {path}: {graph.num_vertices} vertices, {graph.num_edges} edges ({t.seconds:.3f} s)")
    return graph, t.seconds


def _require_matplotlib() -> None:
    from posegraph.plot import require_matplotlib

    require_matplotlib()


# --------------------------------------------------------------------------------------------
# optimize


def _repair_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repair-information", action="store_true",
                   help="replace each information matrix that is not positive semi-definite by the nearest one "
                        "(Frobenius norm; eigenvalues clipped to 1e-9 times the largest), with one warning, "
                        "instead of refusing the file")


def _solver_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--method", choices=("lm", "gn"), default="lm",
                   help="Levenberg-Marquardt (default) or Gauss-Newton")
    p.add_argument("--init", choices=("chordal", "odometry", "file"), default="chordal",
                   help="start: chordal relaxation of the rotations (default), chaining the odometry "
                        "edges, or the poses in the file")
    p.add_argument("--max-iterations", type=_non_negative_int, default=100, metavar="N",
                   help="iteration cap (default 100); reaching it gives exit status 1")
    p.add_argument("--relative-tolerance", type=_non_negative_float, default=None, metavar="TOL",
                   help="stop when an iteration lowers the cost by at most this fraction "
                        "(default: the solver's, 1e-7)")
    p.add_argument("--absolute-tolerance", type=_non_negative_float, default=None, metavar="TOL",
                   help="stop when an iteration lowers the cost by at most this much "
                        "(default: the solver's, 1e-12)")
    p.add_argument("--linear-solver", choices=("auto", "cholmod", "scipy"), default="auto",
                   help="sparse Cholesky backend: CHOLMOD (the system library, else scikit-sparse) or scipy; auto picks "
                        "CHOLMOD when installed")


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0: {text}")
    return value


def _non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0: {text}")
    return value


def _solver_params(args, callback=None):
    from posegraph.solve import SolverParams

    options = dict(method=args.method, max_iterations=args.max_iterations,
                   linear_solver=args.linear_solver, callback=callback)
    if args.relative_tolerance is not None:
        options["relative_tolerance"] = args.relative_tolerance
    if args.absolute_tolerance is not None:
        options["absolute_tolerance"] = args.absolute_tolerance
    return SolverParams(**options)


def _initial_poses(graph, args):
    from posegraph.init import initialize

    if args.init == "chordal":
        return initialize(graph, method="chordal", linear_solver=args.linear_solver)
    return initialize(graph, method=args.init)


def _iteration_printer(status: _Status):
    def callback(record) -> None:
        note = "" if record.accepted else "  (step rejected)"
        status(
            f"  iter {record.iteration:3d}  cost {record.cost:.10e}  decrease {record.cost_decrease:.3e}  "
            f"lambda {record.lambda_:.1e}  {record.seconds:.3f} s{note}"
        )

    return callback


def cmd_optimize(args) -> int:
    from posegraph.atomic import StagedOutputs

    status = _Status(args.quiet)
    _check_output(args.output, inputs=[args.input], allow_input=args.force, what="result")
    if args.report:
        _check_output(args.report, inputs=[args.input], what="report")
    if args.plot:
        _check_output(args.plot, inputs=[args.input], what="figure")
        _require_matplotlib()
    _check_distinct([args.output, args.report, args.plot])

    _import_solver_modules()  # first: it imports scipy.sparse its own way
    from posegraph.io.g2o import write_g2o
    from posegraph.solve import optimize
    from posegraph.solve.residuals import cost

    graph, seconds_read = _read(args.input, status, repair_information=args.repair_information)
    # The cost at the file's poses is printed and reported; with --quiet and no report nothing shows it.
    file_cost = float(cost(graph)) if (not args.quiet or args.report) else float("nan")
    with _Ticker(status, f"initialising ({args.init})"), _Timer() as t_init:
        start = _initial_poses(graph, args)
    start_cost = None  # with --quiet, the solver's own first evaluation (result.initial_cost) supplies it
    if not args.quiet:
        start_cost = float(cost(graph, start)) if args.init != "file" else file_cost
        status(f"initialised ({args.init}): cost {_fmt_cost(file_cost)} -> {_fmt_cost(start_cost)} "
               f"({t_init.seconds:.3f} s)")

    params = _solver_params(args, callback=None if args.quiet else _iteration_printer(status))
    with _Timer() as t_opt:
        result = optimize(graph, initial=start, params=params)
    if start_cost is None:
        start_cost = result.initial_cost
    status(f"{result.method}: {result.termination} after {result.iterations} iterations ({t_opt.seconds:.3f} s)")

    seconds = {"read": seconds_read, "initialise": t_init.seconds, "optimise": t_opt.seconds}
    with StagedOutputs() as outputs:
        with _Ticker(status, f"writing {args.output}"), _Timer() as t_write:
            write_g2o(outputs.stage(args.output), graph, result.poses)
        seconds["write"] = t_write.seconds
        if args.plot:
            from posegraph.plot import plot_trajectories

            with _Ticker(status, f"drawing {args.plot}"), _Timer() as t_plot:
                plot_trajectories(
                    outputs.stage(args.plot), [graph, graph],
                    [f"input ({os.path.basename(args.input)})", "optimised"],
                    [graph.poses, result.poses], title=os.path.basename(args.input),
                )
            seconds["plot"] = t_plot.seconds
        if args.report:
            from posegraph.atomic import write_json_atomic
            from posegraph.report import optimize_report

            report = optimize_report(
                args.input, args.output, graph, result, init=args.init, file_cost=file_cost,
                start_cost=start_cost, seconds=seconds, params=params,
            )
            write_json_atomic(outputs.stage(args.report), report)
        outputs.commit()

    if not args.quiet:
        print(f"input:          {args.input} ({graph.num_vertices} vertices, {graph.num_edges} edges)")
        print(f"file cost:      {_fmt_cost(file_cost)}")
        print(f"initial cost:   {_fmt_cost(result.initial_cost)} (after {args.init} initialisation)")
        print(f"final cost:     {_fmt_cost(result.final_cost)}")
        print(f"iterations:     {result.iterations}")
        print(f"termination:    {result.termination}")
        print(f"linear solver:  {result.linear_solver}")
        print("seconds:        " + ", ".join(f"{k} {v:.3f}" for k, v in seconds.items())
              + f", total {sum(seconds.values()):.3f}")
        print(f"output:         {args.output}" + "".join(f", {p}" for p in (args.report, args.plot) if p))
    if result.converged:
        return EXIT_OK
    _warn(f"the solver stopped before converging ({result.termination}, {result.iterations} iterations); "
          f"the result was written to {args.output} anyway")
    return EXIT_NOT_CONVERGED


# --------------------------------------------------------------------------------------------
# compare


COMPARE_COST_TOLERANCE = 1e-6
"""Default for ``compare --cost-tolerance``: relative difference of the final costs, against
max(1, |gtsam's final cost|). With the solver's default tolerances both optimisers stop within
~1e-9 relative of the same optimum on the standard datasets; 1e-6 leaves room for gtsam stopping
one iteration earlier without hiding a different local minimum."""


def cmd_compare(args) -> int:
    import numpy as np

    from posegraph.gtsam_bridge import require_gtsam, run_gtsam

    require_gtsam()
    if args.report:
        _check_output(args.report, inputs=[args.input], what="report")

    from posegraph.evaluate import rotation_angle
    from posegraph.solve import optimize
    from posegraph.solve.residuals import cost

    status = _Status(args.quiet)
    _import_solver_modules()
    graph, seconds_read = _read(args.input, status, repair_information=args.repair_information)
    with _Timer() as t_init:
        start = _initial_poses(graph, args)
    params = _solver_params(args, callback=None if args.quiet else _iteration_printer(status))
    status(f"posegraph: {params.method}, start {args.init}")
    with _Timer() as t_opt:
        ours = optimize(graph, initial=start, params=params)

    if args.gtsam_start == "same" or args.init == "odometry":
        gtsam_init, gtsam_initial = "given", start
    else:
        gtsam_init, gtsam_initial = args.init, None
    status(f"gtsam: {params.method}, start {'same as posegraph' if gtsam_init == 'given' else args.init}")
    # With repaired information gtsam gets our model, not the file's matrices.
    theirs = run_gtsam(
        graph if args.repair_information else args.input, graph=graph, init=gtsam_init, initial=gtsam_initial,
        method=params.method,
        max_iterations=params.max_iterations, relative_tolerance=params.relative_tolerance,
        absolute_tolerance=params.absolute_tolerance,
    )

    rot = np.degrees(rotation_angle(np.swapaxes(ours.poses[:, :3, :3], -1, -2) @ theirs.poses[:, :3, :3]))
    trans = np.linalg.norm(ours.poses[:, :3, 3] - theirs.poses[:, :3, 3], axis=-1)
    max_rot = float(rot.max()) if rot.size else 0.0
    max_trans = float(trans.max()) if trans.size else 0.0
    difference = abs(ours.final_cost - theirs.final_cost) / max(1.0, abs(theirs.final_cost))
    agree = difference <= args.cost_tolerance
    start_cost = float(cost(graph, start))

    ours_row = {
        "start cost": _fmt_cost(start_cost), "final cost": _fmt_cost(ours.final_cost),
        "iterations": str(ours.iterations), "converged": "yes" if ours.converged else "no",
        "seconds read": f"{seconds_read:.4f}", "seconds initialise": f"{t_init.seconds:.4f}",
        "seconds optimise": f"{t_opt.seconds:.4f}",
        "seconds total": f"{seconds_read + t_init.seconds + t_opt.seconds:.4f}",
    }
    theirs_row = {
        "start cost": _fmt_cost(theirs.initial_cost), "final cost": _fmt_cost(theirs.final_cost),
        "iterations": str(theirs.iterations), "converged": "yes" if theirs.converged else "no",
        "seconds read": f"{theirs.seconds_read:.4f}", "seconds initialise": f"{theirs.seconds_initialise:.4f}",
        "seconds optimise": f"{theirs.seconds_optimise:.4f}", "seconds total": f"{theirs.seconds_total:.4f}",
    }
    header = ("", "posegraph", f"gtsam {theirs.version}".strip())
    width = max(len(k) for k in ours_row) + 2
    col = max(14, *(len(v) for v in ours_row.values())) + 2
    print(f"{args.input}: {graph.num_vertices} vertices, {graph.num_edges} edges; {params.method.upper()}, "
          f"start {args.init}" + (" (gtsam from the same poses)" if gtsam_init == "given" else " (each its own)"))
    print(f"{header[0]:<{width}}{header[1]:<{col}}{header[2]}")
    for key in ours_row:
        print(f"{key:<{width}}{ours_row[key]:<{col}}{theirs_row[key]}")
    print(f"final cost relative difference: {difference:.3e} (tolerance {args.cost_tolerance:g}): "
          + ("agree" if agree else "DISAGREE"))
    print(f"largest rotation difference:    {max_rot:.3e} deg")
    print(f"largest translation difference: {max_trans:.3e}")

    if args.report:
        from posegraph.atomic import write_json_atomic

        write_json_atomic(args.report, {
            "input": args.input, "method": params.method, "init": args.init, "gtsam_start": gtsam_init,
            "relative_tolerance": params.relative_tolerance, "absolute_tolerance": params.absolute_tolerance,
            "max_iterations": params.max_iterations,
            "posegraph": {"start_cost": start_cost, "final_cost": ours.final_cost, "iterations": ours.iterations,
                          "converged": ours.converged, "termination": ours.termination,
                          "linear_solver": ours.linear_solver,
                          "seconds": {"read": seconds_read, "initialise": t_init.seconds, "optimise": t_opt.seconds}},
            "gtsam": {"version": theirs.version, "start_cost": theirs.initial_cost, "final_cost": theirs.final_cost,
                      "iterations": theirs.iterations, "converged": theirs.converged,
                      "seconds": {"read": theirs.seconds_read, "initialise": theirs.seconds_initialise,
                                  "optimise": theirs.seconds_optimise}},
            "final_cost_relative_difference": difference, "cost_tolerance": args.cost_tolerance, "agree": agree,
            "max_rotation_difference_deg": max_rot, "max_translation_difference": max_trans,
        })
    return EXIT_OK if agree else EXIT_NOT_CONVERGED


# --------------------------------------------------------------------------------------------
# verify-jacobians


def cmd_verify(args) -> int:
    from posegraph.verify import format_checks, verify_all

    if not args.no_gtsam:
        from posegraph.gtsam_bridge import require_gtsam

        try:
            require_gtsam()
        except ImportError as exc:
            raise ImportError(f"{exc}; or run verify-jacobians --no-gtsam (finite differences only)") from exc
    graph = None
    if args.input:
        graph, _ = _read(args.input, _Status(True), repair_information=args.repair_information)
    checks = verify_all(graph=graph, samples=args.samples, seed=args.seed, use_gtsam=not args.no_gtsam)
    print(format_checks(checks))
    failed = [c for c in checks if not c.passed]
    if failed:
        _warn(f"{len(failed)} of {len(checks)} checks exceed their tolerance: " + ", ".join(c.name for c in failed))
        return EXIT_NOT_CONVERGED
    return EXIT_OK


# --------------------------------------------------------------------------------------------
# info


def cmd_info(args) -> int:
    from posegraph.report import graph_info

    graph, _ = _read(args.input, _Status(True), repair_information=args.repair_information)
    info = graph_info(graph)
    if args.json:
        import json

        print(json.dumps(info, indent=2))
        return EXIT_OK
    rows = [
        ("file", args.input),
        ("vertices", f"{info['num_vertices']} (ids {info['id_min']}..{info['id_max']}, "
                     + ("contiguous" if info["ids_contiguous"] else "not contiguous")
                     + f"), {info['num_fixed']} fixed"),
        ("edges", f"{info['num_edges']}: {info['num_odometry_edges']} odometry (consecutive ids), "
                  f"{info['num_loop_closures']} loop closures"),
        ("components", str(info["num_components"])),
        ("degree", f"min {info['degree_min']}, max {info['degree_max']}, mean {info['degree_mean']:.3f}, "
                   f"median {info['degree_median']:g}"),
    ]
    for part in ("rotation", "translation"):
        r = info["information"][part]
        rows.append((f"information, {part} block",
                     f"diagonal {r['diagonal_min']:.4g} .. {r['diagonal_max']:.4g}, "
                     f"eigenvalues {r['eigenvalue_min']:.4g} .. {r['eigenvalue_max']:.4g}"))
    whole = info["information"]
    rows.append(("information, 6x6", f"eigenvalues {whole['eigenvalue_min']:.4g} .. {whole['eigenvalue_max']:.4g}; "
                                     f"{whole['coupled_edges']} edges couple rotation and translation"))
    rows.append(("initial cost", f"{_fmt_cost(info['initial_cost'])} (at the file's poses)"))
    width = max(len(key) for key, _ in rows) + 2
    for key, value in rows:
        print(f"{key + ':':<{width}}{value}")
    return EXIT_OK


# --------------------------------------------------------------------------------------------
# eval


def cmd_eval(args) -> int:
    from posegraph.evaluate import evaluate, read_trajectory

    estimate_ids, estimate_poses = read_trajectory(args.estimate, repair_information=args.repair_information)
    reference_ids, reference_poses = read_trajectory(args.reference, repair_information=args.repair_information)
    result = evaluate(estimate_ids, estimate_poses, reference_ids, reference_poses,
                      align=not args.no_align, source=args.estimate)
    if result.num_matched < max(result.num_estimate, result.num_reference):
        _warn(f"compared the {result.num_matched} vertex ids present in both files "
              f"({result.num_estimate} in {args.estimate}, {result.num_reference} in {args.reference})")
    if args.json:
        import json

        print(json.dumps(result.as_dict(), indent=2))
        return EXIT_OK
    print(f"estimate:  {args.estimate}")
    print(f"reference: {args.reference}")
    print(f"matched:   {result.num_matched} poses by vertex id; ATE after "
          + ("a least-squares SE(3) alignment (Umeyama, no scale)" if not args.no_align else "no alignment")
          + "; RPE between consecutive ids")
    names = ("rmse", "mean", "median", "std", "min", "max")
    print(f"{'':<22}" + "".join(f"{n:>12}" for n in names))
    rows = (("ATE translation", result.ate_translation), ("ATE rotation (deg)", result.ate_rotation),
            ("RPE translation", result.rpe_translation), ("RPE rotation (deg)", result.rpe_rotation))
    for label, stats in rows:
        print(f"{label:<22}" + "".join(f"{getattr(stats, n):>12.6g}" for n in names))
    return EXIT_OK


# --------------------------------------------------------------------------------------------
# plot


def cmd_plot(args) -> int:
    inputs = [args.input, *args.more]
    _check_output(args.output, inputs=inputs, what="figure")
    if args.labels is not None and len(args.labels) != len(inputs):
        raise _UsageError(f"--labels needs {len(inputs)} names (one per input), got {len(args.labels)}")
    _require_matplotlib()
    from posegraph.plot import plot_trajectories

    status = _Status(True)
    graphs = [_read(path, status, require_edges=False, repair_information=args.repair_information)[0]
              for path in inputs]
    labels = args.labels or [os.path.basename(p) for p in inputs]
    plot_trajectories(args.output, graphs, labels, loop_closures=not args.no_loop_closures, title=args.title)
    return EXIT_OK


# --------------------------------------------------------------------------------------------
# export


def cmd_export(args) -> int:
    if not args.open3d and not args.ply:
        raise _UsageError("nothing to export: give --open3d GRAPH.json and/or --ply LINES.ply")
    for path, what in ((args.open3d, "Open3D pose graph"), (args.ply, "line set")):
        if path:
            _check_output(path, inputs=[args.input], what=what)
    _check_distinct([args.open3d, args.ply])
    from posegraph.export_open3d import require_open3d, write_open3d_pose_graph, write_trajectory_ply

    require_open3d()
    from posegraph.atomic import StagedOutputs

    graph, _ = _read(args.input, _Status(True), require_edges=False, repair_information=args.repair_information)
    with StagedOutputs() as outputs:
        if args.open3d:
            write_open3d_pose_graph(outputs.stage(args.open3d, suffix=".json"), graph)
        if args.ply:
            write_trajectory_ply(outputs.stage(args.ply, suffix=".ply"), graph, loop_closures=args.loop_closures)
        outputs.commit()
    return EXIT_OK


# --------------------------------------------------------------------------------------------
# parser


class _SkippedParser:
    """Stands in for the subcommands a command line does not name (see :func:`build_parser`)."""

    def add_argument(self, *args, **kwargs) -> None:
        pass

    def set_defaults(self, **kwargs) -> None:
        pass


def _subparser(sub, name: str, help: str, description: str, examples: str):
    import textwrap

    if getattr(sub, "only", None) not in (None, name):
        return _SkippedParser()
    return sub.add_parser(
        name, help=help, description=textwrap.fill(description, width=88),
        epilog="examples:\n" + examples.strip("\n") + "\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


COMMANDS = ("optimize", "compare", "verify-jacobians", "info", "eval", "plot", "export")
"""The subcommands, as :func:`build_parser` adds them."""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command-line parser; ``only`` (a subcommand's name) builds that subcommand alone.

    ``main`` passes the subcommand the command line names, if any: the other six would cost ~4 ms
    of argparse set-up on every run for nothing (their options are never parsed). Without a
    known subcommand (``--help``, a typo, nothing) the whole parser is built, so the help and
    the "invalid choice" error list every command.
    """
    parser = _ArgumentParser(
        prog=PROG,
        description="SE(3) pose-graph optimisation over g2o files, cross-checked against gtsam.",
        epilog="""exit status: 0 success, 1 not converged / checks or comparison failed (results still
written), 2 bad input or usage (nothing written), 130 interrupted.

examples:
  posegraph info sphere2500.g2o
  posegraph optimize sphere2500.g2o -o sphere2500-opt.g2o --report report.json --plot before-after.png
  posegraph compare parking-garage.g2o
  posegraph eval sphere2500-opt.g2o ground-truth.g2o
  posegraph <command> --help      (options and examples of one command)
""",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action=_VersionAction, nargs=0, help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="<command>", parser_class=_ArgumentParser)
    sub.required = True
    sub.only = only

    p = _subparser(sub, "optimize", "optimise a g2o pose graph and write the result",
                   "Optimise the vertex poses of a g2o file and write a g2o file with the same edges and FIX lines "
                   "and the optimised vertices. Progress (one line per iteration: cost, decrease, LM lambda, "
                   "seconds) goes to stderr; a summary to stdout. Exit status 1 (result still written) when the "
                   "iteration cap ends the run before convergence.", """
  posegraph optimize tinyGrid3D.g2o -o tiny-opt.g2o
  posegraph optimize sphere2500.g2o -o out.g2o --report report.json --plot before-after.png
  posegraph optimize garage.g2o -o out.g2o --method gn --init odometry --max-iterations 20 --quiet
  posegraph optimize in.g2o -o in.g2o --force      (overwrite the input, atomically)""")
    p.add_argument("input", metavar="IN.g2o", help="input pose graph")
    p.add_argument("-o", "--output", metavar="OUT.g2o", required=True, help="output pose graph")
    _repair_option(p)
    _solver_options(p)
    p.add_argument("--report", metavar="REPORT.json", help="write costs, iterations, timings and per-iteration "
                   "records as JSON")
    p.add_argument("--plot", metavar="FIG.png", help="draw the input and optimised trajectories (needs matplotlib)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but warnings and errors")
    p.add_argument("--force", action="store_true", help="allow OUT to be the input file")
    p.set_defaults(func=cmd_optimize)

    p = _subparser(sub, "compare", "optimise with posegraph and gtsam, side by side",
                   "Run this project's optimiser and gtsam's (same start, same method and tolerances) on one "
                   "graph in one process, and print start and final costs, iterations, seconds per phase and the "
                   "largest rotation and translation difference between the two solutions. Exit status 0 when "
                   f"the final costs agree within --cost-tolerance (relative, default {COMPARE_COST_TOLERANCE:g}), "
                   "1 otherwise. Needs gtsam (pip install \"posegraph[gtsam]\").", """
  posegraph compare tinyGrid3D.g2o
  posegraph compare sphere2500.g2o --method gn --report compare.json
  posegraph compare garage.g2o --init chordal --gtsam-start own    (gtsam's own InitializePose3)""")
    p.add_argument("input", metavar="IN.g2o", help="input pose graph")
    _repair_option(p)
    _solver_options(p)
    p.add_argument("--gtsam-start", choices=("same", "own"), default="same",
                   help="start gtsam from posegraph's initial poses (default), or let it start on its own: "
                        "InitializePose3 for --init chordal, the file's poses for --init file (gtsam has no "
                        "odometry initialiser: --init odometry always shares the start)")
    p.add_argument("--cost-tolerance", type=_non_negative_float, default=COMPARE_COST_TOLERANCE, metavar="TOL",
                   help="largest relative difference of the final costs counted as agreement")
    p.add_argument("--report", metavar="REPORT.json", help="write the comparison as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_compare)

    p = _subparser(sub, "verify-jacobians", "check the Lie-group core and edge Jacobians",
                   "Cross-validate SO(3)/SE(3) Exp, Log, adjoints, Jacobians and the edge-residual Jacobians "
                   "against gtsam and against central finite differences, on random samples, on angles near 0 and "
                   "near pi, and on the edges of IN when given. Prints the largest difference per quantity and "
                   "its tolerance; exit status 1 when any exceeds it.", """
  posegraph verify-jacobians
  posegraph verify-jacobians sphere2500.g2o --samples 2000
  posegraph verify-jacobians --no-gtsam       (finite differences only)""")
    p.add_argument("input", metavar="IN.g2o", nargs="?", help="also check the Jacobians of this graph's edges")
    _repair_option(p)
    p.add_argument("--samples", type=_non_negative_int, default=500, metavar="N",
                   help="random samples per quantity (default 500)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--no-gtsam", action="store_true", help="skip the comparisons with gtsam")
    p.set_defaults(func=cmd_verify)

    p = _subparser(sub, "info", "counts, components, degrees, information ranges, cost",
                   "Describe a g2o pose graph: vertex and edge counts, FIX vertices, connected components, "
                   "degree statistics, odometry edges (consecutive ids) against loop closures, ranges of the "
                   "information matrices, and the cost at the file's poses.", """
  posegraph info parking-garage.g2o
  posegraph info sphere2500.g2o --json""")
    p.add_argument("input", metavar="IN.g2o", help="input pose graph")
    _repair_option(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(func=cmd_info)

    p = _subparser(sub, "eval", "trajectory errors (ATE, RPE) against a reference",
                   "Absolute trajectory error after a least-squares SE(3) alignment (Umeyama/Horn, no scale) "
                   "and relative pose error between consecutive ids, as rmse/mean/median/std/min/max in the way "
                   "evo reports them. Poses are matched by vertex id.", """
  posegraph eval optimised.g2o ground-truth.g2o
  posegraph eval optimised.g2o ground-truth.g2o --json > errors.json""")
    p.add_argument("estimate", metavar="EST.g2o", help="estimated poses")
    p.add_argument("reference", metavar="GT.g2o", help="reference (ground-truth) poses")
    _repair_option(p)
    p.add_argument("--no-align", action="store_true", help="compute ATE without aligning the trajectories")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_eval)

    p = _subparser(sub, "plot", "draw trajectories in 3D (PNG, PDF, SVG)",
                   "Draw each graph's vertex positions joined in id order, its loop-closure edges faintly, "
                   "several files overlaid with a legend. Needs matplotlib (pip install \"posegraph[plot]\").", """
  posegraph plot sphere2500.g2o -o sphere.png
  posegraph plot before.g2o after.g2o -o before-after.png --labels before after""")
    p.add_argument("input", metavar="IN.g2o", help="pose graph to draw")
    p.add_argument("more", metavar="MORE.g2o", nargs="*", help="more graphs overlaid")
    _repair_option(p)
    p.add_argument("-o", "--output", metavar="FIG.png", required=True,
                   help="figure file; its extension picks the format")
    p.add_argument("--labels", nargs="+", metavar="NAME", help="legend names, one per input (default file names)")
    p.add_argument("--title", help="figure title")
    p.add_argument("--no-loop-closures", action="store_true", help="draw the trajectories only")
    p.set_defaults(func=cmd_plot)

    p = _subparser(sub, "export", "write an Open3D PoseGraph JSON and/or a PLY line set",
                   "Export through Open3D: --open3d writes an open3d.pipelines.registration.PoseGraph "
                   "(read it with open3d.io.read_pose_graph; node k is the k-th vertex of the file, an edge i->j "
                   "becomes source j, target i, transformation Z_ij), --ply the trajectory as a line set. Needs "
                   "Open3D (pip install open3d; on Debian also apt install libusb-1.0-0).", """
  posegraph export optimised.g2o --open3d graph.json
  posegraph export optimised.g2o --ply trajectory.ply --loop-closures""")
    p.add_argument("input", metavar="IN.g2o", help="pose graph to export")
    _repair_option(p)
    p.add_argument("--open3d", metavar="GRAPH.json", help="Open3D pose-graph JSON to write")
    p.add_argument("--ply", metavar="LINES.ply", help="PLY line set of the trajectory to write")
    p.add_argument("--loop-closures", action="store_true", help="also put loop-closure edges in the PLY")
    p.set_defaults(func=cmd_export)
    return parser


def _version() -> str:
    try:
        from posegraph import __version__  # the package's __init__ imports nothing heavy

        return __version__
    except ImportError:  # e.g. a stale editable install that maps posegraph as a namespace package
        from importlib.metadata import version

        return version("posegraph")


class _VersionAction(argparse.Action):
    """``--version``, looked up only when asked for (keeps ``--help`` free of metadata imports)."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{PROG} {_version()}")
        parser.exit()


# --------------------------------------------------------------------------------------------
# entry point


def main(argv=None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``) and return the exit status."""
    printer = _WarningPrinter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = printer
            try:
                argv = sys.argv[1:] if argv is None else list(argv)
                named = argv[0] if argv and argv[0] in COMMANDS else None
                args = build_parser(only=named).parse_args(argv)
                return args.func(args)
            finally:
                printer.finish()
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted; nothing written", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    except _UsageError as exc:
        _error(str(exc))
        return EXIT_USAGE
    except SystemExit as exc:  # --help and --version
        return exc.code if isinstance(exc.code, int) else 0
    except ImportError as exc:
        # An optional dependency is missing: say so in one line (our messages include how to install
        # it). Any other ImportError is a bug of ours and keeps its traceback.
        if exc.name not in OPTIONAL_MODULES and "pip install" not in str(exc):
            raise
        _error(" ".join(str(exc).split()))
        return EXIT_USAGE
    except BrokenPipeError:  # pragma: no cover - e.g. `posegraph info x.g2o | head -1`
        sys.stderr.close()
        return EXIT_NOT_CONVERGED
    except OSError as exc:
        where = exc.filename if exc.filename is not None else ""
        _error(f"{where}: {exc.strerror or exc}" if where else str(exc))
        return EXIT_USAGE
    except ValueError as exc:
        from posegraph.errors import InputError

        if isinstance(exc, InputError):
            _error(" ".join(str(exc).split()))
            return EXIT_USAGE
        raise


if __name__ == "__main__":
    sys.exit(main())
