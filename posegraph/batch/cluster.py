"""The Dask cluster a batch runs on: a client given, a scheduler's address, or a local cluster made for it.

``dask.distributed`` is an optional dependency (``pip install "posegraph[batch]"``), imported here
only, when a batch has files to run.
"""

from __future__ import annotations

import contextlib
import logging
import os

__all__ = ["require_distributed", "batch_client", "default_workers", "kept_environment", "DISTRIBUTED_MISSING"]

DISTRIBUTED_MISSING = ("posegraph batch needs Dask's distributed scheduler (dask.distributed), which is not "
                       'installed: pip install "posegraph[batch]"')

CONNECT_SECONDS = 20
"""How long to try reaching a ``--scheduler`` address before giving up."""


def require_distributed():
    """The ``distributed`` module, or an :class:`ImportError` saying how to install it."""
    try:
        import distributed
    except ImportError as exc:
        raise ImportError(DISTRIBUTED_MISSING, name="distributed") from exc
    return distributed


def default_workers() -> int:
    """Worker processes of a local cluster when none is asked for: one per core."""
    return os.cpu_count() or 1


@contextlib.contextmanager
def batch_client(*, client=None, scheduler: str | None = None, workers: int | None = None):
    """Yield a ``distributed.Client``: ``client`` itself; one connected to ``scheduler``
    (``tcp://host:port``); or one of a local cluster of ``workers`` processes, one thread each
    and one BLAS thread (:data:`WORKER_ENVIRONMENT`), ignoring Ctrl-C (this process takes it
    and closes the cluster), closed on leaving. A scheduler that cannot be reached is a
    :class:`~posegraph.batch.options.BatchError`."""
    if client is not None:
        yield client
        return
    distributed = require_distributed()
    if scheduler is not None:
        with _connect(distributed, scheduler) as connected:
            yield connected
        return
    with kept_environment(), _worker_environment(), contextlib.ExitStack() as started:
        with _workers_ignore_interrupts():
            # CRITICAL, not ERROR: a worker whose heartbeat fails while the cluster closes after Ctrl-C
            # logs that at ERROR with a traceback, on the user's terminal (each file's own errors are
            # in its row and log, not in Dask's)
            cluster = started.enter_context(distributed.LocalCluster(
                n_workers=workers or default_workers(), silence_logs=logging.CRITICAL, **LOCAL_CLUSTER_OPTIONS))
            local = started.enter_context(distributed.Client(cluster, set_as_default=False))
        yield local


@contextlib.contextmanager
def _workers_ignore_interrupts():
    """Ignore Ctrl-C (SIGINT) while the local workers are started, so that they ignore it too.

    Ctrl-C goes to every process of the terminal's foreground group, the workers included; each
    would die printing a traceback, while this process closes the cluster in order (its ``with``
    blocks). A signal ignored is still ignored after ``exec``, so the worker processes started
    inside never see Ctrl-C; this process takes it again once they run (a press during the
    start-up, under a second, is lost). Only from the main thread, where Python handles signals."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


LOCAL_CLUSTER_OPTIONS = dict(
    threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0", scheduler_kwargs={"dashboard": False},
)
"""``distributed.LocalCluster`` options of a batch's local cluster: worker processes of one thread,
no dashboard. The scheduler serves HTTP (health checks) even without one, on port 8787 unless told
otherwise, and warns when another cluster on the machine holds that port: so a free port of the
loopback interface."""


@contextlib.contextmanager
def kept_environment():
    """Leave this process's environment variables as they were on entry, whatever happens inside.

    A nanny sets its ``pre-spawn-environ`` variables in the process that starts the workers (the
    caller's) and leaves them there; without this, a batch would leave ``OPENBLAS_NUM_THREADS=1``
    and the rest in the caller's environment, for every process it starts afterwards."""
    saved = dict(os.environ)
    try:
        yield
    finally:
        for name in set(os.environ) - set(saved):
            del os.environ[name]
        os.environ.update(saved)


WORKER_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""What the nanny sets in each local worker process before it starts: one BLAS thread, as a
``posegraph optimize`` process runs. Dask's default also sets ``MALLOC_TRIM_THRESHOLD_`` to 64 kB,
which gives freed memory back to the system at once, and which the command line then leaves alone
(:func:`posegraph.cli.startup.keep_freed_memory` yields to a user's malloc settings): every file's
arrays page-faulted anew, and the files ran about 2x slower than in ``posegraph optimize``
processes (9 shared graphs, 2 workers; docs/benchmarks.md). Without it the worker keeps freed
memory as the command line does."""


def _worker_environment():
    import dask

    return dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRONMENT})


def _connect(distributed, address: str):
    """A client of the scheduler at ``address``, tried for :data:`CONNECT_SECONDS`; a
    :class:`BatchError` saying how long it waited when it does not answer (nothing is written
    before: OUT_DIR is made only once it answers)."""
    import time

    from posegraph.batch.options import BatchError

    start = time.monotonic()
    try:
        return distributed.Client(address, timeout=CONNECT_SECONDS, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        text = " ".join(str(exc).split()) or type(exc).__name__
        waited = time.monotonic() - start
        raise BatchError(f"cannot reach the Dask scheduler at {address} (waited {waited:.1f} s): {text}; "
                         "nothing was written") from None
