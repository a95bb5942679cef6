"""Sparse symmetric positive-definite solvers for the normal equations.

Every backend is built once per graph from a :class:`~posegraph.solve.sparsity.HessianPattern`
(symbolic work: ordering, elimination tree) and then, each iteration,
``factorize(data)`` with new values of the lower triangle (same pattern) and
``solve(rhs)``; ``factor()`` gives the last factor itself (for covariances by selected
inversion). :func:`make_linear_solver` picks one by name:

``"cholmod"``
    CHOLMOD's supernodal Cholesky from the cvxopt wheel (:mod:`posegraph.linalg.cholmod`, no scipy
    import). The fill-reducing ordering is computed on the vertex graph (p nodes, one entry per
    d×d block) and expanded to the blocks; the analysis runs once, each iteration only the
    numeric factorisation, which reads the lower triangle directly. Ordering ``"auto"``: AMD
    below :data:`posegraph.linalg.cholmod.NESTED_DISSECTION_VERTICES` free vertices, METIS nested
    dissection (pymetis) from there (figures in ``docs/cholesky.md``).
``"scipy"``
    Needs nothing beyond scipy wheels. SuperLU with no pivoting (``diag_pivot_thresh=0``,
    ``SymmetricMode``) on a matrix permuted once per graph: SuperLU's minimum-degree ordering of
    the *vertex* graph (p×p instead of 6p×6p), postordered along its elimination tree so that
    each subtree is contiguous (this makes SuperLU's supernodes large: ~3× faster numeric
    factorisation than the same ordering un-postordered) and expanded to the d×d blocks (d = ``pattern.block_size``, the group's tangent dimension).
    Without pivoting on a symmetric positive-definite matrix LU is Cholesky in disguise
    (U = D Lᵀ), so it is stable.
``"pcg"``
    No factorisation: conjugate gradients preconditioned by an aggregation multigrid W-cycle
    (pyamg, :mod:`posegraph.linalg.multigrid`) on the whole symmetric matrix in d×d block-CSR
    form (:func:`~posegraph.solve.sparsity.symmetric_blocks`), its near-null space the global
    motions at the current poses (:meth:`LinearSolver.linearized_at`). Memory linear in the
    graph, where a Cholesky factor grows as n log n on surface-like graphs. Each solve stops at
    a relative residual given by Eisenstat and Walker's forcing term (at most 1e-2, tightening as
    LM's gradient falls), ``tolerance`` at the least. Gives no factor (covariances factorise anyway).
``"auto"``
    ``"cholmod"`` when cvxopt imports, else ``"scipy"`` — unless the factor foreseen from the vertex
    pattern would not fit in the memory left (:func:`posegraph.linalg.multigrid.factorisation_fits`): then ``"pcg"`` for a caller
    that needs no factor (the optimizer), with a warning, or, without pyamg, an ``ImportError``
    that names the sizes and the install hint instead of a run the system would kill.

A matrix that is not positive definite — or whose factorisation fails numerically in any other
way (a zero or non-finite pivot, an overflow) — raises :class:`NotPositiveDefiniteError`
(LM then raises λ; Gauss-Newton stops). ``name`` says which backend and ordering ran.
"""

from __future__ import annotations

import numpy as np

from posegraph.linalg import cholmod as cholmod_library
from posegraph.linalg import multigrid
from posegraph.linalg.cholmod import NotPositiveDefiniteError
from posegraph.solve.sparsity import HessianPattern, lower_csc, symmetric_block_values, symmetric_blocks

__all__ = [
    "NotPositiveDefiniteError",
    "LinearSolver",
    "CholmodSolver",
    "ScipySolver",
    "MultigridSolver",
    "cholmod_available",
    "make_linear_solver",
]


def cholmod_available() -> bool:
    """Whether CHOLMOD can be used (cvxopt imports: :func:`posegraph.linalg.cholmod.load`)."""
    return cholmod_library.load() is not None


class LinearSolver:
    """Interface: ``factorize(data)`` then ``solve(rhs)`` and ``factor()``; ``name`` says which backend and ordering ran."""

    name: str = "abstract"

    def factorize(self, data: np.ndarray, shift: np.ndarray | None = None) -> None:  # pragma: no cover - interface
        """Numeric factorisation of the matrix whose lower-triangle CSC ``data`` is given, plus
        ``diag(shift)`` (``(dp,)``, LM's damping) when given; ``data`` itself is left unchanged."""
        raise NotImplementedError

    def solve(self, rhs: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        """Solution ``x`` of ``A x = rhs`` for the last factorised ``A``."""
        raise NotImplementedError

    def factor(self, release: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - interface
        """``(indptr, indices, data, permutation)``: the last factor L (lower-triangular CSC, int64
        indices) and the elimination order, with ``A[perm][:, perm] = L Lᵀ``. ``release=True``:
        the caller needs nothing more from this factorisation, which the backend may hand over
        instead of copying (solves then need a new backend)."""
        raise NotImplementedError

    holds_factorization: bool = True
    """Whether keeping the last factorisation for another solve later is cheap (a Cholesky factor
    serves the solver's chord steps); an iterative solver keeps nothing worth holding."""

    def release(self) -> None:
        """Drop what the last factorisation made if it is not held (the next factorize makes it anew)."""

    def confirm_convergence(self) -> bool:
        """Whether the last solve was exact enough for LM's convergence tests (a factorisation's is);
        an inexact solver that answers False solves the next system to its full tolerance."""
        return True

    def linearized_at(self, poses: np.ndarray, free: np.ndarray, group) -> None:
        """Told the poses ``(n, k, k)`` at which the next matrices are built (``free`` ``(n,)`` bool:
        the vertices with variables), once per linearisation; direct solvers need nothing of them
        (:class:`MultigridSolver` builds its near-null space)."""


def shifted(pattern: HessianPattern, data: np.ndarray, shift: np.ndarray | None) -> np.ndarray:
    """The lower-triangle ``data`` of ``H + diag(shift)``: a copy when ``shift`` is given, else ``data``."""
    if shift is None:
        return data
    out = np.array(data, dtype=np.float64, copy=True)
    out[pattern.diagonal] += shift
    return out


class CholmodSolver(LinearSolver):
    """CHOLMOD supernodal Cholesky (:func:`posegraph.linalg.cholmod.block_cholesky`); analysis once in the constructor."""

    ORDERINGS = cholmod_library.ORDERINGS

    def __init__(self, pattern: HessianPattern, ordering: str = "amd", blas_threads: int | None = 1):
        if ordering not in self.ORDERINGS:
            raise ValueError(f"CHOLMOD ordering must be one of {self.ORDERINGS}, got {ordering!r}")
        self.ordering = ordering
        self._cholesky = cholmod_library.block_cholesky(
            pattern.indptr, pattern.indices, pattern.block_indptr, pattern.block_indices,
            pattern.num_variables, _block_sizes(pattern), ordering, blas_threads,
        )  # fmt: skip
        threads = f", {blas_threads} BLAS thread{'s' if blas_threads != 1 else ''}" if self._cholesky.threads_active else ""
        self.name = f"cholmod (supernodal, {ordering}{threads}) via cvxopt"
        self._pattern = pattern

    def factorize(self, data: np.ndarray, shift: np.ndarray | None = None) -> None:
        self._cholesky.factorize(shifted(self._pattern, data, shift))

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._cholesky.solve(rhs)

    def factor(self, release: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return self._cholesky.factor(release)


def vertex_graph(pattern: HessianPattern):
    """``(p, p)`` symmetric 0/1 pattern of the block graph (free vertices, diagonal included), scipy CSC."""
    import scipy.sparse as sp

    p = pattern.num_variables
    lower = sp.csc_matrix((np.ones(pattern.block_indices.shape[0]), pattern.block_indices, pattern.block_indptr), shape=(p, p))
    return (lower + lower.T).tocsc()


def _block_sizes(pattern: HessianPattern):
    """The block size of a pattern's variables: one int for a pose graph, ``(p,)`` sizes with landmarks."""
    return pattern.block_size if pattern.point_size == 0 else pattern.sizes


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
        self.permutation = cholmod_library.block_permutation(order, _block_sizes(pattern))
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

    def factorize(self, data: np.ndarray, shift: np.ndarray | None = None) -> None:
        """SuperLU of the permuted matrix; :class:`NotPositiveDefiniteError` unless every pivot is finite and positive.

        (Without pivoting, LU of a symmetric matrix has U's diagonal = D of ``L D Lᵀ``: all
        positive exactly when the matrix is positive definite.)
        """
        from scipy.sparse.linalg import splu

        self._lu = None
        data = shifted(self._pattern, np.asarray(data, dtype=np.float64), shift)
        if not np.isfinite(data).all():
            raise NotPositiveDefiniteError("matrix has non-finite entries")
        matrix = self._sparse.csc_matrix((data[self._gather], self._indices, self._indptr), shape=self._shape)
        options = {"SymmetricMode": True}
        try:
            lu = splu(matrix, permc_spec="NATURAL", diag_pivot_thresh=0.0, options=options)
        except RuntimeError as err:  # "Factor is exactly singular"
            raise NotPositiveDefiniteError(f"SuperLU: {err}") from err
        pivots = lu.U.diagonal()
        if not (np.isfinite(pivots).all() and (pivots > 0).all()):
            raise NotPositiveDefiniteError("SuperLU: a pivot is not finite and positive: matrix not positive definite")
        self._lu = lu

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self._lu is None:
            raise RuntimeError("factorize() must succeed before solve()")
        x = np.empty_like(rhs, dtype=np.float64)
        x[self.permutation] = self._lu.solve(np.asarray(rhs, dtype=np.float64)[self.permutation])
        return x

    def factor(self, release: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """L = L_unit·√D from SuperLU's ``L_unit U`` (``U = D L_unitᵀ`` without pivoting); see :meth:`LinearSolver.factor`."""
        if self._lu is None:
            raise RuntimeError("factorize() must succeed before factor()")
        lu = self._lu
        if not (np.array_equal(lu.perm_r, np.arange(self._shape[0])) and np.array_equal(lu.perm_c, lu.perm_r)):
            raise RuntimeError("SuperLU pivoted; its factor is not a Cholesky factor")  # not with diag_pivot_thresh=0
        if release:
            self._lu = None
        lower = (lu.L @ self._sparse.diags(np.sqrt(lu.U.diagonal()))).tocsc()
        lower.sort_indices()
        return lower.indptr.astype(np.int64), lower.indices.astype(np.int64), lower.data, self.permutation.copy()


FORCING_MAX, FORCING_GAMMA, FORCING_ALPHA = 1e-2, 0.9, 2.0
"""Eisenstat and Walker ("Choosing the forcing terms in an inexact Newton method", 1996), choice 2
with their γ = 0.9, α = 2: loose solves while LM's gradient falls slowly, tight as it converges."""


CONVERGENCE_TOLERANCE = 1e-4
"""A step solved to this relative residual or tighter is trusted by LM's convergence tests: CG's
iterate then has all but a negligible part of the exact step's model decrease."""


class MultigridSolver(LinearSolver):
    """Multigrid-preconditioned CG (:mod:`posegraph.linalg.multigrid`) on H in block-CSR form; no factor."""

    def __init__(self, pattern: HessianPattern, tolerance: float = multigrid.DEFAULT_TOLERANCE):
        self._cg = multigrid.MultigridCG(tolerance)  # first: without pyamg, nothing else is made
        self._pattern, self._layout = pattern, symmetric_blocks(pattern)
        self._values = None  # the block values: one buffer, refilled by LM's retries on one H, dropped by release()
        self._null_space = None
        self.tolerance = tolerance
        self._last_norm = None  # ‖b‖ of the last solve (forcing term)
        self._tight_next = False  # the next solve to the full tolerance (confirm_convergence)
        self.name = f"pcg (aggregation multigrid via pyamg, relative residual {tolerance:g})"

    holds_factorization = False  # a chord step would cost a whole CG solve, and the hierarchy its memory

    def release(self) -> None:
        """Drop the block matrix and the hierarchy: no memory held while the next H is assembled."""
        self._values = None
        self._cg.release()

    @property
    def iterations(self) -> list[int]:
        """CG iterations of each solve so far."""
        return self._cg.iterations

    def linearized_at(self, poses: np.ndarray, free: np.ndarray, group) -> None:
        self._null_space = multigrid.pose_null_space(group, poses[free])

    def factorize(self, data: np.ndarray, shift: np.ndarray | None = None) -> None:
        """The multigrid hierarchy of the matrix with lower-triangle ``data`` (near-null space: the
        last :meth:`linearized_at`'s global motions, identity blocks before any). ``shift`` goes
        onto the block matrix's diagonal: no copy of ``data``."""
        import scipy.sparse as sp

        pattern = self._pattern
        self._values = symmetric_block_values(pattern, self._layout, np.asarray(data, dtype=np.float64), self._values)
        if shift is not None:
            d = pattern.block_size
            diagonal_blocks = self._layout.diagonal_blocks
            self._values[diagonal_blocks[:, None], np.arange(d), np.arange(d)] += shift.reshape(-1, d)
        size = pattern.dimension
        matrix = sp.bsr_matrix((self._values, self._layout.indices, self._layout.indptr), shape=(size, size), copy=False)
        null_space = self._null_space
        if null_space is None or null_space.shape[0] != size:
            null_space = np.tile(np.eye(pattern.block_size), (pattern.num_variables, 1))
        self._cg.factorize(matrix, null_space)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """CG to the relative residual ``max(tolerance, min(η_max, γ (‖b‖/‖b_prev‖)^α))`` (Eisenstat and
        Walker's second forcing term, ``b_prev`` the last different right-hand side: LM's gradients)."""
        norm = float(np.linalg.norm(rhs))
        if self._tight_next:
            forcing, self._tight_next = self.tolerance, False
        elif self._last_norm is None:
            forcing = FORCING_MAX
        elif norm == self._last_norm:  # the same gradient, another λ: as tight as the last solve
            forcing = self._cg.tolerance
        else:
            forcing = min(FORCING_MAX, FORCING_GAMMA * (norm / self._last_norm) ** FORCING_ALPHA)
        self._last_norm = norm
        self._cg.tolerance = max(self.tolerance, forcing)
        return self._cg.solve(rhs)

    def confirm_convergence(self) -> bool:
        """True when the last solve reached ``tolerance``; else the next one will (a small decrease
        from a loosely solved step is no sign of convergence: the step was short)."""
        if self._cg.tolerance <= max(self.tolerance, CONVERGENCE_TOLERANCE):
            return True
        self._tight_next = True
        return False

    def factor(self, release: bool = False):
        raise NotImplementedError("linear solver 'pcg' computes no factor; covariances need 'cholmod' or 'scipy'")


PCG_POSES_ONLY = ("linear solver 'pcg' takes pose graphs only (its multigrid knows blocks of one size); "
                  "use 'cholmod' or 'scipy' (or 'auto') for a graph with landmarks")
"""Why ``"pcg"`` refuses a graph with landmarks (the command line says it as soon as the file is read)."""


def make_linear_solver(
    kind: str, pattern: HessianPattern, ordering: str = "auto", blas_threads: int | None = 1,
    tolerance: float = multigrid.DEFAULT_TOLERANCE, *, factor_needed: bool = True,
) -> LinearSolver:
    """Build the backend ``kind`` (``"auto"``, ``"cholmod"``, ``"scipy"`` or ``"pcg"``) for ``pattern``.

    ``ordering`` and ``blas_threads`` apply to CHOLMOD (``"auto"``:
    :func:`posegraph.linalg.cholmod.auto_ordering`; ``blas_threads=None`` leaves the BLAS under CHOLMOD
    as it is), ``tolerance`` to ``"pcg"``. Asking for ``"cholmod"`` without cvxopt, or ``"pcg"``
    without pyamg, raises ``ImportError`` with the install hint. ``"auto"`` with
    ``factor_needed=False`` turns to ``"pcg"`` when CHOLMOD's factor would not fit in memory
    (:func:`posegraph.linalg.multigrid.factorisation_fits`).
    """
    if kind == "pcg" and pattern.point_size:
        from posegraph.errors import GraphError

        raise GraphError(PCG_POSES_ONLY)
    if kind == "auto" and not factor_needed and cholmod_available() and not pattern.point_size and not multigrid.factorisation_fits(
        pattern.block_indptr, pattern.block_indices, pattern.num_variables, pattern.block_size, ordering
    ):
        return MultigridSolver(pattern, tolerance)
    if kind == "auto":
        kind = "cholmod" if cholmod_available() else "scipy"
    if kind == "cholmod":
        if not cholmod_available():
            raise ImportError(
                f"linear_solver='cholmod' needs cvxopt's CHOLMOD [{cholmod_library.unavailable_reason()}]; "
                "use linear_solver='scipy' or 'auto'"
            )
        if ordering == "auto":
            ordering = cholmod_library.auto_ordering(pattern.num_variables)
        return CholmodSolver(pattern, ordering, blas_threads)
    if kind == "scipy":
        return ScipySolver(pattern)
    if kind == "pcg":
        return MultigridSolver(pattern, tolerance)
    raise ValueError(f"unknown linear solver {kind!r}: expected 'auto', 'cholmod', 'scipy' or 'pcg'")

