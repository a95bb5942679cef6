"""CHOLMOD's supernodal sparse Cholesky, from the cvxopt wheel, with orderings of the vertex graph.

The one CHOLMOD path: ``cvxopt.cholmod`` (cvxopt 1.3 bundles CHOLMOD 3.0.6 and an OpenBLAS in
its wheels, so ``pip install`` alone gives it; it imports in ~10 ms without scipy). Where cvxopt
is not installed (a platform or Python version without a wheel), :func:`load` returns None with
the reason, and the callers use scipy's SuperLU.

What is used: ``cvxopt.cholmod.symbolic(A, p)`` (analysis once per pattern, with a given
permutation), ``numeric(A, F)`` (numeric factorisation each iteration; ``ArithmeticError`` when a
pivot is not positive), ``solve(F, B, sys)`` (``sys=0``: ``A x = b``; ``sys=7``: ``P b``, used to
read the permutation), ``diag(F)`` (the diagonal of L, checked finite) and ``getfactor(F)`` (L as a
sparse matrix). cvxopt's matrices use its 64-bit index type (``int_t``), so every pattern is
passed with int64 indices. CHOLMOD reads the lower triangle only (``uplo='L'``).

Orderings are computed on the *vertex* graph of the block system (p nodes, one entry per block)
and expanded to the blocks (:func:`block_permutation`): AMD (``cvxopt.amd``) or nested dissection
(METIS's ``METIS_NodeND`` through the ``pymetis`` wheel; cvxopt's CHOLMOD is built without METIS).
CHOLMOD then postorders the given permutation along its elimination tree (``options['postorder']``)
and takes it as given (``options['nmethods'] = 1``; cvxopt's default 0 would also run CHOLMOD's
AMD on the scalar pattern and keep the better of the two, which costs a second ordering per
analysis: on the 50k-pose sphere 1.9–2.2 s of analysis against 1.3–1.5 s, ``docs/cholesky.md``).

Licences: cvxopt is GPL-3; CHOLMOD's Supernodal module is GPL-2+ (the rest LGPL-2.1+); pymetis
is MIT, METIS Apache-2.0.
"""

from __future__ import annotations

import contextlib

import numpy as np

__all__ = [
    "NotPositiveDefiniteError", "SparseCholesky", "load", "unavailable_reason", "ORDERINGS", "VERTEX_ORDERINGS",
    "NESTED_DISSECTION_VERTICES", "auto_ordering", "nested_dissection_available", "fill_reducing_order", "block_permutation", "block_cholesky",
    "block_factor_bytes",
]  # fmt: skip


class NotPositiveDefiniteError(ArithmeticError):
    """The matrix could not be factorised as positive definite (or its factor is not finite)."""


VERTEX_ORDERINGS = ("amd", "nesdis", "metis")
"""Orderings :func:`fill_reducing_order` computes: ``"amd"`` (approximate minimum degree, cvxopt's
AMD) and ``"nesdis"`` (METIS nested dissection through pymetis; ``"metis"`` is the same)."""

ORDERINGS = (*VERTEX_ORDERINGS, "natural", "default")
"""Orderings :class:`SparseCholesky` accepts: :data:`VERTEX_ORDERINGS` (of the scalar pattern
there; :func:`block_cholesky` applies them to the vertex graph), ``"natural"`` (none) and
``"default"`` (CHOLMOD's own strategy on the scalar pattern: AMD)."""

_loaded: list = []  # [cvxopt.cholmod or None, reason]


def load():
    """The ``cvxopt.cholmod`` module, or None when cvxopt cannot be imported (cached).

    :func:`unavailable_reason` says why it is None.
    """
    if not _loaded:
        try:
            from cvxopt import cholmod

            _loaded[:] = [cholmod, None]
        except ImportError as err:  # not installed, or its bundled libraries do not load
            _loaded[:] = [None, f"cvxopt does not import ({err}); pip install cvxopt"]
    return _loaded[0]


def unavailable_reason() -> str | None:
    """Why :func:`load` returns None (None when it does not)."""
    load()
    return _loaded[1]


def _require():
    cholmod = load()
    if cholmod is None:
        raise ImportError(f"CHOLMOD is not available: {unavailable_reason()}")
    return cholmod


@contextlib.contextmanager
def _options(cholmod, **settings):
    """``cvxopt.cholmod.options`` set to ``settings`` inside (the dict is global: restored after)."""
    saved = dict(cholmod.options)
    cholmod.options.clear()
    cholmod.options.update(settings)
    try:
        yield
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)


def _lower_triplets(indptr, indices, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(rows, columns, kept)``: the entries on and below the diagonal of a CSC pattern of order ``n``.

    ``rows``, ``columns`` int64 ``(k,)``; ``kept`` ``(k,)`` their positions among the pattern's
    entries, or None when every entry is kept. CHOLMOD reads only this triangle (``uplo='L'``), and
    cvxopt's triplet constructor costs ~30 ns an entry: a pattern with both triangles is built at half
    the cost.
    """
    indptr = np.asarray(indptr, dtype=np.int64)
    columns = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    rows = np.asarray(indices, dtype=np.int64)
    lower = rows >= columns
    if lower.all():
        return rows, columns, None
    kept = np.flatnonzero(lower)
    return rows[kept], columns[kept], kept


def _as_index_matrix(values):
    from cvxopt import matrix

    return matrix(np.ascontiguousarray(values, dtype=np.int64))


def _lower_matrix(indptr, indices, n: int):
    """``(matrix, gather)``: the cvxopt ``spmatrix`` of a pattern's lower triangle, and where its values come from.

    ``gather`` ``(k,)`` int64: the position, among the pattern's entries, of each value in cvxopt's
    storage order (``matrix.V = data[gather]``), or None when that is the pattern's own order.
    Found by storing the positions 1..k as the values and reading them back (cvxopt sorts the rows
    of each column).
    """
    from cvxopt import matrix, spmatrix

    rows, columns, kept = _lower_triplets(indptr, indices, n)
    count = rows.shape[0]
    # cvxopt copies every array it is given: ours are dropped before it builds the matrix, so that
    # its buffers reuse their memory instead of touching new pages (on parking-garage's 260k
    # entries ~1,500 fewer page faults, ~2.5 ms of a run)
    row_index, column_index = _as_index_matrix(rows), _as_index_matrix(columns)
    del rows, columns
    lower = spmatrix(matrix(np.arange(1.0, count + 1.0)), row_index, column_index, (n, n))
    del row_index, column_index
    stored = np.array(lower.V).ravel()
    if stored.shape != (count,):
        raise ValueError("indices must not repeat a row within a column")
    gather = stored.astype(np.int64) - 1
    if kept is not None:
        return lower, kept[gather]
    # the stored values are the distinct 1..k: in the input's order exactly when increasing
    return lower, None if bool((stored[1:] > stored[:-1]).all()) else gather


class SparseCholesky:
    """``P A Pᵀ = L Lᵀ`` of a sparse symmetric positive-definite matrix by CHOLMOD's supernodal method.

    The pattern is analysed once, here: ``indptr`` ``(n+1,)`` and ``indices`` ``(nnz,)`` of a CSC
    matrix of order ``n`` (any integer type) whose entries on and below the diagonal are used
    (stored entries above it are ignored), ordered by ``ordering`` (a name in :data:`ORDERINGS`)
    or, given ``permutation`` ``(n,)`` (``permutation[k]`` = the row/column eliminated k-th, e.g.
    from :func:`block_permutation`), by that order, postordered. Then, any number of times,
    :meth:`factorize` with new ``data`` ``(nnz,)`` on the same pattern, :meth:`solve`, and
    :meth:`factor` for L itself. ``threads`` caps the BLAS under CHOLMOD during its work
    (:class:`posegraph.linalg.native_threads.NativeThreads`).
    """

    def __init__(self, indptr, indices, n: int, ordering: str = "amd", threads: int | None = 1, *, permutation=None):
        from posegraph.linalg.native_threads import NativeThreads

        self._cholmod = _require()
        if ordering not in ORDERINGS:
            raise ValueError(f"CHOLMOD ordering must be one of {ORDERINGS}, got {ordering!r}")
        self.n = int(n)
        indptr = np.asarray(indptr)
        if indptr.shape != (self.n + 1,) or np.shape(indices) != (int(indptr[-1]),):
            raise ValueError(f"indptr must have shape ({self.n + 1},) and indices ({int(indptr[-1])},)")
        self.nnz = int(indptr[-1])
        self._matrix, self._gather = _lower_matrix(indptr, indices, self.n)
        self._threads = NativeThreads(threads)
        self.threads_active = self._threads.active
        self.ordering = ordering if permutation is None else "given"
        if permutation is None and ordering == "amd" and self.n:
            permutation = _pattern_order(self._matrix)  # the lower matrix just built: no second copy for AMD
        elif permutation is None and ordering in VERTEX_ORDERINGS:
            permutation = fill_reducing_order(indptr, indices, self.n, ordering)
        elif permutation is None and ordering == "natural":
            permutation = np.arange(self.n)
        self._analyse(permutation)
        self._factorized = False
        self._permutation = None
        self._paths = None  # SupernodalPaths of the last numeric factor, read on demand

    def _analyse(self, permutation) -> None:
        cholmod = self._cholmod
        if permutation is None:  # "default": CHOLMOD's own choice
            with _options(cholmod, supernodal=2, postorder=True), self._threads:
                self._symbolic = cholmod.symbolic(self._matrix, uplo="L")
            return
        permutation = np.asarray(permutation)
        if permutation.shape != (self.n,) or not np.array_equal(np.sort(permutation), np.arange(self.n)):
            raise ValueError(f"permutation must be a permutation of range({self.n})")
        with _options(cholmod, supernodal=2, postorder=True, nmethods=1), self._threads:
            self._symbolic = cholmod.symbolic(self._matrix, p=_as_index_matrix(permutation), uplo="L")

    @property
    def factor_bytes(self) -> int | None:
        """Bytes the numeric factorisation will hold, known from the analysis: L's supernodal values
        (``xsize`` doubles, amalgamation's explicit zeros included), its row structure (``ssize``
        indices) and the largest update matrix (``maxcsize`` doubles) — ``8·(xsize + ssize +
        maxcsize)``, read from CHOLMOD's ``cholmod_factor`` (:func:`_supernodal_sizes`). None when
        the factor was closed or the structure does not read as CHOLMOD 3's supernodal factor.
        """
        if self._symbolic is None:
            return None
        sizes = _supernodal_sizes(self._symbolic, self.n)
        return None if sizes is None else 8 * (sizes["xsize"] + sizes["ssize"] + sizes["maxcsize"])

    def factorize(self, data) -> None:
        """Numeric factorisation for values ``data`` ``(nnz,)`` on the analysed pattern.

        Raises :class:`NotPositiveDefiniteError` when a pivot is not positive, an entry is not
        finite (CHOLMOD would let a NaN through to a NaN solution) or the factor's diagonal
        overflows.
        """
        from cvxopt import matrix

        if self._symbolic is None:
            raise RuntimeError("the factor was closed (close() or factor(release=True)); build a new SparseCholesky")
        data = np.asarray(data, dtype=np.float64)
        if data.shape != (self.nnz,):
            raise ValueError(f"data must have shape ({self.nnz},), got {data.shape}")
        self._factorized = False
        self._permutation = None
        self._paths = None  # views of the factor CHOLMOD is about to overwrite
        if not np.isfinite(data).all():
            raise NotPositiveDefiniteError("matrix has non-finite entries")
        self._matrix.V = matrix(data if self._gather is None else data[self._gather])
        cholmod = self._cholmod
        try:
            with _options(cholmod, supernodal=2), self._threads:
                cholmod.numeric(self._matrix, self._symbolic)
                diagonal = np.array(cholmod.diag(self._symbolic)).ravel()
        except ArithmeticError as err:
            raise NotPositiveDefiniteError(f"CHOLMOD: matrix not positive definite (column {err.args[0]} of {self.n})") from err
        except ValueError as err:  # CHOLMOD's other numerical failures ("factorization failed")
            raise NotPositiveDefiniteError(f"CHOLMOD: {err}") from err
        if not (np.isfinite(diagonal).all() and (diagonal > 0).all()):
            raise NotPositiveDefiniteError("CHOLMOD: the factor's diagonal is not finite and positive")
        self._factorized = True

    def _check_factorized(self) -> None:
        if not self._factorized:
            raise RuntimeError("factorize() must succeed before solve() or factor()")

    def solve(self, rhs) -> np.ndarray:
        """``x`` with ``A x = rhs`` for the last factorised ``A``; ``rhs`` ``(n,)`` or ``(n, k)``, same shape out."""
        self._check_factorized()
        rhs = np.asarray(rhs, dtype=np.float64)
        if rhs.ndim not in (1, 2) or rhs.shape[0] != self.n:
            raise ValueError(f"rhs must have shape ({self.n},) or ({self.n}, k), got {rhs.shape}")
        return self._apply(rhs, 0)

    def unit_forward(self, columns, with_rows: bool = False):
        """``Y`` ``(r, c)`` with ``Eᵀ A⁻¹ E = YᵀY`` for the unit columns ``E`` ``(n, c)`` at unknowns ``columns``:
        the rows of ``L⁻¹ P E`` on the elimination-tree paths of ``columns``
        (:class:`posegraph.linalg.supernodal.SupernodalPaths`); where the factor cannot be read, all
        ``n`` rows by cvxopt's dense solves (``sys=7``: ``P b``, then ``sys=4``: ``L⁻¹ b``). ``with_rows``:
        ``(rows (r,), Y)`` with the position of each row of ``Y`` in ``L⁻¹ P E`` (ascending)."""
        self._check_factorized()
        columns = np.asarray(columns, dtype=np.int64)
        paths = self._supernodal_paths()
        if paths:
            rows, y = paths.forward_rows(columns)
        else:
            unit = np.zeros((self.n, columns.shape[0]))
            unit[columns, np.arange(columns.shape[0])] = 1.0
            rows, y = np.arange(self.n), self.forward(unit)
        return (rows, y) if with_rows else y

    @property
    def factor_flops(self) -> float | None:
        """Floating-point operations of the last numeric factorisation, from its supernodes
        (:attr:`posegraph.linalg.supernodal.SupernodalPaths.flops`); None where the factor cannot be read."""
        self._check_factorized()
        paths = self._supernodal_paths()
        return paths.flops if paths else None

    def _supernodal_paths(self):
        """The :class:`~posegraph.linalg.supernodal.SupernodalPaths` view of the last numeric factor, read
        once per factorisation; False where it cannot be trusted (the callers then use dense solves)."""
        from posegraph.linalg.supernodal import SupernodalPaths

        if self._paths is None:
            self._paths = SupernodalPaths.read(self._symbolic, self.n) or False
        return self._paths

    def forward(self, rhs: np.ndarray) -> np.ndarray:
        """``L⁻¹ P rhs`` ``(n,)`` or ``(n, k)``: the first half of :meth:`solve` (``solve = backward ∘ forward``)."""
        self._check_factorized()
        return self._apply(self._apply(np.asarray(rhs, dtype=np.float64), 7), 4)

    def backward(self, rhs: np.ndarray) -> np.ndarray:
        """``Pᵀ L⁻ᵀ rhs`` ``(n,)`` or ``(n, k)``: the second half of :meth:`solve`."""
        self._check_factorized()
        return self._apply(self._apply(np.asarray(rhs, dtype=np.float64), 5), 8)

    def _apply(self, rhs: np.ndarray, system: int) -> np.ndarray:
        """cvxopt's ``solve(F, B, sys=system)`` on a copy of ``rhs`` ``(n,)`` or ``(n, k)``."""
        from cvxopt import matrix

        columns = matrix(np.asfortranarray(rhs.reshape(self.n, -1)))
        with self._threads:
            self._cholmod.solve(self._symbolic, columns, sys=system)
        return np.array(columns).reshape(rhs.shape)

    @property
    def permutation(self) -> np.ndarray:
        """``(n,)`` int64: the order CHOLMOD eliminates in, ``A[perm][:, perm] = L Lᵀ`` (after :meth:`factorize`)."""
        self._check_factorized()
        if self._permutation is None:
            # sys=7 solves Pᵀ x = b, i.e. x = P b: P applied to 0..n-1 is the permutation itself.
            positions = self._apply(np.arange(self.n, dtype=np.float64), 7)
            self._permutation = np.rint(positions).astype(np.int64)
        return self._permutation

    def factor(self, release: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The factor of the last factorised ``A``: ``(indptr, indices, data, permutation)``.

        ``indptr`` ``(n+1,)``, ``indices`` ``(nnz_L,)`` int64 and ``data`` ``(nnz_L,)``: L, lower
        triangular, as CSC (rows sorted, diagonal first in each column; the explicit zeros of
        CHOLMOD's amalgamated supernodes included); ``permutation`` ``(n,)`` as :attr:`permutation`,
        so that ``A[perm][:, perm] = L Lᵀ``. cvxopt's ``getfactor`` turns the factor it reads into a
        symbolic one. By default L is therefore computed on a second factor analysed with that
        permutation as given (one more analysis and numeric factorisation) and this object stays
        usable. ``release=True`` hands over this object's own factor instead — no second
        factorisation, one copy of L fewer in memory — after which it is closed (:meth:`close`).
        """
        permutation = self.permutation
        cholmod = self._cholmod
        with _options(cholmod, supernodal=2, postorder=False, nmethods=1), self._threads:
            if release:
                source = self._symbolic
                self.close()
            else:
                source = cholmod.symbolic(self._matrix, p=_as_index_matrix(permutation), uplo="L")
                cholmod.numeric(self._matrix, source)
            lower = cholmod.getfactor(source)
        del source  # symbolic now: getfactor moved L out of it
        parts = lower.CCS  # cvxopt copies here; the views below do not
        del lower
        indptr, indices, data = (np.asarray(part).ravel() for part in parts)
        return indptr.astype(np.int64, copy=False), indices.astype(np.int64, copy=False), data, permutation.copy()

    def close(self) -> None:
        """Drop the factor and the copy of the matrix now (otherwise when the object is collected)."""
        self._factorized = False
        self._paths = None
        self._symbolic = None
        self._matrix = None


def _supernodal_sizes(capsule, n: int) -> dict[str, int] | None:
    """The size fields of the analysed supernodal factor in cvxopt's capsule, or None.

    Read in place (:func:`posegraph.linalg.factor_struct.read_factor`); trusted only if it describes this
    factor — ``n`` as analysed, the supernodal flag set, ``0 < nsuper ≤ n`` and ``xsize ≥ n`` — so that
    another CHOLMOD's layout gives None, not a wrong size.
    """
    from posegraph.linalg.factor_struct import read_factor

    fields = read_factor(capsule)
    if fields is None or fields["n"] != n or fields["is_super"] != 1:
        return None
    if not 0 < fields["nsuper"] <= n or fields["xsize"] < n:
        return None
    return {key: fields[key] for key in ("nsuper", "ssize", "xsize", "maxcsize")}


NESTED_DISSECTION_VERTICES = 10_000
"""From this many free vertices, ``"auto"`` orders by nested dissection instead of AMD
(:func:`auto_ordering`). Measured with the system CHOLMOD (vertex-graph ordering + analysis, then
one numeric factorisation): sphere 50k poses AMD 0.23 + 4.78 s, nested dissection 0.40 + 2.42 s;
4-layer slab 50k 0.18 + 10.2 s against 0.43 + 6.7 s; 25³ cube 0.06 + 5.8 s against 0.13 + 2.6 s.
Below a few thousand vertices the two factorise alike and AMD analyses twice as fast. With the
cvxopt route and pymetis, ``docs/cholesky.md``."""


def auto_ordering(num_vertices: int) -> str:
    """The ordering ``"auto"`` stands for on a system of ``num_vertices`` free vertices (AMD without pymetis)."""
    if num_vertices < NESTED_DISSECTION_VERTICES:
        return "amd"
    return "nesdis" if nested_dissection_available() else "amd"


def nested_dissection_available() -> bool:
    """Whether ``"nesdis"`` orders can be made: the pymetis wheel is installed (not imported here)."""
    import importlib.util

    return importlib.util.find_spec("pymetis") is not None


def _adjacency(indptr, indices, n: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR ``(xadj, adjncy)`` int64 of the symmetric graph of a pattern, without self-loops (METIS's input)."""
    columns = np.repeat(np.arange(n, dtype=np.int64), np.diff(np.asarray(indptr, dtype=np.int64)))
    rows = np.asarray(indices, dtype=np.int64)
    off = rows != columns
    key = np.unique(np.concatenate([rows[off] * n + columns[off], columns[off] * n + rows[off]]))
    source, target = key // n, key % n
    xadj = np.concatenate([[0], np.cumsum(np.bincount(source, minlength=n))]).astype(np.int64)
    return xadj, target


def _nested_dissection(xadj: np.ndarray, adjncy: np.ndarray, n: int) -> np.ndarray:
    """METIS nested dissection (``METIS_NodeND`` with its defaults) of the graph ``(xadj, adjncy)``, via pymetis."""
    try:
        import pymetis
    except ImportError as err:
        raise ImportError(f"nested dissection needs pymetis ({err}); pip install pymetis, or use ordering 'amd'") from err
    if adjncy.size == 0:  # METIS wants at least one edge; with none every order is fill-free
        return np.arange(n, dtype=np.int64)
    order, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(xadj, adjncy))
    return np.asarray(order, dtype=np.int64)


def fill_reducing_order(indptr, indices, n: int, method: str = "amd") -> np.ndarray:
    """A fill-reducing order ``(n,)`` int64 (``order[k]`` = the node eliminated k-th) of a symmetric pattern.

    ``indptr``/``indices``: CSC of the pattern (for ``"amd"`` the entries on and below the
    diagonal are read; nested dissection symmetrises); ``method`` one of :data:`VERTEX_ORDERINGS`.
    Used on the *vertex* graph of a block system (see :func:`block_permutation`): p nodes instead
    of 6p, with 36 times fewer entries, for the same elimination order of the blocks.
    """
    if method not in VERTEX_ORDERINGS:
        raise ValueError(f"method must be one of {VERTEX_ORDERINGS}, got {method!r}")
    n = int(n)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if method != "amd":
        xadj, adjncy = _adjacency(indptr, indices, n)
        return _remembered("nesdis", (xadj, adjncy), lambda: _nested_dissection(xadj, adjncy, n))
    rows, columns, _ = _lower_triplets(indptr, indices, n)
    return _remembered("amd", (rows, columns), lambda: _approximate_minimum_degree(rows, columns, n))


def _approximate_minimum_degree(rows: np.ndarray, columns: np.ndarray, n: int) -> np.ndarray:
    """cvxopt's AMD order of the symmetric pattern whose lower triangle is ``rows``, ``columns``."""
    _require()
    from cvxopt import spmatrix

    return _pattern_order(spmatrix(1.0, _as_index_matrix(rows), _as_index_matrix(columns), (n, n)))


def _pattern_order(lower) -> np.ndarray:
    """cvxopt's AMD order ``(n,)`` int64 of the symmetric pattern of the cvxopt ``spmatrix`` ``lower``
    (its lower triangle read; values ignored)."""
    from cvxopt import amd

    with _options(amd):
        order = amd.order(lower, uplo="L")
    return np.array(order, dtype=np.int64).ravel()


_LAST_ORDERS: dict = {}
"""Per method, the last pattern ordered and its order: the chordal start and the solver order the
same vertex graph (the free vertices, one node each), so the second asks for an order already made
(AMD on parking-garage ~1 ms; nested dissection of a 50k-pose graph ~0.4 s)."""


def _remembered(method: str, pattern: tuple, compute) -> np.ndarray:
    """``compute()``'s order for ``pattern`` (a tuple of arrays that determines it), or a copy of the
    last one made by ``method`` if that was for an equal pattern."""
    last = _LAST_ORDERS.get(method)
    if last is None or not all(np.array_equal(a, b) for a, b in zip(last[0], pattern)):
        last = _LAST_ORDERS[method] = (pattern, compute())
    return last[1].copy()


def block_permutation(order, block) -> np.ndarray:
    """The scalar permutation eliminating the blocks in the order ``order`` ``(p,)``.

    ``block``: the size of every block (an int: ``(block·p,)``), or ``(p,)`` sizes of blocks laid
    out one after the other (block ``c`` owns rows ``Σ_{c'<c} block[c'] ..``)."""
    order = np.asarray(order, dtype=np.int64)
    if np.ndim(block) == 0:
        return (block * order[:, None] + np.arange(block)[None, :]).reshape(-1)
    sizes = np.asarray(block, dtype=np.int64)
    offsets = np.concatenate(([0], np.cumsum(sizes)))[:-1]
    taken = sizes[order]
    within = np.arange(int(taken.sum())) - np.repeat(np.cumsum(taken) - taken, taken)
    return np.repeat(offsets[order], taken) + within


def block_cholesky(
    indptr, indices, block_indptr, block_indices, num_blocks: int, block: int, ordering: str = "auto",
    threads: int | None = 1,
) -> SparseCholesky:
    """:class:`SparseCholesky` of a matrix made of ``block``×``block`` blocks, analysed once
    (``block``: an int, or the ``(num_blocks,)`` sizes of blocks of several sizes, :func:`block_permutation`).

    ``indptr``/``indices``: the scalar CSC pattern (order ``block·num_blocks``);
    ``block_indptr``/``block_indices``: its block (vertex) pattern, one entry per stored block.
    ``ordering`` ``"auto"`` (:func:`auto_ordering`) or one of :data:`VERTEX_ORDERINGS` orders the
    vertex graph and expands the order to the blocks (:func:`fill_reducing_order`,
    :func:`block_permutation`); any other name in :data:`ORDERINGS` applies to the scalar pattern.
    """
    if ordering == "auto":
        ordering = auto_ordering(num_blocks)
    n = block * num_blocks if np.ndim(block) == 0 else int(np.sum(block))
    if ordering not in VERTEX_ORDERINGS:
        return SparseCholesky(indptr, indices, n, ordering, threads)
    order = fill_reducing_order(block_indptr, block_indices, num_blocks, ordering)
    factor = SparseCholesky(indptr, indices, n, ordering, threads, permutation=block_permutation(order, block))
    factor.ordering = ordering
    return factor


def block_factor_bytes(block_indptr, block_indices, num_blocks: int, block: int, ordering: str = "auto") -> int | None:
    """Bytes the supernodal factor of a matrix of dense ``block``×``block`` blocks on this vertex
    pattern would hold, foreseen from the vertex pattern alone, or None when CHOLMOD does not read.

    The vertex pattern ordered as :func:`block_cholesky` orders it (``"natural"``: as it is;
    ``"default"``, which orders the scalar pattern: AMD) is analysed symbolically — 1/block² of the
    entries, ~0.1 s where the scalar analysis takes ~6 s (200k-pose sphere) — and its sizes scaled:
    ``8·(block²·(xsize + maxcsize) + block·ssize)`` (:attr:`SparseCholesky.factor_bytes`). The
    vertex analysis amalgamates supernodes as the scalar one does at block size, so this is an
    estimate from above: 3.87 GiB for the 3.37 GiB the scalar analysis foresees on that sphere.
    """
    if ordering == "auto":
        ordering = auto_ordering(num_blocks)
    if ordering == "natural":
        order = np.arange(num_blocks)
    else:
        order = fill_reducing_order(block_indptr, block_indices, num_blocks, ordering if ordering in VERTEX_ORDERINGS else "amd")
    vertices = SparseCholesky(block_indptr, block_indices, num_blocks, permutation=order)
    sizes = _supernodal_sizes(vertices._symbolic, vertices.n)
    vertices.close()
    if sizes is None:
        return None
    return 8 * (block**2 * (sizes["xsize"] + sizes["maxcsize"]) + block * sizes["ssize"])
