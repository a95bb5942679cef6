"""How many threads the BLAS under CHOLMOD runs, through ``threadpoolctl``.

CHOLMOD's supernodal factorisation spends most of its time in dense BLAS/LAPACK kernels
(``dsyrk``, ``dgemm``, ``dtrsm``, ``dpotrf``). The cvxopt wheel, which brings CHOLMOD here
(:mod:`posegraph.linalg.cholmod`), bundles its own OpenBLAS — a library apart from numpy's and scipy's —
and its CHOLMOD is built without OpenMP. Which OpenBLAS build a wheel bundles differs by
platform: the Linux x86_64 wheel of cvxopt 1.3 ships a single-threaded one (``threadpoolctl``
reports its threading layer as ``"disabled"``), where there is nothing to set; a threaded build
starts one thread per core, and on a shared 2-core machine two BLAS threads contended with the
other processes (torus3D's 30k×30k factorisation: 0.069 s with one thread against 0.18 s with
the defaults while other jobs ran, measured on the system OpenBLAS).

:class:`NativeThreads` limits the BLAS libraries loaded from cvxopt's package folder (found by
``threadpoolctl.ThreadpoolController``; numpy's and scipy's BLAS are left alone) to ``threads``
inside a ``with`` block and restores them after. It controls nothing (``active`` False) where
there is no such library, where it is single-threaded, where threadpoolctl is not installed, or
where one thread is asked for and ``OPENBLAS_NUM_THREADS=1`` was set before OpenBLAS loaded (as
the command line does): then OpenBLAS already runs one thread, and threadpoolctl's import and
library scan (~15 ms of every run) are saved.
"""

from __future__ import annotations

import os

__all__ = ["NativeThreads", "cholmod_blas_libraries", "single_threaded_numpy_blas"]

_CONTROLLER: list = []  # [threadpoolctl.ThreadpoolController or None], made once


def _controller():
    """A ``ThreadpoolController`` made after cvxopt is imported (cached), or None without threadpoolctl."""
    if not _CONTROLLER:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:
            _CONTROLLER.append(None)
        else:
            _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0]


def cholmod_blas_libraries(info: list[dict] | None = None) -> list[dict]:
    """threadpoolctl's descriptions of the threaded BLAS libraries cvxopt bundles and has loaded.

    ``info``: ``threadpoolctl.threadpool_info()``-style dictionaries (default: this process's).
    """
    if info is None:
        controller = _controller()
        info = controller.info() if controller is not None else []
    return [
        lib
        for lib in info
        if lib.get("user_api") == "blas"
        and "cvxopt" in str(lib.get("filepath", "")).replace("\\", "/").lower()
        and lib.get("threading_layer") != "disabled"
    ]


class NativeThreads:
    """Context manager: the threaded BLAS under CHOLMOD runs ``threads`` threads inside, its own setting after.

    ``threads=None`` does nothing. Make it after importing cvxopt (the libraries are looked up
    when the object is made). Not reentrant.
    """

    def __init__(self, threads: int | None):
        if threads is not None and (int(threads) != threads or threads < 1):
            raise ValueError(f"threads must be a positive integer or None, got {threads!r}")
        self.threads = threads
        already = threads == 1 and os.environ.get("OPENBLAS_NUM_THREADS") == "1"
        self._paths = [] if threads is None or already else [lib["filepath"] for lib in cholmod_blas_libraries()]
        self._limiter = None

    @property
    def active(self) -> bool:
        """Whether any library is controlled (False: the ``with`` block changes nothing)."""
        return bool(self._paths)

    def __enter__(self) -> "NativeThreads":
        if self._paths:
            selected = _controller().select(filepath=self._paths)
            self._limiter = selected.limit(limits=int(self.threads))
        return self

    def __exit__(self, *exc) -> bool:
        if self._limiter is not None:
            self._limiter.restore_original_limits()
            self._limiter = None
        return False


_NUMPY_BLAS: list = []  # [threadpoolctl selection of numpy's threaded BLAS, or None], made once


def single_threaded_numpy_blas():
    """A context manager running numpy's own threaded BLAS (not cvxopt's) on one thread inside, for
    many small dense products (a few hundred rows): on a shared 2-core machine two OpenBLAS threads
    made them 2–3× slower (a 120×120 solve 51 ms against ~1 ms, under load). ``contextlib.nullcontext``
    where there is nothing to limit (no threadpoolctl, a single-threaded BLAS, ``OPENBLAS_NUM_THREADS=1``)."""
    import contextlib

    if not _NUMPY_BLAS:
        controller = None if os.environ.get("OPENBLAS_NUM_THREADS") == "1" else _controller()
        paths = [] if controller is None else [
            lib["filepath"] for lib in controller.info()
            if lib.get("user_api") == "blas" and lib.get("num_threads", 1) > 1
            and "cvxopt" not in str(lib.get("filepath", "")).replace("\\", "/").lower()]
        _NUMPY_BLAS.append(controller.select(filepath=paths) if paths else None)
    selection = _NUMPY_BLAS[0]
    return contextlib.nullcontext() if selection is None else selection.limit(limits=1)
