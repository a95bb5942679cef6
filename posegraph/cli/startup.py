"""Process tuning for the command-line program: lean imports, one BLAS thread, malloc reuse, frozen imports.

Process-wide settings, so done by the command-line program only, never by the library; each
function's docstring gives what it saves, measured.
"""

from __future__ import annotations

import gc
import os
import sys

_UNUSED_NUMPY_SUBMODULES = frozenset({"f2py", "testing", "ma", "polynomial", "ctypeslib", "rec", "char", "strings", "core", "test"})
"""Lazily loaded numpy submodules nothing on the optimise path uses (see :func:`import_scipy_sparse`)."""


def import_scipy_sparse() -> None:
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
"""glibc ``mallopt`` settings of :func:`keep_freed_memory`: M_MMAP_THRESHOLD (−3) 32 MiB,
M_TRIM_THRESHOLD (−1) 256 MiB, M_TOP_PAD (−2) 64 MiB."""

_KEPT = [False]
"""Whether :func:`keep_freed_memory` applied its settings (and :func:`return_freed_memory` has not undone them)."""

_MALLOC_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "GLIBC_TUNABLES")


def keep_freed_memory() -> bool:
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
        _KEPT[0] = _mallopt(_MALLOC_SETTINGS)
        return _KEPT[0]
    except (OSError, AttributeError):
        return False


_LEAN_MALLOC_SETTINGS = {-1: 128 * 2**10, -2: 0}
"""glibc ``mallopt`` settings of :func:`return_freed_memory`: M_TRIM_THRESHOLD (−1) back to 128 kB
(freed memory at the heap's top returned), M_TOP_PAD (−2) 0; blocks below 32 MiB stay in the heap."""

LARGE_GRAPH_EDGES = 100_000
"""From this many edges the command-line program trades :func:`keep_freed_memory`'s reuse for memory
(:func:`return_freed_memory`): a few MB of arrays reused matter on small graphs, hundreds of MiB
kept back on large ones."""


def return_freed_memory() -> bool:
    """Undo the retention part of :func:`keep_freed_memory` for a large graph: freed memory at the
    heap's top is given back, so that what a phase frees does not stay resident in later, larger
    phases. On the 200,000-pose sphere with ``--linear-solver pcg`` the peak varied between 2.81
    and 3.00 GiB from run to run with up to 256 MiB kept, 2.77–2.79 GiB in four runs without (for
    75 s a run against 81–88 s). Applied only where :func:`keep_freed_memory` was; returns whether it was."""
    if not _KEPT[0]:
        return False
    done = _mallopt(_LEAN_MALLOC_SETTINGS)
    _KEPT[0] = not done
    return done


def _mallopt(settings: dict) -> bool:
    """glibc's ``mallopt(key, value)`` for each setting; whether every one was taken."""
    import ctypes

    libc = ctypes.CDLL(None)
    return all(libc.mallopt(ctypes.c_int(key), ctypes.c_int(value)) == 1 for key, value in settings.items())


def single_threaded_blas() -> None:
    """Make OpenBLAS start with one thread in this process, unless ``OPENBLAS_NUM_THREADS`` is set.

    Must run before numpy is imported (OpenBLAS reads the variable when it loads). A threaded
    OpenBLAS — numpy's bundled one, and cvxopt's under CHOLMOD where its wheel bundles a threaded
    build — otherwise starts a worker thread per core at load, which busy-waits for work while the
    main thread goes on importing: on the 2-core machine here ``import numpy`` took 0.14 s against
    0.09 s with one thread, and a whole ``posegraph optimize`` ~30 ms longer. Nothing on this path
    wants more: numpy only multiplies small matrices, and the solver runs CHOLMOD's BLAS on one
    thread anyway (``SolverParams.blas_threads``), which with the variable set needs no
    threadpoolctl (:class:`posegraph.linalg.native_threads.NativeThreads`).
    """
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def import_solver_modules() -> None:
    """Import what the read / initialise / optimise phases use, so that their timings are work,
    not first-use imports. Only those: scipy.sparse.linalg (SuperLU) and scipy.sparse.csgraph
    (odometry start) import on first use, as they are needed only off the default path. With
    CHOLMOD from cvxopt (:mod:`posegraph.linalg.cholmod`, ~10 ms to import) that path needs no scipy at
    all (~0.14 s less per run); without cvxopt, SuperLU's route needs ``scipy.sparse``, imported
    here by :func:`import_scipy_sparse`."""
    single_threaded_blas()
    keep_freed_memory()
    # These imports make ~30,000 objects that live as long as the process. While they are made,
    # the collector would traverse them again and again for nothing (some 50 young and 4 older
    # collections): ~5 ms of every `posegraph optimize` (intel, parking-garage; 16 alternated
    # processes each), so it is off meanwhile. Then they are frozen (moved out of the collector's
    # generations): no longer traversed by every full collection, nor collected one by one when
    # the interpreter shuts down (that teardown took ~30 ms of every `posegraph optimize` on
    # torus3D, ~12 ms frozen). Objects made later are collected as usual.
    enabled = gc.isenabled()
    gc.disable()
    try:
        _import_solver_modules()
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def _import_solver_modules() -> None:
    from posegraph.linalg import cholmod

    if cholmod.load() is None:
        import_scipy_sparse()

    import posegraph.init  # noqa: F401
    import posegraph.io.g2o  # noqa: F401
    import posegraph.solve  # noqa: F401


STOP_SIGNALS = ("SIGTERM", "SIGHUP")
"""Signals that ask the process to stop, handled as Ctrl-C is (:func:`stop_signals_interrupt`)."""


class stop_signals_interrupt:
    """While in the block, SIGTERM and SIGHUP raise :class:`~posegraph.errors.Interrupted` as
    Ctrl-C raises ``KeyboardInterrupt``.

    Their default action ends the process at once, leaving the temporary files of the outputs
    being written (even complete ones) and, between two renames, a new result beside an old
    report; raised as an exception, they unwind as Ctrl-C does: temporary files deleted, renames
    held back until the last one (:class:`posegraph.io.atomic.StagedOutputs`), exit status 128 +
    the signal. Only signals at their default action are taken: one ignored (``nohup`` ignores
    SIGHUP) stays ignored, a handler an embedding program set stays its own. Only in the main
    thread, where Python handles signals; the previous handlers are back after the block.
    """

    def __init__(self) -> None:
        self._previous: dict = {}

    def __enter__(self) -> "stop_signals_interrupt":
        import signal
        import threading

        if threading.current_thread() is not threading.main_thread():
            return self
        for name in STOP_SIGNALS:
            number = getattr(signal, name, None)
            if number is not None and signal.getsignal(number) == signal.SIG_DFL:
                self._previous[number] = signal.signal(number, raise_interrupted)
        return self

    def __exit__(self, *exc) -> bool:
        import signal

        for number, handler in self._previous.items():
            signal.signal(number, handler)
        self._previous = {}
        return False


def raise_interrupted(signum: int, frame) -> None:
    """The handler :class:`stop_signals_interrupt` sets: raise :class:`~posegraph.errors.Interrupted`."""
    from posegraph.errors import Interrupted

    raise Interrupted(signum)


STANDARD_STREAMS = ("stdin", "stdout", "stderr")
"""The standard streams, in the order of their file descriptors 0, 1, 2."""


def reopen_closed_streams() -> tuple[str, ...]:
    """Give each closed standard stream the null device; the names of those that were closed.

    A daemon or a cron job may start the command with descriptor 0, 1 or 2 closed (``<&-``,
    ``>&-``, ``2>&-``); Python then sets ``sys.stdin``/``sys.stdout``/``sys.stderr`` to None, and
    every message or progress line would fail. Each closed descriptor is opened on ``os.devnull``
    first — the first files the command opens would otherwise take its number, and whatever a
    library writes to "standard error" would land in them — and each stream that is None becomes a
    text file on the null device of its own (never on descriptors 0–2: one may have been taken by a
    file before this runs), so that what goes there is discarded and the work goes on.
    """
    closed = []
    for fd, name in enumerate(STANDARD_STREAMS):
        if _descriptor_open(fd) and getattr(sys, name) is not None:
            continue
        if not _descriptor_open(fd):
            null = os.open(os.devnull, os.O_RDONLY if fd == 0 else os.O_WRONLY)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, "r" if fd == 0 else "w", encoding="utf-8"))
        closed.append(name)
    return tuple(closed)


def _descriptor_open(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True
