"""CHOLMOD's supernodal sparse Cholesky, called through ``ctypes`` on the system library.

Why not only scikit-sparse: ``sksparse.cholmod`` imports ``scipy.sparse``, and the two imports
cost ~0.14 s of wall time per process here (``python -c "import numpy"`` 0.08 s against
``python -c "import numpy, scipy.sparse, sksparse.cholmod"`` 0.23 s; loading ``libcholmod`` with
``ctypes`` 0.01 s). For a command-line optimiser whose whole run on a 2,500-pose graph takes
0.4 s that is a third of the time. This module needs numpy and the shared library only
(Debian/Ubuntu: ``libcholmod3``, pulled in by ``libsuitesparse-dev``); where it cannot be used,
:func:`load` returns None and the callers fall back to scikit-sparse, then to scipy's SuperLU.

What is bound (CHOLMOD 3, SuiteSparse 5; ``cholmod_core.h``, ``cholmod_cholesky.h``):
``cholmod_start``/``cholmod_finish`` (the ``cholmod_common`` workspace and settings),
``cholmod_analyze`` (fill-reducing ordering and supernodal symbolic factorisation, once per
pattern), ``cholmod_factorize`` (numeric, each iteration, same pattern), ``cholmod_solve`` with
``CHOLMOD_A`` and ``cholmod_free_{factor,dense}``. Matrices are passed without copying: a
``cholmod_sparse`` header pointing at numpy's int32 ``indptr``/``indices`` and float64 ``data``
of a CSC matrix with ``stype = -1`` (only entries on and below the diagonal are read; entries
above it, if stored, are ignored).

Safety of the struct layouts: ``cholmod_sparse``, ``cholmod_dense`` and the leading
``n, minor`` of ``cholmod_factor`` have not changed since CHOLMOD 1. The settings this module
writes in ``cholmod_common`` (``print``, ``supernodal``, ``nmethods``, ``method[0].ordering``,
``postorder``) sit in its documented prefix; :func:`load` checks that layout by reading back the
defaults ``cholmod_start`` wrote (about thirty fields with known values, e.g. ``grow0 = 1.2``,
``zrelax = {0.8, 0.1, 0.05}``, ``metis_nswitch = 3000``) and refuses the library on any mismatch,
so a CHOLMOD whose ``cholmod_common`` differs is never written to blindly.
"""

from __future__ import annotations

import ctypes
import weakref

import numpy as np

__all__ = [
    "NotPositiveDefiniteError", "CholmodLibrary", "SparseCholesky", "load", "unavailable_reason", "ORDERINGS",
    "VERTEX_ORDERINGS", "NESTED_DISSECTION_VERTICES", "auto_ordering", "fill_reducing_order", "block_permutation",
    "block_cholesky",
]  # fmt: skip


class NotPositiveDefiniteError(ArithmeticError):
    """The matrix could not be factorised as positive definite."""


ORDERINGS = {"natural": 0, "amd": 2, "metis": 3, "nesdis": 4, "colamd": 5, "default": None, "best": None}
"""Fill-reducing orderings by name: CHOLMOD's ``method[0].ordering`` code, or None for its own
strategies (``"default"``: AMD, then METIS if AMD's fill is high; ``"best"``: try all, keep the
least fill)."""

_LIBRARY_NAMES = ("libcholmod.so.3", "libcholmod.so")
"""Tried first by name (the soname of CHOLMOD 3, Debian 12 / Ubuntu 22.04), then through
``ctypes.util.find_library``."""

_SUPPORTED_MAJOR_VERSIONS = (3,)
"""CHOLMOD major versions whose ``cholmod_common`` prefix this module was written against."""

_COMMON_BYTES = 1 << 16
"""Room given to ``cholmod_common`` (CHOLMOD 3's is ~2.7 kB): generous, as only the prefix is described here."""

# CHOLMOD's constants (cholmod_core.h, cholmod_cholesky.h)
_CHOLMOD_INT, _CHOLMOD_PATTERN, _CHOLMOD_REAL, _CHOLMOD_DOUBLE = 0, 0, 1, 0
_CHOLMOD_SUPERNODAL, _CHOLMOD_MAXMETHODS, _CHOLMOD_SOLVE_A, _CHOLMOD_GIVEN = 2, 9, 0, 1
_CHOLMOD_OUT_OF_MEMORY = -2


class _Sparse(ctypes.Structure):
    _fields_ = [
        ("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
        ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("nz", ctypes.c_void_p),
        ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
        ("stype", ctypes.c_int), ("itype", ctypes.c_int), ("xtype", ctypes.c_int),
        ("dtype", ctypes.c_int), ("sorted", ctypes.c_int), ("packed", ctypes.c_int),
    ]  # fmt: skip


class _Dense(ctypes.Structure):
    _fields_ = [
        ("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
        ("d", ctypes.c_size_t), ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
        ("xtype", ctypes.c_int), ("dtype", ctypes.c_int),
    ]  # fmt: skip


def _pattern_header(indptr: np.ndarray, indices: np.ndarray, n: int) -> _Sparse:
    """A ``cholmod_sparse`` header over int32 CSC arrays of order ``n``: pattern only, lower triangle read.

    It points at the arrays' memory, so the caller keeps them alive while the header is used.
    """
    return _Sparse(
        nrow=n, ncol=n, nzmax=indices.shape[0], p=indptr.ctypes.data, i=indices.ctypes.data, nz=None, x=None,
        z=None, stype=-1, itype=_CHOLMOD_INT, xtype=_CHOLMOD_PATTERN, dtype=_CHOLMOD_DOUBLE, sorted=0, packed=1,
    )  # fmt: skip


class _FactorHead(ctypes.Structure):
    """The first two fields of ``cholmod_factor``: its order and the column where factorisation failed (``n`` if none)."""

    _fields_ = [("n", ctypes.c_size_t), ("minor", ctypes.c_size_t)]


class _Method(ctypes.Structure):
    _fields_ = [
        ("lnz", ctypes.c_double), ("fl", ctypes.c_double), ("prune_dense", ctypes.c_double),
        ("prune_dense2", ctypes.c_double), ("nd_oksep", ctypes.c_double), ("other_1", ctypes.c_double * 4),
        ("nd_small", ctypes.c_size_t), ("other_2", ctypes.c_size_t * 4), ("aggressive", ctypes.c_int),
        ("order_for_lu", ctypes.c_int), ("nd_compress", ctypes.c_int), ("nd_camd", ctypes.c_int),
        ("nd_components", ctypes.c_int), ("ordering", ctypes.c_int), ("other_3", ctypes.c_size_t * 4),
    ]  # fmt: skip


class _CommonPrefix(ctypes.Structure):
    """``cholmod_common`` up to ``status`` (CHOLMOD 3)."""

    _fields_ = [
        ("dbound", ctypes.c_double), ("grow0", ctypes.c_double), ("grow1", ctypes.c_double),
        ("grow2", ctypes.c_size_t), ("maxrank", ctypes.c_size_t), ("supernodal_switch", ctypes.c_double),
        ("supernodal", ctypes.c_int), ("final_asis", ctypes.c_int), ("final_super", ctypes.c_int),
        ("final_ll", ctypes.c_int), ("final_pack", ctypes.c_int), ("final_monotonic", ctypes.c_int),
        ("final_resymbol", ctypes.c_int), ("zrelax", ctypes.c_double * 3), ("nrelax", ctypes.c_size_t * 3),
        ("prefer_zomplex", ctypes.c_int), ("prefer_upper", ctypes.c_int),
        ("quick_return_if_not_posdef", ctypes.c_int), ("prefer_binary", ctypes.c_int),
        ("print", ctypes.c_int), ("precise", ctypes.c_int), ("try_catch", ctypes.c_int),
        ("error_handler", ctypes.c_void_p), ("nmethods", ctypes.c_int), ("current", ctypes.c_int),
        ("selected", ctypes.c_int), ("method", _Method * (_CHOLMOD_MAXMETHODS + 1)),
        ("postorder", ctypes.c_int), ("default_nesdis", ctypes.c_int), ("metis_memory", ctypes.c_double),
        ("metis_dswitch", ctypes.c_double), ("metis_nswitch", ctypes.c_size_t), ("nrow", ctypes.c_size_t),
        ("mark", ctypes.c_int64), ("iworksize", ctypes.c_size_t), ("xworksize", ctypes.c_size_t),
        ("Flag", ctypes.c_void_p), ("Head", ctypes.c_void_p), ("Xwork", ctypes.c_void_p),
        ("Iwork", ctypes.c_void_p), ("itype", ctypes.c_int), ("dtype", ctypes.c_int),
        ("no_workspace_reallocate", ctypes.c_int), ("status", ctypes.c_int),
    ]  # fmt: skip


def _defaults_match(common: _CommonPrefix) -> bool:
    """Whether ``common`` holds what ``cholmod_start`` writes in CHOLMOD 3 (``cholmod_defaults``), field by field."""
    methods = common.method
    method_ok = (
        tuple(m.ordering for m in methods) == (1, 2, 3, 4, 0, 4, 4, 4, 5, 2)
        and tuple(m.nd_small for m in methods) == (200,) * 5 + (20000, 4) + (200,) * 3
        and tuple(m.prune_dense for m in methods) == (10.0,) * 7 + (-1.0,) + (10.0,) * 2
        and all(
            m.prune_dense2 == -1.0 and m.nd_oksep == 1.0 and m.aggressive == 1 and m.order_for_lu == 0
            and m.nd_compress == 1 and m.nd_components == 0
            for m in methods
        )
    )  # fmt: skip
    return (
        method_ok
        and common.dbound == 0.0 and common.grow0 == 1.2 and common.grow1 == 1.2 and common.grow2 == 5
        and common.maxrank == 8 and common.supernodal_switch == 40.0 and common.supernodal == 1
        and common.final_asis == 1 and common.final_super == 1 and common.final_ll == 0
        and common.final_pack == 1 and common.final_monotonic == 1 and common.final_resymbol == 0
        and tuple(common.zrelax) == (0.8, 0.1, 0.05) and tuple(common.nrelax) == (4, 16, 48)
        and common.prefer_upper == 1 and common.print == 3 and common.nmethods == 0
        and common.postorder == 1 and common.default_nesdis == 0 and common.metis_memory == 0.0
        and common.metis_dswitch == 0.66 and common.metis_nswitch == 3000
        and common.itype == _CHOLMOD_INT and common.dtype == _CHOLMOD_DOUBLE and common.status == 0
    )  # fmt: skip


class CholmodLibrary:
    """The loaded CHOLMOD shared library with the argument types of the functions used here."""

    def __init__(self, library: ctypes.CDLL, path: str, version: tuple[int, int, int]):
        self.path, self.version = path, version
        c_void_p, c_int = ctypes.c_void_p, ctypes.c_int
        for name, restype, argtypes in (
            ("cholmod_start", c_int, [c_void_p]),
            ("cholmod_finish", c_int, [c_void_p]),
            ("cholmod_analyze", c_void_p, [c_void_p, c_void_p]),
            ("cholmod_analyze_p", c_void_p, [c_void_p, c_void_p, c_void_p, ctypes.c_size_t, c_void_p]),
            ("cholmod_amd", c_int, [c_void_p, c_void_p, ctypes.c_size_t, c_void_p, c_void_p]),
            ("cholmod_metis", c_int, [c_void_p, c_void_p, ctypes.c_size_t, c_int, c_void_p, c_void_p]),
            ("cholmod_nested_dissection", ctypes.c_int64,
             [c_void_p, c_void_p, ctypes.c_size_t, c_void_p, c_void_p, c_void_p, c_void_p]),  # fmt: skip
            ("cholmod_factorize", c_int, [c_void_p, c_void_p, c_void_p]),
            ("cholmod_solve", c_void_p, [c_int, c_void_p, c_void_p, c_void_p]),
            ("cholmod_free_factor", c_int, [c_void_p, c_void_p]),
            ("cholmod_free_dense", c_int, [c_void_p, c_void_p]),
        ):
            function = getattr(library, name)
            function.restype, function.argtypes = restype, argtypes
            setattr(self, name[len("cholmod_") :], function)

    def new_common(self) -> ctypes.Array:
        """A started ``cholmod_common`` (a byte buffer); raises ``OSError`` if its defaults are not CHOLMOD 3's."""
        buffer = ctypes.create_string_buffer(_COMMON_BYTES)
        if not self.start(buffer):
            raise OSError("cholmod_start failed")
        if not _defaults_match(_CommonPrefix.from_buffer(buffer)):
            self.finish(buffer)
            raise OSError(f"{self.path}: cholmod_common does not have CHOLMOD 3's layout")
        return buffer


_loaded: list = []  # [CholmodLibrary or None, reason]


def _find_library() -> tuple[ctypes.CDLL, str]:
    errors = []
    for name in _LIBRARY_NAMES:
        try:
            return ctypes.CDLL(name), name
        except OSError as err:
            errors.append(str(err))
    # Only now: ctypes.util imports shutil, subprocess and tempfile (~4 ms of every start otherwise).
    from ctypes import util

    found = util.find_library("cholmod")
    if found and found not in _LIBRARY_NAMES:
        try:
            return ctypes.CDLL(found), found
        except OSError as err:
            errors.append(str(err))
    raise OSError("; ".join(errors) or "libcholmod not found")


def load() -> CholmodLibrary | None:
    """The system CHOLMOD 3 library, checked (see the module docstring), or None; cached.

    :func:`unavailable_reason` says why it is None.
    """
    if not _loaded:
        try:
            library, path = _find_library()
            version = (ctypes.c_int * 3)()
            if not hasattr(library, "cholmod_version"):
                raise OSError(f"{path}: no cholmod_version (CHOLMOD older than 2.1)")
            library.cholmod_version(version)
            if version[0] not in _SUPPORTED_MAJOR_VERSIONS:
                raise OSError(f"{path}: CHOLMOD {'.'.join(map(str, version))}, this binding knows version 3 only")
            cholmod = CholmodLibrary(library, path, tuple(version))
            cholmod.finish(cholmod.new_common())  # the layout check
            _loaded[:] = [cholmod, None]
        except (OSError, AttributeError) as err:
            _loaded[:] = [None, str(err)]
    return _loaded[0]


def unavailable_reason() -> str | None:
    """Why :func:`load` returns None (None when it does not)."""
    load()
    return _loaded[1]


def _release(cholmod: CholmodLibrary, common: ctypes.Array, factor: ctypes.c_void_p) -> None:
    if factor:
        cholmod.free_factor(ctypes.byref(factor), common)
    cholmod.finish(common)


class SparseCholesky:
    """``A = L Lᵀ`` of a sparse symmetric positive-definite matrix by CHOLMOD's supernodal method.

    The pattern is analysed once, here: ``indptr`` ``(n+1,)`` and ``indices`` ``(nnz,)`` of a CSC
    matrix of order ``n`` whose entries on and below the diagonal are used (stored entries above
    it are ignored), with ``ordering`` a key of :data:`ORDERINGS` — or, given ``permutation`` ``(n,)``
    (``permutation[k]`` = the row/column eliminated k-th, e.g. from :func:`block_permutation`),
    that order, postordered. Then, any number of times,
    :meth:`factorize` with new ``data`` ``(nnz,)`` on the same pattern and :meth:`solve`.
    ``threads`` wraps CHOLMOD's calls in :class:`posegraph.native_threads.NativeThreads`.
    """

    def __init__(
        self, indptr, indices, n: int, ordering: str = "amd", threads: int | None = 1, *, permutation=None, library=None
    ):
        from posegraph.native_threads import NativeThreads

        cholmod = library or load()
        if cholmod is None:
            raise OSError(f"CHOLMOD is not available: {unavailable_reason()}")
        if ordering not in ORDERINGS:
            raise ValueError(f"CHOLMOD ordering must be one of {tuple(ORDERINGS)}, got {ordering!r}")
        self.n = int(n)
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int32)
        self.indices = np.ascontiguousarray(indices, dtype=np.int32)
        if self.indptr.shape != (self.n + 1,) or self.indices.shape != (int(self.indptr[-1]),):
            raise ValueError(f"indptr must have shape ({self.n + 1},) and indices ({int(self.indptr[-1])},)")
        self.nnz = int(self.indices.shape[0])
        self.ordering = ordering
        self._cholmod = cholmod
        self._common = cholmod.new_common()
        settings = _CommonPrefix.from_buffer(self._common)
        settings.print = 0  # CHOLMOD would print "not positive definite" to stdout; we raise instead
        settings.supernodal = _CHOLMOD_SUPERNODAL
        code = _CHOLMOD_GIVEN if permutation is not None else ORDERINGS[ordering]
        if code is not None:
            settings.nmethods = 1
            settings.method[0].ordering = code
            settings.postorder = 1
        elif ordering == "best":
            settings.nmethods = _CHOLMOD_MAXMETHODS
        self._factor = ctypes.c_void_p()
        self._finalizer = weakref.finalize(self, _release, cholmod, self._common, self._factor)
        self._threads = NativeThreads(threads)
        self.threads_active = self._threads.active
        self._matrix = _pattern_header(self.indptr, self.indices, self.n)
        if permutation is not None:
            self.permutation = np.ascontiguousarray(permutation, dtype=np.int32)
            if self.permutation.shape != (self.n,):
                raise ValueError(f"permutation must have shape ({self.n},), got {self.permutation.shape}")
            self.ordering = "given"
        with self._threads:
            if permutation is None:
                factor = cholmod.analyze(ctypes.byref(self._matrix), self._common)
            else:
                factor = cholmod.analyze_p(
                    ctypes.byref(self._matrix), self.permutation.ctypes.data, None, 0, self._common
                )
        if not factor:
            raise self._failure("cholmod_analyze")
        self._factor.value = factor
        self._factorized = False

    def _failure(self, call: str) -> Exception:
        status = _CommonPrefix.from_buffer(self._common).status
        if status == _CHOLMOD_OUT_OF_MEMORY:
            return MemoryError(f"{call}: CHOLMOD ran out of memory (order {self.n}, {self.nnz} entries)")
        return RuntimeError(f"{call} failed with CHOLMOD status {status}")

    def factorize(self, data) -> None:
        """Numeric factorisation for values ``data`` ``(nnz,)`` on the analysed pattern.

        Raises :class:`NotPositiveDefiniteError` when a pivot is not positive, or an entry is not
        finite (CHOLMOD would let a NaN through to a NaN solution).
        """
        data = np.ascontiguousarray(data, dtype=np.float64)
        if data.shape != (self.nnz,):
            raise ValueError(f"data must have shape ({self.nnz},), got {data.shape}")
        if not np.isfinite(data).all():
            self._factorized = False
            raise NotPositiveDefiniteError("matrix has non-finite entries")
        self._factorized = False
        self._matrix.x, self._matrix.xtype = data.ctypes.data, _CHOLMOD_REAL
        try:
            with self._threads:
                ok = self._cholmod.factorize(ctypes.byref(self._matrix), self._factor, self._common)
        finally:
            # ``data`` may be freed after this call; analysis reads the pattern only
            self._matrix.x, self._matrix.xtype = None, _CHOLMOD_PATTERN
        if not ok:
            raise self._failure("cholmod_factorize")
        minor = _FactorHead.from_address(self._factor.value).minor
        if minor < self.n:
            raise NotPositiveDefiniteError(f"CHOLMOD: matrix not positive definite (column {minor} of {self.n})")
        self._factorized = True

    def solve(self, rhs) -> np.ndarray:
        """``x`` with ``A x = rhs`` for the last factorised ``A``; ``rhs`` ``(n,)`` or ``(n, k)``, same shape out."""
        if not self._factorized:
            raise RuntimeError("factorize() must succeed before solve()")
        rhs = np.asarray(rhs, dtype=np.float64)
        if rhs.ndim not in (1, 2) or rhs.shape[0] != self.n:
            raise ValueError(f"rhs must have shape ({self.n},) or ({self.n}, k), got {rhs.shape}")
        columns = np.asfortranarray(rhs.reshape(self.n, -1))
        k = columns.shape[1]
        b = _Dense(nrow=self.n, ncol=k, nzmax=self.n * k, d=self.n, x=columns.ctypes.data, z=None,
                   xtype=_CHOLMOD_REAL, dtype=_CHOLMOD_DOUBLE)  # fmt: skip
        with self._threads:
            solution = self._cholmod.solve(_CHOLMOD_SOLVE_A, self._factor, ctypes.byref(b), self._common)
        if not solution:
            raise self._failure("cholmod_solve")
        handle = ctypes.c_void_p(solution)
        try:
            values = _Dense.from_address(solution).x
            x = np.frombuffer((ctypes.c_double * (self.n * k)).from_address(values), dtype=np.float64)
            out = x.reshape(k, self.n).T.copy() if k > 1 else x.copy()
        finally:
            self._cholmod.free_dense(ctypes.byref(handle), self._common)
        return out.reshape(rhs.shape)

    def close(self) -> None:
        """Free the factor and CHOLMOD's workspace now (otherwise when the object is collected)."""
        self._factorized = False
        self._finalizer()


VERTEX_ORDERINGS = ("amd", "metis", "nesdis")
"""Orderings :func:`fill_reducing_order` computes."""


NESTED_DISSECTION_VERTICES = 10_000
"""From this many free vertices, ``"auto"`` orders by nested dissection instead of AMD
(:func:`auto_ordering`). Measured here (vertex-graph ordering + analysis, then one numeric
factorisation): sphere 50k poses AMD 0.23 + 4.78 s, nested dissection 0.40 + 2.42 s; 4-layer slab
50k 0.18 + 10.2 s against 0.43 + 6.7 s; 25³ cube 0.06 + 5.8 s against 0.13 + 2.6 s. Below a few
thousand vertices the two factorise alike and AMD analyses twice as fast (torus3D, 5,000 poses:
12 + 69 ms against 23 + 60 ms; sphere2500 5.5 + 27 ms against 10 + 25 ms)."""


def auto_ordering(num_vertices: int) -> str:
    """The ordering ``"auto"`` stands for on a system of ``num_vertices`` free vertices."""
    return "nesdis" if num_vertices >= NESTED_DISSECTION_VERTICES else "amd"


def fill_reducing_order(indptr, indices, n: int, method: str = "amd", *, library=None) -> np.ndarray:
    """A fill-reducing order ``(n,)`` (``order[k]`` = the node eliminated k-th) of a symmetric pattern.

    ``indptr``/``indices``: CSC of the pattern (entries on and below the diagonal are read);
    ``method``: ``"amd"`` (``cholmod_amd``), ``"metis"`` (``cholmod_metis``, postordered) or
    ``"nesdis"`` (``cholmod_nested_dissection``: METIS separators, CAMD inside). Used on the
    *vertex* graph of a block system (see :func:`block_permutation`): p nodes instead of 6p, with
    36 times fewer entries, for the same elimination order of the blocks.
    """
    cholmod = library or load()
    if cholmod is None:
        raise OSError(f"CHOLMOD is not available: {unavailable_reason()}")
    if method not in VERTEX_ORDERINGS:
        raise ValueError(f"method must be one of {VERTEX_ORDERINGS}, got {method!r}")
    indptr = np.ascontiguousarray(indptr, dtype=np.int32)
    indices = np.ascontiguousarray(indices, dtype=np.int32)
    n = int(n)
    order = np.zeros(n, dtype=np.int32)
    if n == 0:
        return order.astype(np.int64)
    pattern = _pattern_header(indptr, indices, n)
    common = cholmod.new_common()
    try:
        _CommonPrefix.from_buffer(common).print = 0
        if method == "amd":
            ok = cholmod.amd(ctypes.byref(pattern), None, 0, order.ctypes.data, common)
        elif method == "metis":
            ok = cholmod.metis(ctypes.byref(pattern), None, 0, 1, order.ctypes.data, common)
        else:
            parent, member = np.zeros(n, dtype=np.int32), np.zeros(n, dtype=np.int32)
            ok = cholmod.nested_dissection(
                ctypes.byref(pattern), None, 0, order.ctypes.data, parent.ctypes.data, member.ctypes.data, common
            ) >= 0
        status = _CommonPrefix.from_buffer(common).status
    finally:
        cholmod.finish(common)
    if not ok:
        raise RuntimeError(f"cholmod_{method} failed with CHOLMOD status {status}")
    return order.astype(np.int64)


def block_permutation(order, block: int) -> np.ndarray:
    """The scalar permutation ``(block·p,)`` eliminating ``block``-sized blocks in the order ``order`` ``(p,)``."""
    order = np.asarray(order, dtype=np.int64)
    return (block * order[:, None] + np.arange(block)[None, :]).reshape(-1)


def block_cholesky(
    indptr, indices, block_indptr, block_indices, num_blocks: int, block: int, ordering: str = "auto",
    threads: int | None = 1,
) -> SparseCholesky:
    """:class:`SparseCholesky` of a matrix made of ``block``×``block`` blocks, analysed once.

    ``indptr``/``indices``: the scalar CSC pattern (order ``block·num_blocks``);
    ``block_indptr``/``block_indices``: its block (vertex) pattern, one entry per stored block.
    ``ordering`` ``"auto"`` (:func:`auto_ordering`) or one of :data:`VERTEX_ORDERINGS` orders the
    vertex graph and expands the order to the blocks (:func:`fill_reducing_order`,
    :func:`block_permutation`); any other key of :data:`ORDERINGS` orders the scalar pattern.
    """
    if ordering == "auto":
        ordering = auto_ordering(num_blocks)
    n = block * num_blocks
    if ordering not in VERTEX_ORDERINGS:
        return SparseCholesky(indptr, indices, n, ordering, threads)
    order = fill_reducing_order(block_indptr, block_indices, num_blocks, ordering)
    return SparseCholesky(indptr, indices, n, ordering, threads, permutation=block_permutation(order, block))
