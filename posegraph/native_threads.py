"""How many threads the native code under CHOLMOD runs: the system OpenBLAS and CHOLMOD's OpenMP loops.

CHOLMOD (scikit-sparse) spends its time in two native libraries besides its own code:

* the **system BLAS/LAPACK** (here OpenBLAS, a different library from the one bundled in numpy's
  and scipy's wheels, whose symbols are prefixed ``scipy_openblas``), for the dense kernels of the
  supernodal factorisation (``dsyrk``, ``dgemm``, ``dtrsm``, ``dpotrf``);
* **OpenMP** (libgomp), for the scatter and copy loops between supernodes. SuiteSparse 5's
  supernodal factorisation asks for a fixed four threads (``num_threads(4)``) in every such loop
  over more than a few rows, whatever ``OMP_NUM_THREADS`` says.

On the 2-core machine here, shared with other processes, both hurt: each of those thousands of
small parallel loops per factorisation wakes three sleeping threads and waits for them
(``futex`` wake-ups, ~40 % of the factorisation's time in ``perf`` while other jobs ran), and two
BLAS threads contend for the cores with everything else. Measured on torus3D's 30k×30k H (AMD,
alternating in one process): 0.089 s per factorisation as CHOLMOD comes against 0.071 s with both
set to one thread when the machine was otherwise idle (load 0.7), 0.18 s against 0.069 s while
other jobs ran (load ~2: this was the "slow mode" of ``docs/solver.md``); sphere2500 0.042 against
0.028 s.

:class:`NativeThreads` sets both for the duration of a ``with`` block and restores them after:
OpenBLAS through ``openblas_set_num_threads``, OpenMP by setting the maximum number of *active*
nested parallel levels to 0 (``omp_set_max_active_levels(0)``), which makes every parallel region
inactive, i.e. run by the calling thread alone — the one setting a ``num_threads`` clause cannot
override. Libraries are found among those loaded in the process (``/proc/self/maps``, Linux);
where there are none (reference BLAS, MKL, macOS) the manager does nothing.
"""

from __future__ import annotations

import ctypes

__all__ = ["NativeThreads"]

_OPENBLAS_SYMBOLS = ("openblas_set_num_threads", "openblas_get_num_threads")
_OPENMP_SYMBOLS = ("omp_set_max_active_levels", "omp_get_max_active_levels")
_OPENMP_NAMES = ("libgomp", "libomp", "libiomp")

_handles: dict[str, ctypes.CDLL | None] = {}


def _loaded_libraries() -> list[str]:
    """Paths of the BLAS and OpenMP shared libraries mapped into this process, sorted.

    Empty where ``/proc`` is absent.
    """
    try:
        with open("/proc/self/maps") as maps:
            text = maps.read()
    except OSError:
        return []
    paths = set()
    for line in text.splitlines():
        if ".so" in line and ("blas" in line or "omp" in line):
            path = line.rsplit(None, 1)[-1]
            name = path.rsplit("/", 1)[-1]
            if "blas" in name.lower() or name.startswith(_OPENMP_NAMES):
                paths.add(path)
    return sorted(paths)


def _library(path: str, symbols: tuple[str, ...]) -> ctypes.CDLL | None:
    """The already loaded library at ``path`` if it exports all ``symbols`` (cached), else None."""
    key = f"{path}\0{symbols[0]}"
    if key not in _handles:
        try:
            library = ctypes.CDLL(path)
        except OSError:
            library = None
        _handles[key] = library if library is not None and all(hasattr(library, s) for s in symbols) else None
    return _handles[key]


def system_openblas_libraries(paths: list[str] | None = None) -> list[ctypes.CDLL]:
    """OpenBLAS builds with unprefixed ``openblas_{get,set}_num_threads`` loaded in this process."""
    paths = _loaded_libraries() if paths is None else paths
    found = (_library(p, _OPENBLAS_SYMBOLS) for p in paths if "blas" in p.rsplit("/", 1)[-1].lower())
    return [lib for lib in found if lib is not None]


def openmp_libraries(paths: list[str] | None = None) -> list[ctypes.CDLL]:
    """OpenMP runtimes (GNU libgomp, LLVM libomp, Intel libiomp) loaded in this process."""
    paths = _loaded_libraries() if paths is None else paths
    found = (_library(p, _OPENMP_SYMBOLS) for p in paths if p.rsplit("/", 1)[-1].startswith(_OPENMP_NAMES))
    return [lib for lib in found if lib is not None]


class NativeThreads:
    """Context manager: the system OpenBLAS and OpenMP run ``threads`` threads inside, their own settings after.

    ``threads=None`` does nothing. ``threads=1`` also makes OpenMP parallel regions run serially;
    with more than one thread OpenMP is left to its own choice (CHOLMOD's four threads), as no
    runtime call caps an explicit ``num_threads`` clause at a number other than one. The libraries
    are looked up when the object is made, so make it after importing the code that loads them
    (``sksparse.cholmod``). Not reentrant.
    """

    def __init__(self, threads: int | None):
        if threads is not None and (int(threads) != threads or threads < 1):
            raise ValueError(f"threads must be a positive integer or None, got {threads!r}")
        self.threads = threads
        paths = _loaded_libraries() if threads is not None else []
        self._blas = system_openblas_libraries(paths) if threads is not None else []
        self._openmp = openmp_libraries(paths) if threads == 1 else []
        self._saved_blas: list[int] = []
        self._saved_openmp: list[int] = []

    @property
    def active(self) -> bool:
        """Whether any library is controlled (False: the ``with`` block changes nothing)."""
        return bool(self._blas or self._openmp)

    def __enter__(self) -> "NativeThreads":
        self._saved_blas = [int(lib.openblas_get_num_threads()) for lib in self._blas]
        for lib in self._blas:
            lib.openblas_set_num_threads(int(self.threads))
        self._saved_openmp = [int(lib.omp_get_max_active_levels()) for lib in self._openmp]
        for lib in self._openmp:
            lib.omp_set_max_active_levels(0)
        return self

    def __exit__(self, *exc) -> bool:
        for lib, saved in zip(self._blas, self._saved_blas):
            lib.openblas_set_num_threads(saved)
        for lib, saved in zip(self._openmp, self._saved_openmp):
            lib.omp_set_max_active_levels(saved)
        self._saved_blas, self._saved_openmp = [], []
        return False
