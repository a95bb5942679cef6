"""Sparse symmetric positive-definite solvers for the normal equations.

Every backend is built once per graph from a :class:`~posegraph.solve.sparsity.HessianPattern`
(symbolic work: ordering, elimination tree) and then, each iteration,
``factorize(data)`` with new values of the lower triangle (same pattern) and
``solve(rhs)``. :func:`make_linear_solver` picks one by name:

``"cholmod"``
    CHOLMOD's supernodal Cholesky, called directly on the system library
    (:mod:`posegraph.cholmod`, no scipy import) or, where that binding cannot be used, through
    scikit-sparse. The analysis (fill-reducing ordering, elimination tree, supernodes) runs once;
    each iteration only the numeric factorisation. It reads the lower triangle directly. Ordering: AMD by default
    (on the pose graphs here it factors as fast as METIS / nested dissection and analyses
    several times faster; figures in ``docs/solver.md``). The system OpenBLAS and the OpenMP loops
    under CHOLMOD run one thread during the factorisation and solves by default
    (:class:`~posegraph.native_threads.NativeThreads`): for these sizes on a shared 2-core machine
    that is 1.25× (idle) to 2.6× (other jobs running) faster than CHOLMOD's own four OpenMP threads
    and two BLAS threads.
``"scipy"``
    Needs nothing beyond scipy wheels. SuperLU with no pivoting (``diag_pivot_thresh=0``,
    ``SymmetricMode``) on a matrix permuted once per graph: SuperLU's minimum-degree ordering of
    the *vertex* graph (p×p instead of 6p×6p), postordered along its elimination tree so that
    each subtree is contiguous (this makes SuperLU's supernodes large: ~3× faster numeric
    factorisation than the same ordering un-postordered) and expanded to the 6×6 blocks.
    Without pivoting on a symmetric positive-definite matrix LU is Cholesky in disguise
    (U = D Lᵀ), so it is stable.
``"auto"``
    ``"cholmod"`` when either CHOLMOD path works, else ``"scipy"``.

A matrix that is not positive definite raises :class:`NotPositiveDefiniteError`
(LM then raises λ; Gauss-Newton stops).
"""

from __future__ import annotations

import warnings

import numpy as np

from posegraph import cholmod as cholmod_library
from posegraph.cholmod import NotPositiveDefiniteError
from posegraph.native_threads import NativeThreads
from posegraph.solve.sparsity import BLOCK, HessianPattern, lower_csc

__all__ = [
    "NotPositiveDefiniteError",
    "LinearSolver",
    "CholmodSolver",
    "BlasThreads",
    "NativeThreads",
    "ScipySolver",
    "cholmod_available",
    "scikit_sparse_available",
    "make_linear_solver",
]


BlasThreads = NativeThreads
"""The former name of :class:`posegraph.native_threads.NativeThreads` (which now also covers OpenMP)."""


def scikit_sparse_available() -> bool:
    """Whether scikit-sparse's CHOLMOD wrapper can be imported."""
    try:
        from sksparse import cholmod  # noqa: F401
    except Exception:  # ImportError, or a broken shared library
        return False
    return True


def cholmod_available() -> bool:
    """Whether CHOLMOD can be used: the direct binding (:func:`posegraph.cholmod.load`) or scikit-sparse."""
    return cholmod_library.load() is not None or scikit_sparse_available()


class LinearSolver:
    """Interface: ``factorize(data)`` then ``solve(rhs)``; ``name`` says which backend and ordering ran."""

    name: str = "abstract"

    def factorize(self, data: np.ndarray) -> None:  # pragma: no cover - interface
        """Numeric factorisation of the matrix whose lower-triangle CSC ``data`` is given."""
        raise NotImplementedError

    def solve(self, rhs: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        """Solution ``x`` of ``A x = rhs`` for the last factorised ``A``."""
        raise NotImplementedError


class CholmodSolver(LinearSolver):
    """CHOLMOD supernodal Cholesky; symbolic analysis once in the constructor.

    ``backend``: ``"direct"`` (:class:`posegraph.cholmod.SparseCholesky`), ``"scikit-sparse"``,
    or ``"auto"`` (direct when the system library passes its checks, else scikit-sparse).
    """

    ORDERINGS = tuple(cholmod_library.ORDERINGS)

    def __init__(self, pattern: HessianPattern, ordering: str = "amd", blas_threads: int | None = 1, backend: str = "auto"):
        if ordering not in self.ORDERINGS:
            raise ValueError(f"CHOLMOD ordering must be one of {self.ORDERINGS}, got {ordering!r}")
        if backend not in ("auto", "direct", "scikit-sparse"):
            raise ValueError(f"backend must be 'auto', 'direct' or 'scikit-sparse', got {backend!r}")
        if backend == "auto":
            backend = "direct" if cholmod_library.load() is not None else "scikit-sparse"
        self._pattern = pattern
        self.ordering = ordering
        self.backend = backend
        if backend == "direct":
            # Ordered on the vertex graph (p nodes, one entry per 6×6 block) and expanded to the
            # blocks: the same elimination order as ordering the 6p×6p pattern, found from 36
            # times fewer entries (parking-garage: analysis 6.8 → 5.7 ms, factorisation 9.7 →
            # 8.0 ms with AMD, the block postorder helping the supernodes).
            self._cholesky = cholmod_library.block_cholesky(
                pattern.indptr, pattern.indices, pattern.block_indptr, pattern.block_indices,
                pattern.num_variables, BLOCK, ordering, blas_threads,
            )  # fmt: skip
            active = self._cholesky.threads_active
        else:
            from sksparse import cholmod

            self._cholmod = cholmod
            structure = lower_csc(pattern, np.ones(pattern.nnz))
            with warnings.catch_warnings():
                # scikit-sparse warns when it converts index types; harmless and once per graph
                warnings.simplefilter("ignore", cholmod.CholmodTypeConversionWarning)
                self._factor = cholmod.analyze(structure, mode="supernodal", ordering_method=ordering)
            self._threads = NativeThreads(blas_threads)
            active = self._threads.active
        threads = f", {blas_threads} thread{'s' if blas_threads != 1 else ''}" if active else ""
        via = "" if backend == "direct" else " via scikit-sparse"
        self.name = f"cholmod (supernodal, {ordering}{threads}){via}"

    def factorize(self, data: np.ndarray) -> None:
        if self.backend == "direct":
            self._cholesky.factorize(data)
            return
        matrix = lower_csc(self._pattern, data)
        cholmod = self._cholmod
        try:
            with warnings.catch_warnings(), self._threads:
                warnings.simplefilter("error", cholmod.CholmodWarning)
                warnings.simplefilter("ignore", cholmod.CholmodTypeConversionWarning)
                self._factor.cholesky_inplace(matrix)
        except (cholmod.CholmodNotPositiveDefiniteError, cholmod.CholmodWarning) as err:
            raise NotPositiveDefiniteError(str(err)) from err

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self.backend == "direct":
            return self._cholesky.solve(rhs)
        with self._threads:
            return self._factor(rhs)


def vertex_graph(pattern: HessianPattern):
    """``(p, p)`` symmetric 0/1 pattern of the block graph (free vertices, diagonal included), scipy CSC."""
    import scipy.sparse as sp

    p = pattern.num_variables
    cols = np.repeat(np.arange(p * BLOCK), np.diff(pattern.indptr))
    rows = pattern.indices.astype(np.int64)
    keep = (rows % BLOCK == 0) & (cols % BLOCK == 0)  # one entry per stored block
    br, bc = rows[keep] // BLOCK, cols[keep] // BLOCK
    lower = sp.csc_matrix((np.ones(br.shape[0]), (br, bc)), shape=(p, p))
    return (lower + lower.T).tocsc()


def elimination_tree(pattern) -> np.ndarray:
    """Parent of each node in the elimination tree of a symmetric pattern (``-1`` for roots).

    Liu's algorithm with path compression (Davis, *Direct Methods for Sparse Linear Systems*,
    §4.1), reading the strictly upper entries ``i < k`` of each column ``k``.
    """
    n = pattern.shape[0]
    parent = [-1] * n
    ancestor = [-1] * n
    indptr, indices = pattern.indptr, pattern.indices
    for k in range(n):
        for i in indices[indptr[k] : indptr[k + 1]].tolist():
            while i != -1 and i < k:
                following = ancestor[i]
                ancestor[i] = k
                if following == -1:
                    parent[i] = k
                i = following
    return np.asarray(parent, dtype=np.int64)


def tree_postorder(parent: np.ndarray) -> np.ndarray:
    """Nodes of a forest in depth-first postorder (children before parents, subtrees contiguous)."""
    n = parent.shape[0]
    children: list[list[int]] = [[] for _ in range(n)]
    roots: list[int] = []
    for v in range(n - 1, -1, -1):  # reversed so that children lists come out in ascending order
        (children[parent[v]] if parent[v] >= 0 else roots).append(v)
    order: list[int] = []
    stack: list[tuple[int, bool]] = [(r, False) for r in roots]
    while stack:
        v, expanded = stack.pop()
        if expanded:
            order.append(v)
            continue
        stack.append((v, True))
        stack.extend((c, False) for c in children[v])
    return np.asarray(order, dtype=np.int64)


def vertex_ordering(pattern: HessianPattern) -> np.ndarray:
    """Fill-reducing order of the free vertices: SuperLU's MMD on AᵀA+A of the vertex graph, postordered.

    Returns ``order`` with ``order[new] = old`` (block-column indices).
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    graph = vertex_graph(pattern)
    p = graph.shape[0]
    if p == 0:
        return np.zeros(0, dtype=np.int64)
    # Only the pattern matters for the ordering; a diagonally dominant matrix on it factors trivially.
    degree = np.asarray(graph.sum(axis=0)).ravel()
    dominant = (sp.diags(degree + 1.0) - 0.5 * graph).tocsc()
    lu = splu(dominant, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    order = np.argsort(lu.perm_c)
    permuted = graph[order][:, order].tocsc()
    return order[tree_postorder(elimination_tree(permuted))]


class ScipySolver(LinearSolver):
    """SuperLU (scipy) without pivoting on the full symmetric matrix, permuted once per graph."""

    def __init__(self, pattern: HessianPattern):
        import scipy.sparse as sp

        self._sparse = sp
        self._pattern = pattern
        d = pattern.dimension
        order = vertex_ordering(pattern)
        self.permutation = (BLOCK * order[:, None] + np.arange(BLOCK)[None, :]).ravel()
        # Map from the lower-triangle data to the permuted full matrix's CSC data, computed by
        # pushing the positions 0..nnz-1 through the same symmetrisation and permutation.
        positions = np.arange(pattern.nnz, dtype=np.float64) + 1.0  # +1: keep explicit zeros apart
        lower = lower_csc(pattern, positions)
        strict = sp.tril(lower, k=-1, format="csc")
        full = (lower + strict.T).tocsc()
        full = full[self.permutation][:, self.permutation].tocsc()
        full.sort_indices()
        self._gather = full.data.astype(np.int64) - 1
        self._indices = full.indices.astype(np.int32)
        self._indptr = full.indptr.astype(np.int32)
        self._shape = (d, d)
        self._lu = None
        self.name = "scipy (SuperLU, no pivoting, postordered vertex MMD)"

    def factorize(self, data: np.ndarray) -> None:
        from scipy.sparse.linalg import splu

        matrix = self._sparse.csc_matrix((data[self._gather], self._indices, self._indptr), shape=self._shape)
        try:
            lu = splu(
                matrix,
                permc_spec="NATURAL",
                diag_pivot_thresh=0.0,
                options={"SymmetricMode": True},
            )
        except RuntimeError as err:  # "Factor is exactly singular"
            raise NotPositiveDefiniteError(str(err)) from err
        self._lu = lu

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self._lu is None:
            raise RuntimeError("factorize() must be called before solve()")
        x = np.empty_like(rhs, dtype=np.float64)
        x[self.permutation] = self._lu.solve(np.asarray(rhs, dtype=np.float64)[self.permutation])
        return x


def make_linear_solver(
    kind: str, pattern: HessianPattern, ordering: str = "auto", blas_threads: int | None = 1
) -> LinearSolver:
    """Build the backend ``kind`` (``"auto"``, ``"cholmod"`` or ``"scipy"``) for ``pattern``.

    ``ordering`` and ``blas_threads`` apply to CHOLMOD (``"auto"`` means AMD; ``blas_threads=None``
    leaves OpenBLAS's own setting). Asking for ``"cholmod"`` without scikit-sparse raises
    ``ImportError`` with the install hint.
    """
    if kind == "auto":
        kind = "cholmod" if cholmod_available() else "scipy"
    if kind == "cholmod":
        if not cholmod_available():
            raise ImportError(
                "linear_solver='cholmod' needs the CHOLMOD library (apt-get install libsuitesparse-dev) "
                f"[{cholmod_library.unavailable_reason()}] or scikit-sparse (pip install 'posegraph[fast]'); "
                "use linear_solver='scipy' or 'auto'"
            )
        if ordering == "auto":
            ordering = cholmod_library.auto_ordering(pattern.num_variables)
        return CholmodSolver(pattern, ordering, blas_threads)
    if kind == "scipy":
        return ScipySolver(pattern)
    raise ValueError(f"unknown linear solver {kind!r}: expected 'auto', 'cholmod' or 'scipy'")
