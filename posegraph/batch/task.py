"""One file of a batch, on a Dask worker: ``posegraph optimize`` run in the worker's process.

The worker calls the command line's own entry point (:func:`posegraph.cli.program.main`) with
``optimize IN -o OUT --report R [options]``, so each file goes through exactly the code a
``posegraph optimize`` process runs — its checks, messages, exit statuses and atomic writes — and
its result is byte for byte the one that command writes. What it prints goes to ``NAME.log``
instead of the terminal; its exit status and report become the file's row of the summary.

The command line tunes process-wide state (warning filters, standard streams, the collector),
so a worker process optimises one file at a time (:data:`_ONE_AT_A_TIME`): a worker with several
threads runs its files in turn. Dask's local workers are started with one thread each.
"""

from __future__ import annotations

import threading
import time

from posegraph.batch.files import FileJob, exit_line

__all__ = ["optimize_file"]

_ONE_AT_A_TIME = threading.Lock()
"""Held while a file runs: the command line's streams and warning filters are the process's."""


def optimize_file(job: FileJob) -> dict:
    """Run ``job`` as ``posegraph optimize`` in this process, write its log; its summary row
    (:func:`posegraph.batch.rows.file_row`)."""
    from posegraph.io.atomic import write_text_atomic
    from posegraph.batch.rows import file_row

    from posegraph.cli.startup import import_solver_modules

    with _ONE_AT_A_TIME:
        import_solver_modules()  # once per worker: a file's seconds are its own work, as in its report
        start = time.perf_counter()
        printed, status = _run_captured(job.argv)
        seconds = time.perf_counter() - start
    write_text_atomic(job.log, f"{job.command}\n{printed}{exit_line(status)}\n")
    return file_row(job, status, printed, seconds)


def _run_captured(argv: list) -> tuple[str, int]:
    """``(what it printed on stdout and stderr, interleaved; exit status)`` of ``posegraph ARGV``.

    The BLAS under CHOLMOD runs one thread (:class:`~posegraph.linalg.native_threads.NativeThreads`), as
    in a ``posegraph optimize`` process: the worker processes share the machine's cores.
    """
    import contextlib
    import gc
    import io

    from posegraph.cli.program import main
    from posegraph.cli.startup import import_solver_modules
    from posegraph.linalg.native_threads import NativeThreads

    # The previous file's reference cycles go before import_solver_modules freezes what is alive.
    gc.collect()
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
        import_solver_modules()  # what `optimize` imports first; NativeThreads needs cvxopt loaded
        with NativeThreads(1):
            status = main(argv)
    return printed.getvalue(), status
