""":func:`optimize_many`: ``posegraph optimize`` over many files on a Dask cluster, one summary row per file."""

from __future__ import annotations

import os

__all__ = ["optimize_many", "SUMMARY_NAME"]

SUMMARY_NAME = "summary.json"
"""The summary's name in OUT_DIR when no other path is given (and ``summary.csv`` beside it)."""


def optimize_many(paths, out_dir, *, client=None, scheduler=None, workers=None, force=False, report=None,
                  plot=False, covariances=False, progress=None, **options) -> list[dict]:
    """Optimise each g2o file of ``paths`` as ``posegraph optimize`` does, in parallel on Dask.

    Each file runs as ``posegraph optimize IN -o OUT_DIR/NAME.g2o --report OUT_DIR/NAME.report.json
    [options]`` in a worker process (:mod:`posegraph.batch.task`), so its result is byte for byte
    that command's; what it prints goes to ``OUT_DIR/NAME.log`` (:mod:`posegraph.batch.files`).
    ``options`` are ``optimize``'s per-file options by their Python names (``method="gn"``,
    ``max_iterations=20``, ``robust="gnc"``, ``fix=[0, 5]``, ``repair_information=True`` …:
    :func:`posegraph.batch.options.file_option_defaults`); ``plot``/``covariances`` add
    ``NAME.png``/``NAME.cov.npz``.

    Cluster: ``client`` (a ``distributed.Client``) if given, else the scheduler at ``scheduler``
    (``"tcp://host:port"``; its workers must import posegraph and see the same paths), else a local
    cluster of ``workers`` processes (default one per core, at most one per file) made and closed here.
    A file whose outputs an earlier run completed after the input last changed, with the same
    options, is skipped unless ``force``. The summary goes to ``report`` (default
    ``OUT_DIR/summary.json``) and a CSV beside it. ``progress(row, counts)`` is called once before
    any file finishes (``row`` None) and after each; ``counts``: ``done, failed, running, waiting,
    total``.

    Returns the rows in the order of ``paths`` (:data:`posegraph.batch.rows.ROW_FIELDS`): a file that
    fails is a row with status ``failed`` and ``optimize``'s one-line reason, never an exception.
    Raises :class:`~posegraph.batch.options.BatchError` (nothing run) for options ``optimize``
    refuses, inputs that would share or overwrite outputs, an unreachable scheduler, more than one
    of ``client``, ``scheduler``, ``workers``;
    :class:`TypeError` for an unknown option; :class:`ImportError` without ``dask.distributed``.
    """
    from posegraph.batch.files import outputs_complete
    from posegraph.batch.rows import skipped_row, write_summary

    if sum(x is not None for x in (client, scheduler, workers)) > 1:
        from posegraph.batch.options import BatchError

        raise BatchError("give at most one of client, scheduler and workers")
    report = os.path.join(out_dir, SUMMARY_NAME) if report is None else os.fspath(report)
    jobs = _plan(paths, out_dir, options, plot, covariances, report)
    rows = [None if force or not outputs_complete(job) else skipped_row(job) for job in jobs]
    todo = [k for k, row in enumerate(rows) if row is None]
    progress = progress or (lambda row, counts: None)
    if todo:
        with _interrupt_deferred() as interrupted, _client(client, scheduler, workers, len(todo)) as running:
            _make_out_dir(out_dir, report)  # only now that the cluster answers: a refusal leaves nothing behind
            _run_jobs(running, jobs, todo, rows, progress, interrupted)
    else:
        progress(None, _counts(rows, 0, 0))
    write_summary(rows, report)
    return rows


def _plan(paths, out_dir, options: dict, plot: bool, covariances: bool, report: str) -> list:
    """The jobs, after every check that can fail before work: options, names, OUT_DIR (that it is or
    can be made a folder one can write in; made later, by :func:`_make_out_dir`), the summary's path."""
    from posegraph.batch.files import plan_jobs
    from posegraph.batch.options import BatchError, check_options, option_argv
    from posegraph.batch.rows import summary_paths
    from posegraph.cli.common import check_output

    paths = [os.fspath(p) for p in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
    if not paths:
        raise BatchError("no input files")
    if "-" in paths:
        raise BatchError("a batch reads files, not standard input (-)")
    argv = option_argv(options)
    jobs = plan_jobs(paths, out_dir, argv, plot=plot, covariances=covariances)
    check_options(argv, jobs[0].input, jobs[0].output)
    if plot:  # once here, rather than one failed row per file
        from posegraph.analysis.plot import require_matplotlib

        require_matplotlib()
    _check_out_dir(out_dir)
    taken = {os.path.realpath(p) for job in jobs for p in (job.input, *job.outputs)}
    for summary in summary_paths(report):
        if not _made_with(summary, out_dir):  # else checked once OUT_DIR is made (_make_out_dir)
            check_output(summary, what="summary")
        if os.path.realpath(summary) in taken:
            raise BatchError(f"the summary {summary} would be an input or a file's output: choose another --report")
    return jobs


def _check_out_dir(out_dir: str) -> None:
    """A :class:`BatchError` (or :class:`~posegraph.errors.OutputError`) unless OUT_DIR is a folder one
    can write in, or can be made: its nearest existing ancestor a folder one can create in. Nothing is
    left behind (the check creates a probe file and removes it)."""
    from posegraph.batch.options import BatchError
    from posegraph.cli.common import check_output

    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise BatchError(f"the output folder {out_dir} is a file")
    existing = os.path.abspath(out_dir)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise BatchError(f"cannot make the output folder {out_dir}: {existing} is a file")
    check_output(os.path.join(existing, ".posegraph-out-dir"), what="outputs")


def _made_with(path: str, out_dir: str) -> bool:
    """Whether ``path`` lies in OUT_DIR and OUT_DIR does not exist yet (it is made once the cluster answers)."""
    folder = os.path.dirname(os.path.abspath(path))
    return folder == os.path.abspath(out_dir) and not os.path.isdir(folder)


def _make_out_dir(out_dir: str, report: str) -> None:
    """Make OUT_DIR, then check the summary's path as :func:`_plan` did when its folder existed."""
    from posegraph.batch.rows import summary_paths
    from posegraph.cli.common import check_output

    os.makedirs(out_dir, exist_ok=True)
    for summary in summary_paths(report):
        check_output(summary, what="summary")


def _client(client, scheduler, workers, files: int):
    from posegraph.batch.cluster import batch_client, default_workers

    return batch_client(client=client, scheduler=scheduler, workers=min(workers or default_workers(), files))


POLL_SECONDS = 0.05
"""How often the wait for the next finished file looks for it, and for a Ctrl-C (:func:`_interrupt_deferred`)."""


class _interrupt_deferred:
    """Ctrl-C while a cluster runs sets ``self.is_set`` instead of raising anywhere inside Dask (whose
    event loop logs tracebacks, or drops the KeyboardInterrupt, when it lands in its callbacks);
    :func:`_run_jobs` looks at it between waits and raises KeyboardInterrupt there, and leaving the
    block raises it if it came later (while the cluster closed). SIGTERM and SIGHUP, where the
    command line raises them as interrupts (:class:`posegraph.cli.startup.stop_signals_interrupt`),
    are deferred the same way and raised as :class:`~posegraph.errors.Interrupted`. Outside the
    main thread, where no signal handler can be set, Ctrl-C raises where it lands, as by default."""

    def __init__(self):
        self.is_set = False
        self.signum = None
        self._previous = {}

    def __enter__(self):
        import signal
        import threading

        from posegraph.cli.startup import STOP_SIGNALS, raise_interrupted

        if threading.current_thread() is not threading.main_thread():
            return self
        raising = {signal.SIGINT: signal.default_int_handler}
        raising.update({getattr(signal, name): raise_interrupted for name in STOP_SIGNALS if hasattr(signal, name)})
        for number, handler in raising.items():
            if signal.getsignal(number) is handler:
                self._previous[number] = signal.signal(number, self._note)
        return self

    def _note(self, signum, frame) -> None:
        self.is_set = True
        self.signum = signum

    def interrupt(self):
        """The exception the signal received stands for: KeyboardInterrupt, or Interrupted(signum)."""
        import signal

        from posegraph.errors import Interrupted

        return KeyboardInterrupt() if self.signum in (None, signal.SIGINT) else Interrupted(self.signum)

    def __exit__(self, kind, value, traceback):
        import signal

        for number, handler in self._previous.items():
            signal.signal(number, handler)
        if self.is_set and kind is None:
            raise self.interrupt()
        return False


def _run_jobs(client, jobs: list, todo: list, rows: list, progress, interrupted=None) -> None:
    """Submit ``jobs[k]`` for each ``k`` in ``todo`` (largest input first), fill ``rows[k]`` as each
    ends; raises KeyboardInterrupt between files once ``interrupted.is_set``."""
    import time

    from distributed import as_completed

    from posegraph.batch.task import optimize_file

    # Largest first, so that no large file starts last and runs alone (sizes break ties by input order).
    order = sorted(todo, key=lambda k: -_size(jobs[k].input))
    futures = {client.submit(optimize_file, jobs[k], pure=False, priority=len(order) - rank): k
               for rank, k in enumerate(order)}
    slots = max(1, len(client.nthreads()))  # a worker process runs one file at a time (posegraph.batch.task)
    progress(None, _counts(rows, len(futures), slots))
    finished = as_completed(list(futures), loop=client.loop)
    try:
        while futures:
            if interrupted is not None and interrupted.is_set:
                raise interrupted.interrupt()
            if not finished.has_ready():
                time.sleep(POLL_SECONDS)
                continue
            for future in finished.next_batch(block=False):
                k = futures.pop(future)
                rows[k] = _row_of(future, jobs[k])
                progress(rows[k], _counts(rows, len(futures), slots))
    finally:
        for future in futures:  # only on an error or Ctrl-C: the files not finished are not left running
            future.cancel()


def _row_of(future, job) -> dict:
    """The task's row, or a failed row when the task itself failed (worker died, cluster lost it)."""
    from posegraph.batch.rows import failed_row

    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001 - one file's failure must not stop the others
        text = " ".join(str(exc).split())
        return failed_row(job, f"the task failed on the cluster ({type(exc).__name__}: {text})")


def _counts(rows: list, pending: int, slots: int) -> dict:
    from posegraph.batch.rows import tally

    by_status = tally(rows)
    running = min(pending, slots)
    return {"done": by_status["ok"] + by_status["skipped"], "failed": by_status["failed"] + by_status["not converged"],
            "running": running, "waiting": pending - running, "total": len(rows), "skipped": by_status["skipped"]}


def _size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0
