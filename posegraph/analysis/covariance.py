"""Marginal and joint covariances of the poses, by selected inversion of the Cholesky factor.

At poses ``X`` the Gauss-Newton matrix ``H = Σ_e J_eᵀ Ω_e J_e`` of the free vertices (right
perturbations ``X_k ⊕ δ_k = X_k·Exp(δ_k)``, the group's tangent order as gtsam: ``[ω; v]`` for
SE(3), ``[v_x, v_y, ω]`` for SE(2)) is the inverse of the Laplace approximation's covariance:
``Σ = H⁻¹``. Vertex ``k``'s marginal covariance is the ``d×d`` diagonal block ``Σ_kk`` (``d =
graph.group.dim``: 6 for SE(3), 3 for SE(2)); it is what ``gtsam.Marginals(graph,
values).marginalCovariance(key)`` returns for the same graph.

Gauge. The solver holds ``FIX`` vertices and one anchor per connected component constant
(:func:`posegraph.model.graph.held_vertices`); they have no variables in H. Their covariance is
reported as **zero**: every other covariance is *relative to the held vertices* — the
uncertainty of a pose given that its component's anchor (or the fixed vertices) is known
exactly. It is the limit of gtsam's with a prior of vanishing σ on the held vertices: such a
prior changes a covariance of size ``s`` next to a held vertex by about ``σ²/s`` relative, so
the two agree as σ → 0. A different gauge (e.g. the anchor at another vertex) gives different
marginals; covariances of *relative* poses do not depend on it.

Method (``docs/covariances.md``): H in the solver's lower-triangle layout
(:mod:`posegraph.solve.sparsity`); its Cholesky factor ``P H Pᵀ = L Lᵀ`` by the solver's own
linear backend (:func:`factor_hessian`: CHOLMOD through cvxopt with the solver's block ordering,
SuperLU without cvxopt); then the Takahashi / Erisman–Tinney recurrence over ``L``'s block
pattern (:func:`selected_inverse`), which yields every entry of ``Σ`` inside that pattern — all
diagonal blocks among them — without forming any other entry.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = [
    "marginal_covariances",
    "landmark_covariances",
    "joint_covariance",
    "linearisation_point",
    "hessian_at",
    "factor_hessian",
    "BlockFactor",
    "block_factor",
    "selected_inverse",
    "supernodes",
]


def hessian_at(graph, poses, points=None):
    """The Gauss-Newton matrix at ``poses`` ``(n, k, k)`` (``k`` = ``graph.group.matrix_size``): ``(pattern, data)``.

    ``pattern`` is the :class:`~posegraph.solve.sparsity.HessianPattern` (held vertices have no
    variables; ``pattern.variable_of`` maps vertices to block columns), ``data`` the CSC values
    of H's lower triangle in that pattern. A landmark graph's H (at ``points`` ``(L, s)``, the
    graph's own positions when None) comes in the padded layout of :func:`landmark_hessian_at`:
    ``n + L`` blocks of ``d``, landmark ``l`` the pseudo-vertex ``n + l``.
    """
    from posegraph.model.graph import held_vertices

    if graph.landmarks is not None:
        return landmark_hessian_at(graph, poses, points)
    from posegraph.solve.linearize import linearize
    from posegraph.solve.sparsity import analyze_pattern, hessian_values

    held = held_vertices(graph)
    pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held, graph.group.dim)
    poses = np.asarray(poses, dtype=np.float64)
    blocks = linearize(poses, graph)
    data = hessian_values(pattern, blocks.hessian_blocks)
    if graph.priors is not None:  # unary edges: their diagonal blocks (posegraph.solve.unary)
        from posegraph.solve.unary import add_prior_hessian, linearize_priors, prior_errors

        add_prior_hessian(pattern, data, linearize_priors(poses, graph, prior_errors(poses, graph)))
    return pattern, data


def landmark_hessian_at(graph, poses, points=None):
    """H of a landmark graph at ``poses`` ``(n, k, k)`` and ``points`` ``(L, s)`` (None: the graph's
    positions) in a layout of equal ``d×d`` blocks: ``(pattern, data)``.

    The solver's H has blocks of two sizes (``d`` per free pose, then ``s`` per free landmark:
    :func:`posegraph.solve.sparsity.analyze_pattern` with ``points``); it is assembled exactly as the
    solver does (:class:`~posegraph.solve.objective.Objective`, edges, priors and landmark families),
    then each free landmark's ``s`` rows are moved into a block of ``d`` whose last ``d − s`` rows are
    decoupled unit rows (zero off-diagonal, 1 on the diagonal). ``pattern`` is then a pose-graph
    pattern over ``n + L`` pseudo-vertices (landmark ``l`` is ``n + l``, joined to each pose that
    measures it; held: the graph's held vertices and the ``FIX`` landmarks), and ``H⁻¹`` of it holds
    the solver's ``H⁻¹`` in the landmark blocks' first ``s`` rows and columns, the unit rows' inverse
    (the identity) apart: the uniform blocks the selected inversion (:func:`selected_inverse`) needs,
    for ``(d − s)/d`` more rows per landmark.
    """
    from posegraph.model.graph import held_vertices
    from posegraph.model.landmarks import observed_pairs
    from posegraph.solve.landmark_terms import point_variables
    from posegraph.solve.sparsity import analyze_pattern

    landmarks, n, d = graph.landmarks, graph.num_vertices, graph.group.dim
    points = landmarks.positions if points is None else np.asarray(points, dtype=np.float64)
    if points.shape != landmarks.positions.shape:
        raise ValueError(f"points must have shape {landmarks.positions.shape}, got {points.shape}")
    held = held_vertices(graph)
    mixed = analyze_pattern(n, graph.edge_from, graph.edge_to, held, d, point_variables(graph))
    data = _solver_hessian(graph, mixed, np.asarray(poses, dtype=np.float64), points)
    pose, landmark = observed_pairs(landmarks)
    padded = analyze_pattern(n + landmarks.count, np.r_[graph.edge_from, pose], np.r_[graph.edge_to, n + landmark],
                             np.r_[held, landmarks.fixed], d)  # fmt: skip
    return padded, _padded_values(mixed, data, padded)


def _solver_hessian(graph, pattern, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """CSC ``data`` of the solver's H (no loss) in ``pattern``, as :func:`posegraph.solve.optimize` assembles it."""
    from posegraph.solve.landmark_terms import add_landmark_hessian
    from posegraph.solve.objective import Objective
    from posegraph.solve.sparsity import hessian_values
    from posegraph.solve.unary import add_prior_hessian

    objective = Objective(graph)
    blocks = objective.linearize(poses, objective.evaluate(poses, points))
    data = hessian_values(pattern, blocks.hessian_slice)
    if blocks.priors is not None:
        add_prior_hessian(pattern, data, blocks.priors)
    add_landmark_hessian(pattern, data, blocks.landmarks)
    return data


def _padded_values(mixed, data: np.ndarray, padded) -> np.ndarray:
    """``data`` of the mixed-block pattern ``mixed`` moved into the equal-block pattern ``padded``
    (:func:`landmark_hessian_at`), the free landmarks' unit rows added."""
    d, s, first = mixed.block_size, mixed.point_size, mixed.pose_dimension

    def moved(rows):  # a mixed row's row in the padded system (pose rows stay; landmark j's a-th: d·(P + j) + a)
        rows = np.asarray(rows, dtype=np.int64)
        point = rows - first
        return np.where(rows < first, rows, first + d * (point // max(s, 1)) + point % max(s, 1))

    size = padded.dimension
    keys = moved(mixed.entry_columns) * size + moved(mixed.indices)
    padded_keys = padded.entry_columns.astype(np.int64) * size + padded.indices
    position = np.searchsorted(padded_keys, keys)
    if np.any(position >= len(padded_keys)) or np.any(padded_keys[np.minimum(position, len(padded_keys) - 1)] != keys):
        raise RuntimeError("the padded pattern misses an entry of the landmark graph's H")
    values = np.zeros(padded.nnz)
    values[position] = data
    free_points = int(np.count_nonzero(mixed.point_variable_of >= 0))
    unit = (first + d * np.arange(free_points)[:, None] + np.arange(s, d)).ravel()
    values[padded.diagonal[unit]] = 1.0
    return values


@dataclass(frozen=True, eq=False)
class CSCFactor:
    """A lower-triangular sparse factor ``L`` in CSC arrays."""

    indptr: np.ndarray
    """``(N + 1,)`` column pointers."""
    indices: np.ndarray
    """``(nnz,)`` row indices."""
    data: np.ndarray
    """``(nnz,)`` values."""


def factor_hessian(pattern, data, solver: str = "auto") -> tuple[CSCFactor, np.ndarray]:
    """``(L, permutation)`` with ``H[perm][:, perm] = L Lᵀ``, by the solver's linear backend.

    ``pattern``/``data``: H as :func:`hessian_at` returns it; ``solver`` as
    :func:`posegraph.solve.linear.make_linear_solver` (``"auto"``: CHOLMOD through cvxopt, ordered
    by :func:`posegraph.linalg.cholmod.auto_ordering` on the vertex graph — AMD, or METIS nested
    dissection from 10,000 free vertices — and postordered by CHOLMOD; SuperLU without cvxopt).
    The backend hands its factor over (``factor(release=True)``): one copy of L fewer. The order
    keeps each vertex's ``d`` variables together (a block ordering, postordered: a vertex's
    variables form a chain of the elimination tree); checked. Raises
    :class:`posegraph.linalg.cholmod.NotPositiveDefiniteError` for an H that is not positive definite.
    """
    backend = _factorised(pattern, data, solver)
    return _handed_over(backend, pattern.block_size)


def _factorised(pattern, data, solver: str):
    """The solver's linear backend for ``pattern``, factorised with ``data``."""
    from posegraph.solve.linear import make_linear_solver

    backend = make_linear_solver(solver, pattern, "auto", blas_threads=1)
    backend.factorize(data)
    return backend


def _handed_over(backend, d: int) -> tuple[CSCFactor, np.ndarray]:
    """``(L, permutation)`` from a factorised backend, which gives its factor up; the order checked."""
    indptr, indices, values, permutation = backend.factor(release=True)
    blocks = permutation.reshape(-1, d)
    if np.any(blocks % d != np.arange(d)) or np.any(blocks // d != blocks[:, :1] // d):
        raise RuntimeError("the factor's order splits a vertex's variables: not a block ordering")
    return CSCFactor(indptr, indices, values), permutation


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


def selected_inverse(factor: BlockFactor, columns=None, overwrite: bool = False) -> np.ndarray:
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
    for these columns' blocks; the other blocks of the result are zero. ``None``: all.

    ``overwrite``: Σ is written over ``factor.values`` (returned; the factor is then spent), which
    saves a copy of L's size: each supernode's blocks of ``L`` are read by that supernode's step
    alone, before it writes its Σ blocks in their place.
    """
    starts = supernodes(factor)
    sigma = factor.values if overwrite else np.zeros_like(factor.values)
    visit = np.arange(starts.shape[0] - 1)
    if columns is not None:
        visit = np.unique(np.searchsorted(starts, ancestor_closure(factor, columns), side="right") - 1)
        if overwrite:  # the blocks of the supernodes not visited keep L's values: zero them
            supernode = np.searchsorted(starts, factor.columns, side="right") - 1
            sigma[~np.isin(supernode, visit)] = 0.0
    first, last = starts[visit], starts[visit + 1] - 1
    width = last - first + 1
    height = width + np.diff(factor.indptr)[last] - 1
    # Supernodes at one depth of the supernodal tree do not depend on each other: done top down,
    # one batch per depth and shape. Those no other visited supernode descends from are needed by
    # none: done last, batched by shape alone (on sphere2500 about half, most 1 column × 5 rows).
    parent = factor.parents()[last]
    node_of = np.where(parent >= 0, np.searchsorted(first, parent, side="right") - 1, -1)  # parent's supernode
    has_child = np.zeros(visit.shape[0], dtype=bool)
    has_child[node_of[node_of >= 0]] = True
    shape = width * (int(height.max(initial=0)) + 1) + height
    inner = np.flatnonzero(has_child)
    for group in _groups(_depths(node_of)[inner] * (int(shape.max(initial=0)) + 1) + shape[inner]):
        batch = inner[group]
        _update_supernodes(factor, sigma, first[batch], int(width[batch[0]]), int(height[batch[0]]))
    leaves = np.flatnonzero(~has_child)
    for group in _groups(shape[leaves]):
        batch = leaves[group]
        _update_supernodes(factor, sigma, first[batch], int(width[batch[0]]), int(height[batch[0]]))
    return sigma


def _depths(parent: np.ndarray) -> np.ndarray:
    """Depth of each node of a forest whose parents come after their children (``-1``: a root)."""
    depth = np.zeros(parent.shape[0], dtype=np.int64)
    for k, up in zip(range(parent.shape[0] - 1, -1, -1), parent[::-1].tolist()):
        if up >= 0:
            depth[k] = depth[up] + 1
    return depth


def _groups(keys: np.ndarray) -> list[np.ndarray]:
    """Indices of equal ``keys``, one array per key, keys ascending."""
    if keys.size == 0:
        return []
    order = np.argsort(keys, kind="stable")
    cuts = np.flatnonzero(np.diff(keys[order])) + 1
    return np.split(order, cuts)


def _update_supernodes(factor: BlockFactor, sigma: np.ndarray, first: np.ndarray, width: int, height: int) -> None:
    """One step of :func:`selected_inverse` for ``g`` independent supernodes of equal shape, batched.

    ``first`` ``(g,)``: their first block columns; ``width`` columns and ``height`` block rows each
    (rows: the supernode's columns, then its last column's rows below). Writes their Σ blocks.
    """
    d, g = factor.block, first.shape[0]
    last = first + width - 1
    below = factor.rows[factor.indptr[last][:, None] + 1 + np.arange(height - width)]  # S, (g, h − w)
    r, j = np.arange(height)[:, None], np.arange(width)[None, :]
    start = factor.indptr[first[:, None] + np.arange(width)]  # (g, w): first block of each column
    if np.array_equal(factor.indptr[last + 1][:, None] - start, height - j):  # every block stored: no search
        position = np.where(r >= j, start[:, None, :] + r - j, -1)  # (g, h, w); −1: above the diagonal
    else:  # a relaxed supernode: some blocks of its dense trapezoid are not in L (zero)
        R = np.concatenate((first[:, None] + np.arange(width), below), axis=1)
        position = np.where(r >= j, factor.find(R[:, :, None], first[:, None, None] + j), -1)
    stored = position >= 0
    blocks = factor.values[np.where(stored, position, 0)] * stored[..., None, None]
    L_RD = blocks.transpose(0, 1, 3, 2, 4).reshape(g, height * d, width * d)
    inverse, sigma_RD = _inverse_products(L_RD[:, : width * d])  # L_DD⁻¹, L_DD⁻ᵀ L_DD⁻¹
    if height > width:
        B = _times_lower(L_RD[:, width * d :], inverse)  # L_SD L_DD⁻¹
        sigma_SD = _minus_sigma_product(factor, sigma, below, B)  # −Σ_SS B
        sigma_RD = np.concatenate((sigma_RD - np.swapaxes(B, -1, -2) @ sigma_SD, sigma_SD), axis=1)
    sigma[position[stored]] = sigma_RD.reshape(g, height, d, width, d).transpose(0, 1, 3, 2, 4)[stored]


def _inverse_products(lower: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(L⁻¹, L⁻ᵀ L⁻¹)`` ``(g, k, k)`` each, for lower-triangular ``L`` ``(g, k, k)``.

    One matrix (a large supernode): LAPACK ``dtrtri`` and ``dlauum`` (``k³/3`` flops each, against
    ``k³`` for a general inverse and ``2k³`` for a general product); many small ones: batched numpy.
    """
    if lower.shape[0] > 1:
        inverse = np.linalg.inv(lower)
        return inverse, np.swapaxes(inverse, -1, -2) @ inverse
    from scipy.linalg.lapack import dlauum, dtrtri

    inverse, info = dtrtri(lower[0], lower=1)
    if info:
        raise ArithmeticError(f"diagonal block of the factor is singular (LAPACK dtrtri info {info})")
    product, info = dlauum(inverse, lower=1)  # lower triangle of L⁻ᵀ L⁻¹; the strict upper is L⁻¹'s: 0
    product = product + np.tril(product, -1).T
    return inverse[None], product[None]


def _times_lower(A: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """``A · lower`` ``(g, m, k)`` for lower-triangular ``lower``: BLAS ``dtrmm`` (half a ``dgemm``) for one."""
    if A.shape[0] > 1:
        return A @ lower
    from scipy.linalg.blas import dtrmm

    return dtrmm(1.0, lower[0], A[0], side=1, lower=1)[None]


def _minus_sigma_product(factor: BlockFactor, sigma: np.ndarray, S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``−Σ_SS B`` ``(g, |S|·d, w)`` for rows of ascending block indices ``S`` ``(g, |S|)``.

    Gathers the stored ``Σ[max(S_a, S_b), min(S_a, S_b)]`` — right on and below the block diagonal,
    transposed above it — and transposes the blocks above back, then one general product (OpenBLAS's
    ``dgemm`` runs ~2.4× faster than its ``dsymm`` on a 528×528 Σ_SS, measured here).
    """
    g, m, d = S.shape[0], S.shape[1], factor.block
    position = factor.find(np.maximum(S[:, :, None], S[:, None, :]), np.minimum(S[:, :, None], S[:, None, :]))
    if np.any(position < 0):
        raise RuntimeError("factor pattern is not closed under elimination: a block of Σ_SS is missing")
    blocks = sigma[position]  # (g, m, m, d, d): Σ_ab for a ≥ b, Σ_abᵀ above
    upper = (np.arange(m)[:, None] < np.arange(m)[None, :])[:, :, None, None]
    full = np.where(upper, np.swapaxes(blocks, -1, -2), blocks).transpose(0, 1, 3, 2, 4).reshape(g, m * d, m * d)
    return -(full @ B)


@dataclass(frozen=True, eq=False)
class _Factorisation:
    factor: BlockFactor
    """Blocks of ``L``, ``P H Pᵀ = L Lᵀ``."""
    position: np.ndarray
    """``(n,)`` block column of each vertex in elimination order, ``-1`` for held vertices; ``(n + L,)``
    for a landmark graph, landmark ``l`` at ``n + l`` (:func:`landmark_hessian_at`)."""


def _factorise(graph, poses, keep_scalar: bool = False, solver: str = "auto", points=None) -> _Factorisation:
    """The block factor of H at ``poses`` (and ``points``, landmark graphs: :func:`landmark_hessian_at`)."""
    d = graph.group.dim
    if np.shape(poses) != np.shape(graph.poses):
        raise ValueError(f"poses must have shape {np.shape(graph.poses)}, got {np.shape(poses)}")
    pattern, data = hessian_at(graph, poses, points)
    vertices = pattern.num_vertices
    variable_of, p = pattern.variable_of, pattern.num_variables
    if p == 0:  # every vertex held: nothing to factorise
        empty = np.zeros(0, dtype=np.int64)
        L, permutation = CSCFactor(np.zeros(1, dtype=np.int64), empty, np.zeros(0)), empty
    else:
        backend = _factorised(pattern, data, solver)
        del pattern, data  # H's arrays go before cvxopt copies L (the peak of memory)
        L, permutation = _handed_over(backend, d)
        del backend
    rank = np.empty(p, dtype=np.int64)
    rank[permutation[::d] // d] = np.arange(p)  # block column of each variable
    free = variable_of >= 0
    position = np.full(vertices, -1, dtype=np.int64)
    position[free] = rank[variable_of[free]]
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


def marginal_covariances(graph, poses, vertices=None, *, points=None) -> np.ndarray:
    """Marginal covariance of each requested vertex's pose: ``(k, d, d)``.

    ``poses``: shaped as ``graph.poses``, the point of linearisation (normally the optimised
    poses), or the result that holds them (``OptimizeResult``, ``RobustResult``: its ``.poses`` and
    ``.points``); ``vertices``: ``(k,)`` vertex *indices* (``graph.index_of(ids)`` for ids), all vertices
    when ``None``; ``d = graph.group.dim``. Block ``a`` is ``Cov(δ)`` of ``X ⊕ δ = X·Exp(δ)`` for
    ``X`` the pose of ``vertices[a]``, in the group's tangent order (``[ω; v]`` for SE(3),
    ``[v_x, v_y, ω]`` for SE(2)) — the convention of ``gtsam.Marginals.marginalCovariance``. Held vertices (``FIX`` and component
    anchors) get zero: the gauge is theirs, the others' covariances are relative to them (module
    docstring). Cost: one sparse Cholesky and the selected inversion over the requested
    vertices' block columns and their elimination-tree ancestors (:func:`selected_inverse`).
    Raises :class:`posegraph.linalg.cholmod.NotPositiveDefiniteError` when H is not positive definite
    at ``poses``.

    A landmark graph's H includes its landmark measurements, linearised at ``points`` ``(L, s)``
    (:func:`landmark_hessian_at`), so the poses' covariances are those with the landmarks
    marginalised out; :func:`landmark_covariances` gives the landmarks'. Its points are required
    (:func:`linearisation_point`).
    """
    poses, points = linearisation_point(graph, poses, points, "marginal_covariances")
    vertices = _vertex_indices(graph, vertices)
    return _diagonal_blocks(graph, poses, points, vertices, graph.group.dim)


def linearisation_point(graph, poses, points, caller: str = "landmark_covariances"):
    """``(poses (n, k, k), points (L, s) or None)``: where a covariance function linearises.

    ``poses`` is an array or a result holding ``.poses`` and ``.points`` (``OptimizeResult``,
    ``RobustResult``; an explicit ``points`` wins over the result's). A landmark graph without
    points raises ``ValueError``: the graph's own positions are the file's, not the solve's, and
    the covariances at them are silently other ones (on DLR's ``dlr.g2o``: landmarks' up to 98 %,
    poses' up to 27 % apart, ``docs/covariances.md``); ``graph.landmarks.positions`` passed as
    ``points`` says that they are meant.
    """
    if hasattr(poses, "poses"):
        points = getattr(poses, "points", None) if points is None else points
        poses = poses.poses
    if graph.landmarks is not None and points is None:
        raise ValueError(
            f"{caller}: a landmark graph's covariances need its solved points as well as the poses: pass the "
            f"result ({caller}(graph, result)) or its points (points=result.points); the graph's own "
            "positions are the file's, not the optimised ones (points=graph.landmarks.positions if meant)"
        )
    return poses, points


def landmark_covariances(graph, poses, points=None, landmarks=None) -> np.ndarray:
    """Marginal covariance of each requested landmark's position: ``(k, s, s)``.

    ``poses`` ``(n, k, k)`` and ``points`` ``(L, s)`` are the point of linearisation, normally the
    optimised ones: ``landmark_covariances(graph, result)`` takes both from an ``OptimizeResult``
    (or ``RobustResult``), ``landmark_covariances(graph, result.poses, result.points)`` is the same;
    poses without points raise ``ValueError`` (:func:`linearisation_point`). ``landmarks``: ``(k,)`` landmark *indices* (``graph.landmarks.index_of(ids)`` for ids), all when
    None; ``s = graph.landmarks.space_dim``. Block ``a`` is ``Cov(δ)`` of ``p + δ`` (world frame,
    additive: the solver's landmark step) — gtsam's ``Marginals.marginalCovariance`` of a
    ``Point2``/``Point3``. Gauge as :func:`marginal_covariances`: relative to the held vertices;
    ``FIX`` landmarks get zero. One sparse Cholesky of the padded H (:func:`landmark_hessian_at`)
    and the selected inversion over the requested landmarks' block columns and their ancestors.
    """
    if graph.landmarks is None:
        raise ValueError("the graph has no landmarks")
    poses, points = linearisation_point(graph, poses, points)
    count = graph.landmarks.count
    landmarks = np.arange(count) if landmarks is None else np.asarray(landmarks)
    if landmarks.ndim != 1 or not np.issubdtype(landmarks.dtype, np.integer) and landmarks.size:
        raise ValueError("landmarks must be a 1-D array of landmark indices (graph.landmarks.index_of(ids) maps ids)")
    landmarks = landmarks.astype(np.int64)
    if np.any((landmarks < 0) | (landmarks >= count)):
        raise IndexError(f"landmark indices must lie in [0, {count}), got {landmarks[(landmarks < 0) | (landmarks >= count)][:5].tolist()}")
    s = graph.landmarks.space_dim
    return _diagonal_blocks(graph, poses, points, graph.num_vertices + landmarks, graph.group.dim)[:, :s, :s]


def _diagonal_blocks(graph, poses, points, blocks: np.ndarray, d: int) -> np.ndarray:
    """``(k, d, d)`` diagonal blocks of ``H⁻¹`` of the (pseudo-)vertices ``blocks`` ``(k,)``, zero for held ones."""
    out = np.zeros((blocks.shape[0], d, d))
    if blocks.size == 0:
        return out
    with _one_blas_thread():
        setup = _factorise(graph, poses, points=points)
        K = setup.position[blocks]
        free = K >= 0
        if not free.any():
            return out
        columns = np.unique(K[free])
        every = columns.shape[0] == setup.factor.indptr.shape[0] - 1
        sigma = selected_inverse(setup.factor, None if every else columns, overwrite=True)
    diagonal = sigma[setup.factor.indptr[K[free]]]
    out[free] = 0.5 * (diagonal + np.swapaxes(diagonal, -1, -2))
    return out


def joint_covariance(graph, poses, vertices, *, points=None) -> np.ndarray:
    """Joint covariance ``(k·d, k·d)`` of the poses of ``vertices`` ``(k,)`` (vertex indices).

    Block ``(a, b)`` (rows ``a·d : (a+1)·d``, columns ``b·d : (b+1)·d``) is ``Cov(δ_a, δ_b)`` of
    ``vertices[a]`` and ``vertices[b]``, in the given order; conventions and gauge as
    :func:`marginal_covariances` (rows and columns of held vertices are zero). When every pair's
    block lies in the factor's pattern (one vertex an elimination-tree ancestor of the other,
    joined in ``L``) they come from :func:`selected_inverse`; otherwise — the usual case for the
    two ends of a candidate loop closure — from ``k·d`` columns of ``H⁻¹``, two triangular solves
    with ``L`` each (:func:`_solve_columns`). ``poses`` may be a result; a landmark graph's H includes
    its landmarks at ``points``, required as in :func:`marginal_covariances`.
    """
    poses, points = linearisation_point(graph, poses, points, "joint_covariance")
    vertices = _vertex_indices(graph, vertices)
    d = graph.group.dim
    k = vertices.shape[0]
    out = np.zeros((k, d, k, d))
    if k == 0:
        return out.reshape(0, 0)
    with _one_blas_thread():
        setup = _factorise(graph, poses, keep_scalar=True, points=points)
        free = np.flatnonzero(setup.position[vertices] >= 0)
        if free.size == 0:
            return out.reshape(k * d, k * d)
        K = setup.position[vertices[free]]
        position = setup.factor.find(np.maximum.outer(K, K), np.minimum.outer(K, K))
        if np.all(position >= 0):
            blocks = selected_inverse(setup.factor, np.unique(K), overwrite=True)[position]  # Σ[max, min]
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
