"""The sparse linear least-squares problem both chordal stages solve, and its SPD solve.

Both the chordal rotations and the translations given rotations minimise, over one r×k block
``x_k`` per vertex (``r`` the space dimension: 3 for 3D graphs, 2 for planar ones),

    ``Σ_e  ½ tr((x_j − P_e x_i − h_e)ᵀ W_e (x_j − P_e x_i − h_e))``,

with an r×r transfer ``P_e``, an r×r symmetric positive-definite weight ``W_e`` and an offset
``h_e`` (given as ``g_e = W_e h_e``, which is what the normal equations need). Held vertices
(fixed and anchors, :func:`posegraph.model.graph.held_vertices`) are *eliminated*, not softly anchored by a
prior: their blocks move to the right-hand side. Setting the gradient to zero gives, per edge,
the normal-equation blocks

    ``H_jj += W``,  ``H_ii += Pᵀ W P``,  ``H_ji −= W P``,  ``H_ij −= Pᵀ W``,
    ``b_j += g``,  ``b_i −= Pᵀ g``,

and a held ``x_i`` (resp. ``x_j``) adds ``W P x_i`` to ``b_j`` (resp. ``Pᵀ W x_j`` to ``b_i``).
The matrix ``H`` (rp×rp for p free vertices) is the same for all k columns: one factorisation,
k right-hand sides. It is positive definite whenever every component holds a vertex and every
``W_e`` is positive definite, which :mod:`posegraph.init.weights` guarantees.

The block sparsity depends only on the edges and the held set, so :class:`RelativeLeastSquares`
analyses it once — the CSC pattern, where each per-edge block entry lands in it, and CHOLMOD's
symbolic factorisation — and each :meth:`~RelativeLeastSquares.solve` only refills the values
(the rotation and translation stages share one analysis).

:meth:`~RelativeLeastSquares.restricted` serves a sub-problem from the same analysis: only some
edges count (the others get ``W = 0``, ``g = 0``: zero values in the analysed pattern) and more
vertices are held (each extra held vertex keeps its analysed variable, with a unit diagonal block,
no coupling and a zero right-hand side; its edges to free vertices move to their right-hand sides
as for any held vertex). Its solution equals that of the problem analysed for the counted edges
and the larger held set, up to round-off (another elimination order).

This module depends on :mod:`posegraph.linalg.cholmod` (scipy only on the SuperLU path), not on
:mod:`posegraph.solve`: initialisation comes before the solver in the data flow. Every numerical
failure of either backend (a matrix not positive definite to working precision, an overflow)
raises :class:`~posegraph.linalg.cholmod.NotPositiveDefiniteError`.
"""

from __future__ import annotations

import numpy as np

from posegraph.linalg import cholmod as cholmod_library
from posegraph.linalg import multigrid
from posegraph.linalg.cholmod import NotPositiveDefiniteError

__all__ = ["RelativeLeastSquares", "LINEAR_SOLVERS", "NotPositiveDefiniteError"]

LINEAR_SOLVERS = ("auto", "cholmod", "scipy", "pcg")


class RelativeLeastSquares:
    """The relative least-squares problem of the module docstring for one edge set and held set.

    Parameters
    ----------
    held : (n,) bool — vertices whose block is given, not solved for.
    edge_from, edge_to : (m,) int — vertex indices ``i``, ``j`` of each edge.
    linear_solver : ``"auto"`` | ``"cholmod"`` | ``"scipy"`` | ``"pcg"``.
        ``"cholmod"``: CHOLMOD from cvxopt (:func:`posegraph.linalg.cholmod.block_cholesky`: supernodal
        Cholesky, the vertex graph ordered as in the solver, symbolic analysis kept between
        solves); ``"scipy"``: SuperLU in symmetric mode (minimum-degree ordering on AᵀA+A, no
        off-diagonal pivoting — on an SPD matrix that is Cholesky in disguise), needing nothing
        beyond scipy; ``"auto"``: CHOLMOD when cvxopt imports, else SuperLU — and SuperLU too
        when CHOLMOD reports the matrix as not positive definite (it can, at round-off level,
        when the weights span many decades), or ``"pcg"`` when the factor foreseen from the vertex
        pattern would not fit in memory (:attr:`iterative`); ``"pcg"``: no factorisation, multigrid-preconditioned
        conjugate gradients on H in r×r block form (:mod:`posegraph.linalg.multigrid`, pyamg; its
        near-null space identity blocks, a uniform shift of every ``x_k``), each column of the
        right-hand side to a relative residual of :data:`posegraph.linalg.multigrid.DEFAULT_TOLERANCE`.
    threads : int or None, default 1
        Threads of the BLAS under CHOLMOD during its work
        (:class:`posegraph.linalg.native_threads.NativeThreads`; None leaves it as it is).
    block : int, default 3
        ``r``, the rows of each vertex's block ``x_k`` (3 for 3D graphs, 2 for planar ones).
    ordering : str, default ``"auto"``
        CHOLMOD's fill-reducing ordering of the vertex graph (:func:`posegraph.linalg.cholmod.block_cholesky`).
    """

    def __init__(
        self,
        held: np.ndarray,
        edge_from: np.ndarray,
        edge_to: np.ndarray,
        *,
        linear_solver: str = "auto",
        threads: int | None = 1,
        block: int = 3,
        ordering: str = "auto",
    ):
        if linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, got {linear_solver!r}")
        if threads is not None and (int(threads) != threads or threads < 1):
            raise ValueError(f"threads must be a positive integer or None, got {threads!r}")
        if ordering != "auto" and ordering not in cholmod_library.ORDERINGS:
            raise ValueError(f"ordering must be 'auto' or one of {cholmod_library.ORDERINGS}, got {ordering!r}")
        self.linear_solver = linear_solver
        self.threads = threads
        self.block = int(block)
        self.ordering = ordering
        self.held = np.asarray(held, dtype=bool)
        self.edge_from = np.asarray(edge_from, dtype=np.int64)
        self.edge_to = np.asarray(edge_to, dtype=np.int64)
        free = ~self.held
        self.num_free = int(np.count_nonzero(free))
        self.variable = np.full(self.held.shape[0], -1, dtype=np.int64)
        self.variable[free] = np.arange(self.num_free)
        i, j = self.edge_from, self.edge_to
        self.free_from, self.free_to = free[i], free[j]
        self.both_free = self.free_from & self.free_to
        self._cholesky = None  # CHOLMOD's analysis, made at the first factorisation
        self._multigrid = None  # "pcg": the multigrid solver, its aggregates kept between solves
        self._analyse_pattern()
        # Which blocks the pattern stores (the analysed free sets) and what a restriction changes:
        self._layout = (self.free_from, self.free_to, self.both_free)
        self._counted = None  # (m,) bool: edges whose terms count; None: all
        self._pinned = np.zeros(0, dtype=np.int64)  # data positions of extra held vertices' diagonals

    def restricted(self, counted_edges: np.ndarray, held: np.ndarray) -> "RelativeLeastSquares":
        """This problem over the edges ``counted_edges`` ``(m,)`` bool only, holding ``held | self.held``
        ``(n,)`` bool: a view sharing the analysis (pattern, CHOLMOD's symbolic factorisation).

        Every component of the counted edges must contain a held vertex (e.g. ``held`` from
        :func:`posegraph.model.graph.held_vertices` of the graph of the counted edges), else the system is
        singular. See the module docstring.
        """
        import copy

        counted_edges = np.asarray(counted_edges, dtype=bool)
        held = np.asarray(held, dtype=bool) | self.held
        if counted_edges.shape != self.edge_from.shape or held.shape != self.held.shape:
            raise ValueError("counted_edges must have shape (m,) and held (n,)")
        self._analysed()  # made once here, so that every view shares it
        view = copy.copy(self)
        view.held, view._counted = held, counted_edges
        view._multigrid = None  # its aggregates are the view's own matrix's
        free = ~held
        view.free_from, view.free_to = free[self.edge_from], free[self.edge_to]
        view.both_free = view.free_from & view.free_to
        pinned = self.variable[held & ~self.held]
        view._pinned = self._diagonal_positions[pinned].ravel()
        return view

    def _analyse_pattern(self) -> None:
        """CSC pattern of H and the CSC position of every per-edge block entry (see :meth:`_matrix`).

        Works on r×r blocks (one sort of the block pairs, not of r² times as many entries): with
        the stored blocks sorted by (block column c, block row q), scalar column ``r·c + b`` holds
        the column's ``count_c`` blocks one after another, so entry ``(a, b)`` of the ``s``-th block
        of block column ``c`` sits at ``r²·(blocks before column c) + r·count_c·b + r·s + a``.
        """
        r = self.block
        axis = np.arange(r)
        i, j, var = self.edge_from, self.edge_to, self.variable
        block_rows = np.concatenate(
            [var[j[self.free_to]], var[i[self.free_from]], var[j[self.both_free]], var[i[self.both_free]]]
        )
        block_cols = np.concatenate(
            [var[j[self.free_to]], var[i[self.free_from]], var[i[self.both_free]], var[j[self.both_free]]]
        )
        p = self.num_free
        keys, block_of = np.unique(block_cols * np.int64(p) + block_rows, return_inverse=True)
        rows, cols = keys % max(p, 1), keys // max(p, 1)
        count = np.bincount(cols, minlength=p)
        blocks_before = np.concatenate([[0], np.cumsum(count)])
        rank = np.arange(keys.size) - blocks_before[cols]  # s: rank of the block within its column
        # positions (block, a, b) for every stored block
        base = r * r * blocks_before[cols] + r * rank
        position = base[:, None, None] + axis[None, :, None] + r * count[cols][:, None, None] * axis[None, None, :]
        self._nnz = r * r * keys.size
        # int32 below 2³¹ entries (every pose graph this side of ~10⁸ edges): half the memory of
        # the scatter map, which lives as long as the problem (r² positions an edge and block)
        self._position = position[block_of].ravel().astype(np.int32 if self._nnz < 2**31 else np.int64)
        column_counts = np.repeat(r * count, r)  # entries in each scalar column
        self._indptr = np.concatenate([[0], np.cumsum(column_counts)]).astype(np.int32)
        indices = np.empty(self._nnz, dtype=np.int32)
        indices[position.ravel()] = (r * rows[:, None, None] + axis[None, :, None] + 0 * axis[None, None, :]).ravel()
        self._indices = indices
        # the vertex pattern (both triangles), for ordering the blocks (posegraph.linalg.cholmod.fill_reducing_order)
        self._block_indptr = np.concatenate([[0], np.cumsum(count)]).astype(np.int32)
        self._block_rows = rows.astype(np.int32)
        # (p, r) positions of the diagonal entries of each variable's diagonal block (every free
        # vertex has one: a free vertex without edges would be its own component's anchor)
        diagonal_blocks = np.flatnonzero(rows == cols)
        self._diagonal_positions = np.zeros((p, r), dtype=np.int64)
        self._diagonal_positions[cols[diagonal_blocks]] = position[diagonal_blocks][:, axis, axis]

    def _matrix(self, transfer: np.ndarray, weight_transfer: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """CSC ``data`` of H (both triangles) with its per-edge blocks ``W``, ``PᵀWP``, ``−WP``,
        ``−PᵀW`` summed into the fixed pattern ``(self._indptr, self._indices)``.

        The pattern has a slot for each block of the analysed free sets (``self._layout``); a block
        touching a vertex held only by :meth:`restricted` gets zeros there, and such a vertex's
        diagonal block is the identity."""
        layout_from, layout_to, layout_both = self._layout
        blocks = (  # made one at a time, each added in place: no temporary as large as all four
            lambda: weight[layout_to] * self.free_to[layout_to, None, None],
            lambda: transfer[layout_from].transpose(0, 2, 1) @ weight_transfer[layout_from] * self.free_from[layout_from, None, None],
            lambda: -weight_transfer[layout_both] * self.both_free[layout_both, None, None],
            lambda: -weight_transfer[layout_both].transpose(0, 2, 1) * self.both_free[layout_both, None, None],
        )  # fmt: skip
        data = np.zeros(self._nnz)
        start = 0
        for block in blocks:
            values = block().ravel()
            np.add.at(data, self._position[start : start + values.size], values)
            start += values.size
        data[self._pinned] = 1.0
        return data

    def solve(
        self,
        held_values: np.ndarray,
        transfer: np.ndarray,
        weight: np.ndarray,
        weighted_offset: np.ndarray | None = None,
        *,
        refinement_steps: int = 1,
        near_null_space: np.ndarray | None = None,
    ) -> np.ndarray:
        """The minimiser ``(n, r, k)``; held rows equal ``held_values``.

        ``held_values`` ``(n, r, k)`` (rows of free vertices are ignored), ``transfer`` ``P_e`` and
        ``weight`` ``W_e`` ``(m, r, r)``, ``weighted_offset`` ``g_e = W_e h_e`` ``(m, r, k)`` or
        None for zero. ``refinement_steps`` steps of iterative refinement follow the first solve.
        ``near_null_space`` ``(n, r, r)``, for ``"pcg"``: blocks ``x_k`` with ``x_j ≈ P_e x_i`` on
        every edge (what H barely moves before the held vertices are removed; identity blocks,
        exact when every ``P_e = I``, if None).
        """
        values = np.array(held_values, dtype=np.float64, copy=True)
        k = values.shape[-1]
        if self.num_free == 0:
            return values
        if self._counted is not None:  # edges that do not count: W = 0, g = 0
            weight = weight * self._counted[:, None, None]
            if weighted_offset is not None:
                weighted_offset = weighted_offset * self._counted[:, None, None]
        i, j, var = self.edge_from, self.edge_to, self.variable
        free_i, free_j = self.free_from, self.free_to
        weight_transfer = weight @ transfer  # W P
        solve = self._factorize(self._matrix(transfer, weight_transfer, weight), near_null_space)

        shape = (self.num_free, self.block, k)
        rhs = np.zeros(shape)
        if weighted_offset is not None:
            np.add.at(rhs, var[j[free_j]], weighted_offset[free_j])
            np.add.at(rhs, var[i[free_i]], -(transfer[free_i].transpose(0, 2, 1) @ weighted_offset[free_i]))
        only_j = free_j & ~free_i
        np.add.at(rhs, var[j[only_j]], weight_transfer[only_j] @ values[i[only_j]])
        only_i = free_i & ~free_j
        np.add.at(rhs, var[i[only_i]], weight_transfer[only_i].transpose(0, 2, 1) @ values[j[only_i]])

        free = ~self.held
        values[free] = solve(rhs.reshape(-1, k)).reshape(shape)[var[free]]
        for _ in range(refinement_steps):
            # Iterative refinement from the edges' own residuals rather than b − H x, in which two
            # large terms nearly cancel: the gradient is evaluated from edge differences
            # x_j − P x_i, accurate to the round-off of x itself, so one correction removes most
            # of the first solve's cond(H)·ε error when the weights span many decades.
            pull = weight @ (values[j] - transfer @ values[i])
            if weighted_offset is not None:
                pull = pull - weighted_offset
            gradient = np.zeros(shape)
            np.add.at(gradient, var[j[free_j]], pull[free_j])
            np.add.at(gradient, var[i[free_i]], -(transfer[free_i].transpose(0, 2, 1) @ pull[free_i]))
            values[free] -= solve(gradient.reshape(-1, k)).reshape(shape)[var[free]]
        return values

    def _csc(self, data: np.ndarray):
        import scipy.sparse as sp

        size = self.block * self.num_free
        return sp.csc_matrix((data, self._indices, self._indptr), shape=(size, size))

    def _factorize(self, data: np.ndarray, near_null_space: np.ndarray | None = None):
        """``solve(rhs) -> x`` for the matrix with CSC ``data``, by the backend chosen at construction
        (``near_null_space``: :meth:`solve`'s, for ``"pcg"``).

        Raises :class:`NotPositiveDefiniteError` when no backend factorises it, or its solution is not finite.
        """
        solve = None
        if self.iterative:
            solve = self._multigrid_solve(data, near_null_space)
        elif self.linear_solver != "scipy":
            if cholmod_library.load() is None and self.linear_solver == "cholmod":
                raise ImportError(f"linear_solver='cholmod': {cholmod_library.unavailable_reason()}")
            if cholmod_library.load() is not None:
                solve = self._cholmod_solve(data)
        if solve is None:
            solve = _superlu_solver(self._csc(data))

        def finite_solve(rhs: np.ndarray) -> np.ndarray:
            solution = solve(rhs)
            if not np.isfinite(solution).all():
                raise NotPositiveDefiniteError("the solution of the relative least-squares problem is not finite")
            return solution

        return finite_solve

    def _multigrid_solve(self, data: np.ndarray, near_null_space: np.ndarray | None):
        """Multigrid-preconditioned CG's solve for the matrix (:mod:`posegraph.linalg.multigrid`; smoothed
        aggregation: these r×r systems are small beside the solver's, its prolongators cheap)."""
        if self._multigrid is None:
            self._multigrid = multigrid.MultigridCG(smoothed=True)
        r = self.block
        matrix = self._csc(data).tobsr(blocksize=(r, r))
        if near_null_space is None:
            null = np.tile(np.eye(r), (self.num_free, 1))
        else:
            null = np.ascontiguousarray(near_null_space[~self.held].reshape(-1, r))
        self._multigrid.factorize(matrix, null)
        return self._multigrid.solve

    @property
    def iterative(self) -> bool:
        """Whether the solves run by ``"pcg"``: asked for, or ``"auto"`` whose CHOLMOD factor would
        not fit in memory (:meth:`_analysed`, decided once, at the first call)."""
        self._analysed()
        return self.linear_solver == "pcg"

    def _analysed(self):
        """CHOLMOD's analysis, made once (None on the SuperLU and pcg paths). ``"auto"`` turns to
        ``"pcg"`` instead when the factor foreseen from the vertex pattern would not fit in the
        memory left (:func:`posegraph.linalg.multigrid.factorisation_fits`)."""
        if self._cholesky is not None or self.linear_solver not in ("auto", "cholmod") or cholmod_library.load() is None:
            return self._cholesky
        if self.linear_solver == "auto" and not multigrid.factorisation_fits(
            self._block_indptr, self._block_rows, self.num_free, self.block, self.ordering
        ):
            self.linear_solver = "pcg"
            return None
        self._cholesky = self._symbolic()
        return self._cholesky

    def _symbolic(self):
        """CHOLMOD's factorisation object for the pattern: ordering and symbolic analysis."""
        return cholmod_library.block_cholesky(
            self._indptr, self._indices, self._block_indptr, self._block_rows, self.num_free, self.block,
            self.ordering, threads=self.threads,
        )  # fmt: skip

    def _cholmod_solve(self, data: np.ndarray):
        """CHOLMOD's solve for the matrix (analysed at the first call), or None when it is not
        positive definite and ``"auto"`` may fall back to SuperLU."""
        self._analysed()
        try:
            self._cholesky.factorize(data)
        except NotPositiveDefiniteError:
            if self.linear_solver == "cholmod":
                raise
            return None
        return self._cholesky.solve


def _superlu_solver(matrix):
    """``solve(rhs)`` by SuperLU without off-diagonal pivoting; :class:`NotPositiveDefiniteError` when
    it fails or a pivot is not finite and positive (U's diagonal is D of ``L D Lᵀ``)."""
    from scipy.sparse.linalg import splu

    if not np.isfinite(matrix.data).all():
        raise NotPositiveDefiniteError("matrix has non-finite entries")
    try:
        factor = splu(matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as err:  # "Factor is exactly singular"
        raise NotPositiveDefiniteError(f"SuperLU: {err}") from err
    pivots = factor.U.diagonal()
    if not (np.isfinite(pivots).all() and (pivots > 0).all()):
        raise NotPositiveDefiniteError("SuperLU: a pivot is not finite and positive: matrix not positive definite")
    return lambda rhs: factor.solve(np.asarray(rhs, dtype=np.float64))
