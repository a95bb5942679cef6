"""What the subcommands share: messages, progress lines, output checks, reading, option types.

Only the standard library is imported here; the project's modules are imported inside the
functions that use them (see :mod:`posegraph.cli`).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

PROG = "posegraph"

EXIT_OK = 0
EXIT_NOT_CONVERGED = 1
EXIT_USAGE = 2
EXIT_BUG = 3
EXIT_INTERRUPTED = 130


def interrupted_status(exc: BaseException) -> int:
    """The exit status of a run stopped by ``exc``: 128 + the signal, as a shell shows a process a
    signal ended (130 for Ctrl-C's ``KeyboardInterrupt``; SIGTERM's :class:`~posegraph.errors.Interrupted` 143)."""
    import signal

    return 128 + getattr(exc, "signum", signal.SIGINT)


def interrupted_message(exc: BaseException) -> str:
    """``interrupted`` (``by SIGTERM``…), then exactly what this run has delivered
    (:func:`posegraph.io.atomic.committed_outputs`): "nothing written", or the outputs complete on
    disk when the signal came after their renames (which it never splits)."""
    import signal

    from posegraph.io.atomic import committed_outputs

    number = getattr(exc, "signum", signal.SIGINT)
    said = "interrupted" if number == signal.SIGINT else f"interrupted by {signal.Signals(number).name}"
    written = committed_outputs()
    if not written:
        return f"{said}; nothing written"
    return f"{said}; written, complete: {', '.join(written)}; nothing else written"


STDIO = "-"
"""A file argument naming standard input (where a graph is read) or standard output (where one is written)."""

CLOSED_STREAMS: set = set()
"""The standard streams (``"stdin"``, ``"stdout"``, ``"stderr"``) that were closed when the command
started (:func:`posegraph.cli.startup.reopen_closed_streams`): what goes there is discarded, and ``-``
cannot name them."""

LARGE_GRAPH_POSES = 10_000
"""Graphs above this many poses get a line as each slow phase (reading, initialising) starts."""
LARGE_FILE_BYTES = 4_000_000
"""Files above this size get a line before reading: about :data:`LARGE_GRAPH_POSES` poses (the
standard files hold ~440 bytes per pose: sphere2500 is 1.09 MB for 2,500 poses)."""

OPTIONAL_MODULES = frozenset({"gtsam", "open3d", "matplotlib", "mpl_toolkits"})
"""Packages some commands or options need; their absence is a usage error, not a crash."""

MAX_WARNINGS_SHOWN = 20
"""Warnings beyond this many are counted, not printed (a file can repeat one repair per line)."""


# --------------------------------------------------------------------------------------------
# messages


class UsageError(Exception):
    """A command-line mistake found after parsing (e.g. conflicting outputs)."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line and lets main() choose the exit status."""

    def error(self, message):
        raise UsageError(f"{message} (see '{self.prog} --help')")

    def parse_args(self, args=None, namespace=None):
        """argparse's, but arguments left over after a subcommand point at that subcommand's help:
        argparse reports them from the top-level parser, whose help lists no subcommand's options."""
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            command = getattr(namespace, "command", None)
            where = f"{self.prog} {command}" if command else self.prog
            raise UsageError(f"unrecognized arguments: {' '.join(extras)} (see '{where} --help')")
        return namespace


def error(message: str) -> None:
    print(f"{PROG}: error: {message}", file=sys.stderr, flush=True)


def warn(message: str) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr, flush=True)


class WarningPrinter:
    """``warnings.showwarning`` replacement: one line per warning, without source lines."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self, message, category, filename, lineno, file=None, line=None):
        self.count += 1
        if self.count <= MAX_WARNINGS_SHOWN:
            text = " ".join(str(message).split())
            if not _is_ours(category):
                text = f"{category.__name__}: {text}"
            warn(text)

    def finish(self) -> None:
        if self.count > MAX_WARNINGS_SHOWN:
            warn(f"{self.count - MAX_WARNINGS_SHOWN} more warnings not shown")


def _is_ours(category) -> bool:
    from posegraph.errors import PosegraphWarning

    return issubclass(category, PosegraphWarning)


class Status:
    """Progress and phase lines on stderr, silenced by ``--quiet``."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet

    def __call__(self, message: str) -> None:
        if not self.quiet:
            print(message, file=sys.stderr, flush=True)


TICKER_DELAY = 1.0
"""Seconds a phase runs before :class:`Ticker` shows its elapsed time."""


class Ticker:
    """While a long phase runs, an elapsed-time line on an interactive stderr (redrawn in place).

    Reading, initialising and writing report no fraction done, so the line shows the phase and its
    seconds so far; it appears only after :data:`TICKER_DELAY` seconds and only on a terminal, so
    quick runs, pipes and log files see just the final phase line.
    """

    def __init__(self, status: Status, label: str) -> None:
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


class Timer:
    """``with Timer() as t:`` … then ``t.seconds``, the block's wall-clock time."""

    def __enter__(self):
        self.start = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.start


def fmt_cost(x: float) -> str:
    return f"{x:.12g}"


# --------------------------------------------------------------------------------------------
# paths and inputs


def check_output(
    path: str, *, inputs=(), allow_input: bool = False, what: str = "output", stdout: bool = False
) -> None:
    """Fail before any work if ``path`` cannot be written as asked; ``-`` is standard output where
    the command can write this output there (``stdout``), else a usage error.

    The path is judged as :func:`posegraph.io.atomic.output_target` will deliver it: a folder, a
    dangling link, a block device or a socket is refused; a device or FIFO must be writable; a
    file (or a link's target) must be creatable in its folder and not be an input.
    """
    from posegraph.io.atomic import output_target
    from posegraph.errors import OutputError

    if path == STDIO:
        if stdout and "stdout" in CLOSED_STREAMS:
            raise UsageError(f"the {what} cannot go to standard output (-): it is closed; give a file name")
        if stdout:
            return
        raise UsageError(f"the {what} cannot go to standard output (-): give a file name")
    try:
        target = output_target(path)
    except OutputError as exc:
        raise OutputError(exc.reason.replace("the file", f"the {what}", 1), path=path) from None
    if target.kind == "node":  # written into, never replaced: it cannot clobber an input
        if not os.access(target.path, os.W_OK):
            raise OutputError(f"cannot write the {what}: permission denied", path=path)
        return
    folder = os.path.dirname(os.path.abspath(target.path))
    if not os.path.isdir(folder):
        raise OutputError(f"cannot write the {what}: folder {folder} does not exist", path=path)
    reason = _cannot_create_in(folder)
    if reason:
        raise OutputError(f"cannot write the {what}: no file can be created in folder {folder} ({reason})", path=path)
    for source in inputs:
        if source != STDIO and _same_file(path, source) and not allow_input:
            hint = " (pass --force to overwrite it)" if what == "result" else ""
            raise OutputError(f"the {what} would overwrite the input {source}{hint}", path=path)


def _cannot_create_in(folder: str) -> str:
    """Why no file can be created in ``folder`` ("" if one can): a real attempt, as the writers will
    make (``os.access`` says yes to root on read-only file systems and on ``/proc``)."""
    from posegraph.io.atomic import create_new_file

    try:
        probe = create_new_file(folder, ".posegraph-probe-")
    except OSError as exc:
        return exc.strerror or str(exc)
    os.unlink(probe)
    return ""


def check_figure(path: str, inputs=()) -> None:
    """Fail before any work if the figure ``path`` cannot be drawn: matplotlib missing, a format it
    does not write (the extension picks it; none means PNG), or an unwritable path."""
    from posegraph.errors import OutputError

    check_output(path, inputs=inputs, what="figure")
    require_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    formats = FigureCanvasAgg.get_supported_filetypes()
    extension = os.path.splitext(path)[1].lstrip(".").lower()
    if extension and extension not in formats:
        raise OutputError(f"cannot draw a figure in format {extension!r}; matplotlib writes "
                          + ", ".join(sorted(formats)), path=path)


def check_inputs(paths) -> None:
    """A :class:`UsageError` if standard input (``-``) is named more than once, or is closed."""
    if sum(path == STDIO for path in paths) > 1:
        raise UsageError("standard input (-) can be read only once")
    for path in paths:
        check_stdin(path)


def check_stdin(path: str) -> None:
    """A :class:`UsageError` if ``path`` is ``-`` and standard input was closed (an empty graph would follow)."""
    if path == STDIO and "stdin" in CLOSED_STREAMS:
        raise UsageError("standard input (-) is closed: give a file name")


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def check_distinct(paths) -> None:
    """A :class:`UsageError` if two of the given (non-empty) output paths are the same file.
    Devices and FIFOs may be named twice (``-o /dev/null --report /dev/null``): each output is
    written into them whole, one after the other, and none replaces another."""
    paths = [p for p in paths if p and not _is_node(p)]
    for k, a in enumerate(paths):
        for b in paths[k + 1 :]:
            if _same_file(a, b):
                raise UsageError(f"two outputs are the same file: {a} and {b}")


def _is_node(path: str) -> bool:
    """Whether ``path`` leads to a character device or a FIFO."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)


def read_graph(path: str, status: Status, *, require_edges: bool = True, repair_information: bool = False,
               uses_file_poses: bool = True, **options):
    """``(graph, seconds)``: :func:`posegraph.io.g2o.read_g2o` with a phase line on ``status``
    (``options``: further reader options, :func:`reader_options`). ``uses_file_poses=False``: the
    command starts from poses of its own (``--init chordal``, certify's candidate), so the warning that
    a file without vertex lines has its vertices at the identity (:class:`~posegraph.errors.MissingPosesWarning`)
    would be noise, and is not shown."""
    import warnings

    from posegraph.errors import MissingPosesWarning
    from posegraph.io.g2o import read_g2o

    check_stdin(path)
    size = os.path.getsize(path) if path != STDIO and os.path.isfile(path) else 0
    if size > LARGE_FILE_BYTES:
        status(f"reading {path} ({size / 1e6:.1f} MB) …")
    with Ticker(status, f"reading {path}"), Timer() as t, warnings.catch_warnings():
        if not uses_file_poses:
            warnings.simplefilter("ignore", MissingPosesWarning)
        graph = read_g2o(path, require_edges=require_edges, repair_information=repair_information, **options)
    status(f"read {display_name(path)}: {graph_size(graph)} ({t.seconds:.3f} s)")
    from posegraph.cli import startup

    if graph.num_edges >= startup.LARGE_GRAPH_EDGES:
        startup.return_freed_memory()  # (read_g2o has just trimmed the heap: what is free is given back)
    return graph, t.seconds


def stage_or_print(outputs, path: str, text: str, printed: list) -> None:
    """``text`` staged for ``path`` in ``outputs`` (:class:`posegraph.io.atomic.StagedOutputs`), or, for
    ``-``, kept in ``printed`` to go to standard output once the files are committed (:func:`print_all`)."""
    if path == STDIO:
        printed.append(text)
    else:
        outputs.write_text(path, text)


def print_all(printed: list) -> None:
    """The texts :func:`stage_or_print` kept, on standard output."""
    for text in printed:
        sys.stdout.write(text)
    sys.stdout.flush()


def graph_size(graph) -> str:
    """``"6969 vertices, 6968 edges"``, and ``", 151 landmarks, 3640 landmark measurements"`` when it has them."""
    text = f"{graph.num_vertices} vertices, {graph.num_edges} edges"
    if graph.landmarks is not None:
        text += f", {graph.landmarks.count} landmarks, {graph.landmarks.num_measurements} landmark measurements"
    return text


def display_name(path: str) -> str:
    """``path`` as messages show it (``<stdin>`` / ``<stdout>`` for ``-``)."""
    return "<stdin>" if path == STDIO else path


def require_matplotlib() -> None:
    from posegraph.analysis.plot import require_matplotlib

    require_matplotlib()


# --------------------------------------------------------------------------------------------
# options


QUIET_HELP = ("no progress lines and no summary: print only warnings, errors and the output the command is for "
              "(the tables of info, eval, compare and verify-jacobians; the results written with -o, --report)")


def quiet_option(p) -> None:
    """``-q``/``--quiet``, which every subcommand takes (:func:`posegraph.cli.parser.build_parser` adds it
    to those whose own options do not; ``optimize`` and ``batch`` have it among the per-file options)."""
    p.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)


def repair_option(p: argparse.ArgumentParser) -> None:
    """``--repair-information``, which every subcommand reading a graph takes."""
    p.add_argument("--repair-information", action="store_true",
                   help="replace each information matrix that is not positive semi-definite by the nearest one "
                        "(Frobenius norm; eigenvalues clipped to 1e-9 times the largest), with one warning, "
                        "instead of refusing the file")
    p.add_argument("--edge2-information", choices=("auto", "g2o", "toro"), default="auto",
                   help="the order of the 6 information entries of TORO's EDGE2 lines: auto (default) tells it per "
                        "file (the order in which every line gives a positive semi-definite matrix; a file where "
                        "both do and differ is refused), toro (xx xy yy tt xt yt) or g2o (xx xy xt yy yt tt)")
    p.add_argument("--poses-only", action="store_true",
                   help="skip the landmark lines (VERTEX_XY, EDGE_SE2_XY, EDGE_SE3_TRACKXYZ, BR, LANDMARK...), which are "
                        "read otherwise, with one warning: the poses alone are read")
    p.add_argument("--isam-information", choices=("sqrt", "information", "covariance"), default="sqrt",
                   help="what the noise entries of iSAM's ODOMETRY, LANDMARK and POINT3 lines are: sqrt (default, "
                        "iSAM's upper-triangular square-root information), information (as gtsam's readG2o reads "
                        "ODOMETRY) or covariance (gtsam's victoria_park.txt)")


def reader_options(args) -> dict:
    """The reader options of :func:`repair_option`'s arguments but ``--repair-information``, for :func:`read_graph`."""
    return {"edge2_information": getattr(args, "edge2_information", "auto"), "poses_only": getattr(args, "poses_only", False),
            "isam_information": getattr(args, "isam_information", "sqrt")}


INT_OPTION_MAX = 2**63 - 1
"""The largest integer an option takes: ids and counts go to numpy's int64 and C longs, where a larger
one would end in an OverflowError deep inside the work instead of a usage error here."""


def non_negative_int(text: str) -> int:
    """An option's integer ``0 ≤ value ≤`` :data:`INT_OPTION_MAX`, else argparse's usage error naming it."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0: {text}")
    if value > INT_OPTION_MAX:
        shown = text if len(text) <= 30 else f"{text[:12]}…({len(text)} digits)"
        raise argparse.ArgumentTypeError(f"too large: {shown} (at most 2^63 - 1 = {INT_OPTION_MAX})")
    return value


def positive_int(text: str) -> int:
    value = non_negative_int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1: {text}")
    return value


def _number(text: str) -> float:
    """``float(text)``, or the argparse error "not a number"."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = _number(text)
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0: {text}")
    return value


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    value = _number(text)
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0: {text}")
    return value


def unit_fraction(text: str) -> float:
    """argparse type: a number in [0, 1]."""
    value = _number(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1], got {text}")
    return value
