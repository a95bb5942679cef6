"""Marginal and joint covariances of the poses, by selected inversion of the Cholesky factor.

At poses ``X`` the Gauss-Newton matrix ``H = Σ_e J_eᵀ Ω_e J_e`` of the free vertices (right
perturbations ``X_k ⊕ δ_k = X_k·Exp(δ_k)``, tangent order ``[ω; v]``, as gtsam) is the inverse of
the Laplace approximation's covariance: ``Σ = H⁻¹``. Vertex ``k``'s marginal covariance is the
``d×d`` diagonal block ``Σ_kk`` (``d = 6`` for SE(3)); it is what ``gtsam.Marginals(graph,
values).marginalCovariance(key)`` returns for the same graph.

Gauge. The solver holds ``FIX`` vertices and one anchor per connected component constant
(:func:`posegraph.graph.held_vertices`); they have no variables in H. Their covariance is
reported as **zero**: every other covariance is *relative to the held vertices* — the
uncertainty of a pose given that its component's anchor (or the fixed vertices) is known
exactly. It is the limit of gtsam's with a prior of vanishing σ on the held vertices (σ = 1e-6
changes the others by ~σ²·‖Ω‖, far below the figures' precision). A different gauge (e.g. the
anchor at another vertex) gives different marginals; covariances of *relative* poses do not
depend on it.

Method (``docs/covariances.md``): H in the solver's lower-triangle layout
(:mod:`posegraph.solve.sparsity`), a fill-reducing order of the vertex graph expanded to the
``d×d`` blocks (so each vertex's ``d`` variables are contiguous in the permuted order), the
Cholesky factor ``P H Pᵀ = L Lᵀ`` (CHOLMOD through cvxopt, SuperLU without pivoting as the
fallback), then the Takahashi / Erisman–Tinney recurrence over ``L``'s block pattern
(:func:`selected_inverse`), which yields every entry of ``Σ`` inside that pattern — all diagonal
blocks among them — without forming any other entry.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = [
    "marginal_covariances",
    "joint_covariance",
    "hessian_at",
    "vertex_elimination_order",
    "cholesky_factor",
    "BlockFactor",
    "block_factor",
    "selected_inverse",
    "supernodes",
]


def tangent_dimension(graph) -> int:
    """``d``: the group's tangent dimension (``graph.group.dim`` when present, else Ω's size)."""
    group = getattr(graph, "group", None)
    dim = getattr(group, "dim", None)
    return int(dim) if dim is not None else int(np.shape(graph.information)[-1])


def hessian_at(graph, poses):
    """The Gauss-Newton matrix at ``poses`` ``(n, 4, 4)``: ``(pattern, data)``.

    ``pattern`` is the :class:`~posegraph.solve.sparsity.HessianPattern` (held vertices have no
    variables; ``pattern.variable_of`` maps vertices to block columns), ``data`` the CSC values
    of H's lower triangle in that pattern.
    """
    from posegraph.graph import held_vertices
    from posegraph.solve.linearize import linearize
    from posegraph.solve.sparsity import analyze_pattern, hessian_values

    held = held_vertices(graph)
    pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held)
    blocks = linearize(np.asarray(poses, dtype=np.float64), graph)
    return pattern, hessian_values(pattern, blocks.hessian_blocks)


def vertex_elimination_order(pattern) -> np.ndarray:
    """Fill-reducing elimination order ``(p,)`` of the free vertices (``order[k]`` = block column eliminated k-th).

    As the solver orders: CHOLMOD's ordering of the vertex graph (:func:`posegraph.cholmod.fill_reducing_order`,
    AMD below / nested dissection from :data:`posegraph.cholmod.NESTED_DISSECTION_VERTICES`) when the
    system library is there, else AMD from cvxopt's bundled copy, postordered along the elimination
    tree (subtrees contiguous: larger supernodes); without either, SuperLU's postordered MMD
    (:func:`posegraph.solve.linear.vertex_ordering`).
    """
    from posegraph import cholmod
    from posegraph.solve import linear

    p = pattern.num_variables
    if p == 0:
        return np.zeros(0, dtype=np.int64)
    if cholmod.load() is not None:
        method = cholmod.auto_ordering(p)
        order = cholmod.fill_reducing_order(pattern.block_indptr, pattern.block_indices, p, method)
    else:
        try:
            from cvxopt import amd, matrix, spmatrix
        except ImportError:
            return linear.vertex_ordering(pattern)
        cols = np.repeat(np.arange(p), np.diff(pattern.block_indptr))
        graph = spmatrix(1.0, matrix(pattern.block_indices.astype(np.int64)), matrix(cols), (p, p))
        order = np.asarray(amd.order(graph, uplo="L"), dtype=np.int64).ravel()
    vertex_graph = linear.vertex_graph(pattern)
    permuted = vertex_graph[order][:, order].tocsc()
    return order[linear.tree_postorder(linear.elimination_tree(permuted))]


@dataclass(frozen=True, eq=False)
class CSCFactor:
    """A lower-triangular sparse factor ``L`` in CSC arrays."""

    indptr: np.ndarray
    """``(N + 1,)`` column pointers."""
    indices: np.ndarray
    """``(nnz,)`` row indices."""
    data: np.ndarray
    """``(nnz,)`` values."""


def cholesky_factor(lower_csc, permutation) -> tuple[CSCFactor, np.ndarray]:
    """Cholesky factor ``L`` of ``P A Pᵀ = L Lᵀ`` (``(P A Pᵀ)[i, j] = A[perm[i], perm[j]]``).

    ``lower_csc`` = ``(indptr, indices, data)``: the lower triangle of the symmetric positive-definite
    ``N×N`` matrix ``A``; ``permutation`` ``(N,)``. Returns ``(L, permutation)``, ``L`` exactly for
    that permutation. CHOLMOD (cvxopt's bundled copy, supernodal LLᵀ) when cvxopt imports, with
    ``nmethods = 1`` and ``postorder = False`` so that it factors in the given order (by default it
    would also try AMD and postorder, and cvxopt does not return the order it used); else SuperLU
    without pivoting (:func:`_superlu_cholesky`). Raises
    :class:`posegraph.cholmod.NotPositiveDefiniteError` for a matrix that is not positive definite.
    """
    permutation = np.asarray(permutation, dtype=np.int64)
    try:
        import cvxopt.cholmod  # noqa: F401
    except ImportError:
        return _superlu_cholesky(lower_csc, permutation), permutation
    return _cvxopt_cholesky(lower_csc, permutation), permutation


def _cvxopt_cholesky(lower_csc, permutation: np.ndarray) -> CSCFactor:
    from cvxopt import cholmod, matrix, spmatrix

    from posegraph.cholmod import NotPositiveDefiniteError

    indptr, indices, data = (np.asarray(a) for a in lower_csc)
    n = indptr.shape[0] - 1
    cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    A = spmatrix(matrix(np.asarray(data, dtype=np.float64)), matrix(indices.astype(np.int64)), matrix(cols), (n, n))
    saved = dict(cholmod.options)
    cholmod.options.update(supernodal=2, nmethods=1, postorder=False)
    try:
        F = cholmod.symbolic(A, p=matrix(permutation), uplo="L")
        cholmod.numeric(A, F)
        L = cholmod.getfactor(F)
    except ArithmeticError as err:  # cvxopt raises ArithmeticError when A is not positive definite
        raise NotPositiveDefiniteError(str(err)) from err
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)
    colptr, rows, values = L.CCS
    return CSCFactor(
        np.asarray(colptr, dtype=np.int64).ravel(),
        np.asarray(rows, dtype=np.int64).ravel(),
        np.asarray(values, dtype=np.float64).ravel(),
    )


def _superlu_cholesky(lower_csc, permutation: np.ndarray) -> CSCFactor:
    """``L = L_unit · diag(√u_kk)`` from SuperLU's ``P A Pᵀ = L_unit U`` with natural order and no pivoting.

    On a symmetric positive-definite matrix LU without pivoting is ``U = D L_unitᵀ``, so this is
    the Cholesky factor. The row/column permutations SuperLU reports are checked to be the identity.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    from posegraph.cholmod import NotPositiveDefiniteError

    indptr, indices, data = lower_csc
    n = len(indptr) - 1
    lower = sp.csc_matrix((data, indices, indptr), shape=(n, n))
    full = (lower + sp.tril(lower, k=-1).T).tocsc()[permutation][:, permutation].tocsc()
    try:
        lu = splu(full, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as err:
        raise NotPositiveDefiniteError(str(err)) from err
    identity = np.arange(n)
    pivots = lu.U.diagonal()
    if not (np.array_equal(lu.perm_r, identity) and np.array_equal(lu.perm_c, identity)) or np.any(pivots <= 0):
        raise NotPositiveDefiniteError("SuperLU pivoted or met a non-positive pivot: the matrix is not positive definite")
    L = (lu.L @ sp.diags(np.sqrt(pivots))).tocsc()
    L.sort_indices()
    return CSCFactor(L.indptr.astype(np.int64), L.indices.astype(np.int64), L.data)


@dataclass(frozen=True, eq=False)
class BlockFactor:
    """``L`` cut into ``d×d`` blocks: the lower block pattern, by block column, rows ascending.

    Block ``b`` sits at block row ``rows[b]``, block column ``columns[b]``; each column's first block
    is its diagonal block, so ``parent[K] = rows[indptr[K] + 1]`` is ``K``'s parent in the block
    elimination tree.
    """

    block: int
    """``d``."""
    indptr: np.ndarray
    """``(p + 1,)``: blocks of column ``K`` are ``indptr[K] : indptr[K + 1]``."""
    rows: np.ndarray
    """``(b,)`` block rows."""
    columns: np.ndarray
    """``(b,)`` block columns."""
    values: np.ndarray
    """``(b, d, d)`` the blocks of ``L`` (entries not stored by the factor are zero)."""
    keys: np.ndarray
    """``(b,)`` ``columns·p + rows``, ascending: the lookup key of each block."""
    scalar: CSCFactor | None
    """The scalar factor the blocks were cut from, for solves (``None`` when not kept)."""

    @property
    def num_blocks(self) -> int:
        return int(self.rows.shape[0])

    def find(self, rows, columns) -> np.ndarray:
        """Index of block ``(rows, columns)`` (``rows ≥ columns``), ``-1`` where it is not in the pattern."""
        p = self.indptr.shape[0] - 1
        query = np.asarray(columns, dtype=np.int64) * p + np.asarray(rows, dtype=np.int64)
        pos = np.minimum(np.searchsorted(self.keys, query), self.keys.shape[0] - 1)
        return np.where(self.keys[pos] == query, pos, -1)

    def parents(self) -> np.ndarray:
        """``(p,)`` parent of each block column in the block elimination tree, ``-1`` for roots."""
        p = self.indptr.shape[0] - 1
        parent = np.full(p, -1, dtype=np.int64)
        has = np.diff(self.indptr) > 1
        parent[has] = self.rows[self.indptr[:-1][has] + 1]
        return parent


def block_factor(factor: CSCFactor, block: int) -> BlockFactor:
    """Cut the scalar factor into ``block×block`` blocks (pattern: every block holding a stored entry).

    Requires each vertex's ``block`` variables to be contiguous in the factor's order, which the
    block-expanded permutation guarantees.
    """
    n = factor.indptr.shape[0] - 1
    if n % block:
        raise ValueError(f"factor of order {n} is not made of {block}×{block} blocks")
    p = n // block
    found = _whole_blocks(factor, block)
    if found is None:  # some stored block is partial: find the blocks by sorting their keys
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(factor.indptr))
        rows = factor.indices
        if np.any(rows < cols):
            raise ValueError("factor has entries above the diagonal")
        keys = (cols // block) * p + rows // block
        unique = np.sort(keys)
        unique = unique[np.concatenate(([True], unique[1:] != unique[:-1]))] if unique.size else unique
        block_cols, block_rows = unique // p, unique % p
        indptr = np.searchsorted(block_cols, np.arange(p + 1))
        values = np.zeros((block_rows.shape[0], block, block))
        values[np.searchsorted(unique, keys), rows % block, cols % block] = factor.data
    else:
        values, block_rows, indptr = found
        block_cols = np.repeat(np.arange(p, dtype=np.int64), np.diff(indptr))
    if np.any(block_rows[indptr[:-1]] != np.arange(p)):
        raise ValueError("factor has an empty diagonal block")
    return BlockFactor(block, indptr, block_rows, block_cols, values, block_cols * p + block_rows, factor)


def _whole_blocks(factor: CSCFactor, block: int):
    """``(values, block rows, block indptr)`` when ``L`` stores whole blocks, else ``None``.

    Then scalar column ``d·K + q`` holds the ``d − q`` lower rows of its diagonal block followed by
    all ``d`` rows of each off-diagonal block of block column ``K``, the same blocks for every
    ``q`` — true of a pattern closed under elimination with dense diagonal blocks (CHOLMOD's,
    amalgamated supernodes included). Checked, and gathered, one ``q`` at a time: index arrays of
    ``nnz / d`` entries, not ``nnz`` (at 50,000 poses ``nnz(L)`` is ~8·10⁷).
    """
    d = block
    counts = np.diff(factor.indptr)
    per_column = counts[::d] // d  # blocks in each block column, diagonal included
    q = np.arange(counts.shape[0]) % d
    if np.any(counts[::d] % d) or not np.array_equal(counts, (d - q) + d * (np.repeat(per_column, d) - 1)):
        return None
    indptr = np.concatenate(([0], np.cumsum(per_column)))
    p = per_column.shape[0]
    diagonal = indptr[:-1]
    off = np.ones(indptr[-1], dtype=bool)
    off[diagonal] = False
    off = np.flatnonzero(off)  # off-diagonal blocks, by column
    column = np.repeat(np.arange(p), per_column - 1)
    rank = off - diagonal[column] - 1  # 0 for the first off-diagonal block of its column
    values = np.zeros((indptr[-1], d, d))
    block_rows = np.empty(indptr[-1], dtype=np.int64)
    block_rows[diagonal] = np.arange(p)
    within = np.arange(d)
    for k in range(d):
        start = factor.indptr[d * np.arange(p) + k]  # scalar column d·K + k
        head = start[:, None] + np.arange(d - k)
        if not np.array_equal(factor.indices[head], d * np.arange(p)[:, None] + np.arange(k, d)):
            return None
        values[diagonal, k:, k] = factor.data[head]
        entries = start[column, None] + (d - k) + d * rank[:, None] + within  # (off blocks, d)
        rows = factor.indices[entries]
        if k == 0:
            block_rows[off] = rows[:, 0] // d
        if not np.array_equal(rows, d * block_rows[off][:, None] + within):
            return None
        values[off, :, k] = factor.data[entries]
    return values, block_rows, indptr


def ancestor_closure(factor: BlockFactor, columns) -> np.ndarray:
    """Block columns ``columns`` and all their ancestors in the elimination tree, ascending.

    The Σ blocks of column ``K`` depend only on Σ among ``K``'s row blocks, all ancestors of ``K``:
    so this set is all :func:`selected_inverse` has to visit for the marginals of ``columns``.
    """
    parent = factor.parents().tolist()
    marked = np.zeros(len(parent), dtype=bool)
    for column in np.asarray(columns, dtype=np.int64).ravel().tolist():
        while column >= 0 and not marked[column]:
            marked[column] = True
            column = parent[column]
    return np.flatnonzero(marked)


RELAXED_SUPERNODES = ((4, 1.0), (16, 0.8), (48, 0.1), (None, 0.05))
"""Amalgamation of :func:`supernodes`: a merged supernode of at most ``width`` block columns may hold
at most this fraction of zero blocks in its dense trapezoid — CHOLMOD's defaults (``nrelax`` =
4, 16, 48; ``zrelax`` = 0.8, 0.1, 0.05). Each supernode costs a fixed dozen numpy calls: on
sphere2500 70 % of the fundamental ones are one column wide."""


def supernodes(factor: BlockFactor, relaxed: bool = True) -> np.ndarray:
    """First block column of each block supernode, then ``p``: ``(s + 1,)``.

    Fundamental supernodes: columns ``K`` and ``K + 1`` share one when ``K + 1`` is ``K``'s parent
    and column ``K`` has exactly one block more (the pattern being closed under elimination, their
    rows below coincide). ``relaxed``: a supernode is then merged into the next when that is its
    parent, within :data:`RELAXED_SUPERNODES`; its columns' rows are then those of its last column
    with zero blocks where ``L`` stores none (:func:`selected_inverse` handles them).
    """
    p = factor.indptr.shape[0] - 1
    if p == 0:
        return np.zeros(1, dtype=np.int64)
    count = np.diff(factor.indptr)
    parent = factor.parents()
    joined = (parent[:-1] == np.arange(1, p)) & (count[:-1] == count[1:] + 1)
    starts = np.concatenate(([0], np.flatnonzero(~joined) + 1, [p]))
    if not relaxed:
        return starts
    stored = np.concatenate(([0], np.cumsum(count)))  # blocks in columns < K
    merged, first = [0], 0
    for start, end in zip(starts[1:-1].tolist(), starts[2:].tolist()):
        width, height = end - first, count[end - 1] + end - 1 - first  # rows: the group's and below
        dense = width * height - width * (width - 1) // 2
        zeros = 1.0 - (stored[end] - stored[first]) / dense
        limit = next(z for w, z in RELAXED_SUPERNODES if w is None or width <= w)
        if parent[start - 1] != start or zeros > limit:
            merged.append(start)
            first = start
    return np.asarray(merged + [p], dtype=np.int64)


def selected_inverse(factor: BlockFactor, columns=None) -> np.ndarray:
    """``Σ = (L Lᵀ)⁻¹`` on the block pattern of ``L``: ``(b, d, d)``, block ``b`` = ``Σ[rows[b], columns[b]]``.

    Takahashi, Fagan & Chin (1973) / Erisman & Tinney (1975) recurrence, in block form as in Lin et
    al., "SelInv", ACM TOMS 37 (2011), Alg. 1 (there with LDLᵀ). From ``Σ = L⁻ᵀ L⁻¹`` (so
    ``Lᵀ Σ = L⁻¹``, upper triangular), for each supernode ``D`` (:func:`supernodes`: consecutive
    columns with a dense lower-triangular diagonal part ``L_DD`` and common rows ``S`` below it) in
    reverse elimination order::

        B     = L_SD · L_DD⁻¹                       (|S|·d × |D|·d)
        Σ_SD  = −Σ_SS · B
        Σ_DD  = L_DD⁻ᵀ L_DD⁻¹ − Bᵀ Σ_SD

    ``Σ_SS`` lies in the block pattern (closed under elimination: rows ``i > j`` of a column make
    ``(i, j)`` a block of ``L``) and belongs to later supernodes, already done. Each supernode is a
    few dense products of size ``(|S| + |D|)·d``. ``columns``: only the supernodes holding these
    block columns or their elimination-tree ancestors (:func:`ancestor_closure`) are visited, enough
    for these columns' blocks; the other blocks of the result stay zero. ``None``: all.
    """
    starts = supernodes(factor)
    sigma = np.zeros_like(factor.values)
    visit = np.arange(starts.shape[0] - 1)
    if columns is not None:
        visit = np.unique(np.searchsorted(starts, ancestor_closure(factor, columns), side="right") - 1)
    first, last = starts[visit], starts[visit + 1] - 1
    width = last - first + 1
    height = width + np.diff(factor.indptr)[last] - 1
    # Supernodes no other visited supernode descends from are needed by none: done last, in
    # batches of equal shape (on sphere2500 about half the supernodes, most 1 column × 5 rows).
    parent = factor.parents()[last]
    node_of = np.searchsorted(first, parent, side="right") - 1  # visited supernode holding the parent
    has_child = np.zeros(visit.shape[0], dtype=bool)
    has_child[node_of[(parent >= 0) & (node_of >= 0)]] = True
    for k in np.flatnonzero(has_child)[::-1].tolist():
        _update_supernodes(factor, sigma, first[k : k + 1], int(width[k]), int(height[k]))
    leaves = np.flatnonzero(~has_child)
    shape = width[leaves] * (int(height.max(initial=0)) + 1) + height[leaves]
    for key in np.unique(shape).tolist():
        batch = leaves[shape == key]
        _update_supernodes(factor, sigma, first[batch], int(width[batch[0]]), int(height[batch[0]]))
    return sigma


def _update_supernodes(factor: BlockFactor, sigma: np.ndarray, first: np.ndarray, width: int, height: int) -> None:
    """One step of :func:`selected_inverse` for ``g`` independent supernodes of equal shape, batched.

    ``first`` ``(g,)``: their first block columns; ``width`` columns and ``height`` block rows each
    (rows: the supernode's columns, then its last column's rows below). Writes their Σ blocks.
    """
    d, g = factor.block, first.shape[0]
    last = first + width - 1
    below = factor.rows[factor.indptr[last][:, None] + 1 + np.arange(height - width)]  # S, (g, h − w)
    R = np.concatenate((first[:, None] + np.arange(width), below), axis=1)
    r, j = np.arange(height)[:, None], np.arange(width)[None, :]
    position = np.where(r >= j, factor.find(R[:, :, None], first[:, None, None] + j), -1)  # (g, h, w); −1: zero
    stored = position >= 0
    blocks = factor.values[np.where(stored, position, 0)] * stored[..., None, None]
    L_RD = blocks.transpose(0, 1, 3, 2, 4).reshape(g, height * d, width * d)
    inverse = _triangular_inverse(L_RD[:, : width * d])  # L_DD⁻¹
    sigma_RD = np.swapaxes(inverse, -1, -2) @ inverse
    if height > width:
        B = L_RD[:, width * d :] @ inverse
        sigma_SD = _minus_sigma_product(factor, sigma, below, B)  # −Σ_SS B
        sigma_RD = np.concatenate((sigma_RD - np.swapaxes(B, -1, -2) @ sigma_SD, sigma_SD), axis=1)
    sigma[position[stored]] = sigma_RD.reshape(g, height, d, width, d).transpose(0, 1, 3, 2, 4)[stored]


def _triangular_inverse(lower: np.ndarray) -> np.ndarray:
    """Inverses ``(g, k, k)`` of lower-triangular ``(g, k, k)``: LAPACK ``dtrtri`` for one (a third of
    the flops of a general inverse, for the large supernodes), batched ``inv`` for many small ones."""
    if lower.shape[0] > 1:
        return np.linalg.inv(lower)
    from scipy.linalg.lapack import dtrtri

    inverse, info = dtrtri(lower[0], lower=1)
    if info:
        raise ArithmeticError(f"diagonal block of the factor is singular (LAPACK dtrtri info {info})")
    return inverse[None]


def _minus_sigma_product(factor: BlockFactor, sigma: np.ndarray, S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``−Σ_SS B`` ``(g, |S|·d, w)`` for rows of ascending block indices ``S`` ``(g, |S|)``.

    Gathers the stored ``Σ[max(S_a, S_b), min(S_a, S_b)]``: right on and below the block diagonal
    (diagonal blocks are symmetric), transposed above it; so only the lower triangle is right. One
    supernode: BLAS ``dsymm`` reads just that; a batch: it is mirrored first.
    """
    g, m, d = S.shape[0], S.shape[1], factor.block
    position = factor.find(np.maximum(S[:, :, None], S[:, None, :]), np.minimum(S[:, :, None], S[:, None, :]))
    if np.any(position < 0):
        raise RuntimeError("factor pattern is not closed under elimination: a block of Σ_SS is missing")
    gathered = sigma[position].transpose(0, 1, 3, 2, 4).reshape(g, m * d, m * d)
    if g == 1:
        from scipy.linalg.blas import dsymm

        return dsymm(-1.0, gathered[0], B[0], lower=1)[None]
    lower = np.tril(gathered)
    return -((lower + np.swapaxes(np.tril(lower, -1), -1, -2)) @ B)


@dataclass(frozen=True, eq=False)
class _Factorisation:
    factor: BlockFactor
    """Blocks of ``L``, ``P H Pᵀ = L Lᵀ``."""
    position: np.ndarray
    """``(n,)`` block column of each vertex in elimination order, ``-1`` for held vertices."""


def _factorise(graph, poses, keep_scalar: bool = False) -> _Factorisation:
    from posegraph.cholmod import block_permutation

    d = tangent_dimension(graph)
    if np.shape(poses) != np.shape(graph.poses):
        raise ValueError(f"poses must have shape {np.shape(graph.poses)}, got {np.shape(poses)}")
    pattern, data = hessian_at(graph, poses)
    if pattern.dimension != d * pattern.num_variables:
        raise ValueError(f"Hessian blocks are {pattern.dimension // max(pattern.num_variables, 1)}, expected {d}")
    order = vertex_elimination_order(pattern)
    L, _ = cholesky_factor((pattern.indptr, pattern.indices, data), block_permutation(order, d))
    rank = np.empty_like(order)
    rank[order] = np.arange(order.shape[0])
    free = pattern.variable_of >= 0
    position = np.full(graph.num_vertices, -1, dtype=np.int64)
    position[free] = rank[pattern.variable_of[free]]
    factor = block_factor(L, d)
    if not keep_scalar:  # the blocks hold the same numbers: let the scalar copy go
        factor = dataclasses.replace(factor, scalar=None)
    return _Factorisation(factor, position)


def _one_blas_thread():
    """numpy's/scipy's BLAS (and cvxopt's) on one thread for the block, when threadpoolctl is installed.

    The dense products of :func:`selected_inverse` are small and many; on the shared 2-core machine
    here two BLAS threads contending with other jobs made it 5× slower (sphere2500: 1.9 s against
    0.38 s on one thread, measured alternately under load ~2).
    """
    # threadpoolctl limits the BLAS libraries loaded when it is called: numpy's, scipy's and
    # cvxopt's wheels each bundle their own OpenBLAS, so load them all first.
    import scipy.linalg.blas  # noqa: F401

    try:
        import cvxopt.cholmod  # noqa: F401
    except ImportError:
        pass
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(1)


def _vertex_indices(graph, vertices) -> np.ndarray:
    n = graph.num_vertices
    if vertices is None:
        return np.arange(n)
    vertices = np.asarray(vertices)
    if vertices.ndim != 1 or not np.issubdtype(vertices.dtype, np.integer) and vertices.size:
        raise ValueError("vertices must be a 1-D array of vertex indices (graph.index_of(ids) maps ids)")
    vertices = vertices.astype(np.int64)
    if np.any((vertices < 0) | (vertices >= n)):
        raise IndexError(f"vertex indices must lie in [0, {n}), got {vertices[(vertices < 0) | (vertices >= n)][:5].tolist()}")
    return vertices


def marginal_covariances(graph, poses, vertices=None) -> np.ndarray:
    """Marginal covariance of each requested vertex's pose: ``(k, d, d)``.

    ``poses`` ``(n, 4, 4)``: the point of linearisation (normally the optimised poses);
    ``vertices``: ``(k,)`` vertex *indices* (``graph.index_of(ids)`` for ids), all vertices when
    ``None``. Block ``k`` is ``Cov(δ)`` of ``X_k ⊕ δ = X_k·Exp(δ)``, tangent order ``[ω; v]`` —
    the convention of ``gtsam.Marginals.marginalCovariance``. Held vertices (``FIX`` and component
    anchors) get zero: the gauge is theirs, the others' covariances are relative to them (module
    docstring). Cost: one sparse Cholesky and the selected inversion over the requested
    vertices' block columns and their elimination-tree ancestors (:func:`selected_inverse`).
    Raises :class:`posegraph.cholmod.NotPositiveDefiniteError` when H is not positive definite
    at ``poses``.
    """
    vertices = _vertex_indices(graph, vertices)
    d = tangent_dimension(graph)
    out = np.zeros((vertices.shape[0], d, d))
    if vertices.size == 0:
        return out
    with _one_blas_thread():
        setup = _factorise(graph, poses)
        K = setup.position[vertices]
        free = K >= 0
        columns = np.unique(K[free])
        every = columns.shape[0] == setup.factor.indptr.shape[0] - 1
        sigma = selected_inverse(setup.factor, None if every else columns)
    diagonal = sigma[setup.factor.indptr[K[free]]]
    out[free] = 0.5 * (diagonal + np.swapaxes(diagonal, -1, -2))
    return out


def joint_covariance(graph, poses, vertices) -> np.ndarray:
    """Joint covariance ``(k·d, k·d)`` of the poses of ``vertices`` ``(k,)`` (vertex indices).

    Block ``(a, b)`` (rows ``a·d : (a+1)·d``, columns ``b·d : (b+1)·d``) is ``Cov(δ_a, δ_b)`` of
    ``vertices[a]`` and ``vertices[b]``, in the given order; conventions and gauge as
    :func:`marginal_covariances` (rows and columns of held vertices are zero). When every pair's
    block lies in the factor's pattern (one vertex an elimination-tree ancestor of the other,
    joined in ``L``) they come from :func:`selected_inverse`; otherwise — the usual case for the
    two ends of a candidate loop closure — from ``k·d`` columns of ``H⁻¹``, two triangular solves
    with ``L`` each (:func:`_solve_columns`).
    """
    vertices = _vertex_indices(graph, vertices)
    d = tangent_dimension(graph)
    k = vertices.shape[0]
    out = np.zeros((k, d, k, d))
    if k == 0:
        return out.reshape(0, 0)
    with _one_blas_thread():
        setup = _factorise(graph, poses, keep_scalar=True)
        free = np.flatnonzero(setup.position[vertices] >= 0)
        if free.size == 0:
            return out.reshape(k * d, k * d)
        K = setup.position[vertices[free]]
        position = setup.factor.find(np.maximum.outer(K, K), np.minimum.outer(K, K))
        if np.all(position >= 0):
            blocks = selected_inverse(setup.factor, np.unique(K))[position]  # Σ[max, min]
            upper = K[:, None] < K[None, :]
            blocks[upper] = np.swapaxes(blocks[upper], -1, -2)
        else:
            blocks = _solve_columns(setup.factor, K)
    out[np.ix_(free, np.arange(d), free, np.arange(d))] = blocks.transpose(0, 2, 1, 3)
    joint = out.reshape(k * d, k * d)
    return 0.5 * (joint + joint.T)


def _solve_columns(factor: BlockFactor, K: np.ndarray) -> np.ndarray:
    """``Σ[K_a, K_b]`` ``(k, k, d, d)`` from ``X = L⁻ᵀ L⁻¹ E``, ``E`` the identity's columns of the blocks ``K``."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve_triangular

    d = factor.block
    n = factor.scalar.indptr.shape[0] - 1
    L = sp.csc_matrix((factor.scalar.data, factor.scalar.indices, factor.scalar.indptr), shape=(n, n)).tocsr()
    scalar = (d * K[:, None] + np.arange(d)).ravel()
    E = np.zeros((n, scalar.shape[0]))
    E[scalar, np.arange(scalar.shape[0])] = 1.0
    Y = spsolve_triangular(L, E, lower=True)
    X = spsolve_triangular(L.T.tocsr(), Y, lower=False)
    k = K.shape[0]
    return X[scalar].reshape(k, d, k, d).transpose(0, 2, 1, 3)
