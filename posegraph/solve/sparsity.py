"""Block sparsity of the normal equations, analysed once per graph.

The Gauss-Newton matrix ``H = Σ_e J_eᵀ Ω_e J_e`` of a pose graph has one
d×d block per free vertex on the diagonal and one d×d block per pair of free
vertices joined by at least one edge, ``d`` the tangent dimension of the
graph's group (6 for SE(3), 3 for SE(2)). Only the **lower triangle** is stored,
in CSC form (the layout CHOLMOD reads with ``stype = -1``): diagonal blocks
keep their d(d+1)/2 entries on and below the diagonal (21 for SE(3)),
off-diagonal blocks all d² (36).

:func:`analyze_pattern` computes that layout once, together with the position
in the CSC ``data`` array of every entry of every edge's blocks ``H_ii``,
``H_jj`` and ``H_ij``. Each iteration :func:`hessian_values` and
:func:`gradient_values` then scatter-add the new per-edge blocks with one
``np.bincount`` each — no Python loop over edges. Entries that are not stored
(upper halves of diagonal blocks, blocks of held vertices) point at one extra
slot past the end, which is dropped.

numpy only: no scipy.sparse here (its import costs ~0.1 s per process, see
:mod:`posegraph.linalg.cholmod`); :func:`lower_csc` builds a scipy matrix on request.

Variables: vertex ``k`` is *free* unless ``held[k]``; free vertices are
numbered ``0..p-1`` in vertex order and vertex ``k``'s tangent occupies rows
``d·c .. d·c+d−1`` of the system, ``c = variable_of[k]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posegraph.lie.group import SE3

__all__ = [
    "HessianPattern", "analyze_pattern", "hessian_values", "gradient_values", "lower_matvec", "lower_csc", "PinnedVariables",
    "SymmetricBlocks", "symmetric_blocks", "symmetric_block_values",
]

BLOCK = SE3.dim
"""The default block size, SE(3)'s tangent dimension (graphs of other groups pass ``group.dim``)."""


@dataclass(frozen=True, eq=False)
class HessianPattern:
    """Lower-triangular CSC layout of H and the scatter maps from per-edge blocks into it."""

    num_vertices: int
    """Number of graph vertices ``n``."""
    variable_of: np.ndarray
    """``(n,)`` int64: block column of each vertex, ``-1`` for held (fixed or anchored) vertices."""
    num_variables: int
    """Number of free vertices ``p``; the system has dimension ``dp``."""
    indptr: np.ndarray
    """``(dp + 1,)`` int32 CSC column pointers of the lower triangle."""
    indices: np.ndarray
    """``(nnz,)`` int32 CSC row indices, sorted within each column (diagonal entry first)."""
    diagonal: np.ndarray
    """``(dp,)`` int64 positions of the diagonal entries in ``data``."""
    block_indptr: np.ndarray
    """``(p + 1,)`` int32 CSC column pointers of the *vertex* pattern: the lower triangle of the
    p×p graph of free vertices, one entry per stored d×d block (for block orderings)."""
    block_indices: np.ndarray
    """``(p + number of off-diagonal blocks,)`` int32 rows of that pattern, diagonal first in each column."""
    hessian_positions: np.ndarray
    """``(3, d²·m)`` int32 (int64 past 2³¹ stored entries): row ``k`` holds the position in ``data`` of each entry of the ``k``-th
    per-edge blocks ``(m, d, d)`` raveled, ``k = 0, 1, 2`` for ``H_ii, H_jj, H_ij``; ``nnz`` for
    entries that are not stored."""
    gradient_positions: np.ndarray
    """``(2d·m,)`` int32 (int64 past 2³¹): row of ``g`` of each entry of ``grads.ravel()``, for ``grads`` of shape
    ``(m, 2, d)`` stacking ``[g_i, g_j]`` of each edge; ``dp`` for held vertices' entries."""
    block_size: int = BLOCK
    """Block size ``d``: the tangent dimension of the graph's group (6 for SE(3))."""

    @property
    def dimension(self) -> int:
        """Size ``dp`` of the linear system."""
        return self.block_size * self.num_variables

    @property
    def entry_columns(self) -> np.ndarray:
        """``(nnz,)`` int32 column of each stored entry, made anew at each use: as large as
        ``indices``, and needed only by the few who ask (a caller that asks often keeps it)."""
        return np.repeat(np.arange(self.dimension, dtype=np.int32), np.diff(self.indptr))

    @property
    def nnz(self) -> int:
        """Number of stored (lower-triangle) entries."""
        return int(self.indices.shape[0])

    def expand(self, delta: np.ndarray) -> np.ndarray:
        """``(dp,)`` solution vector -> ``(n, d)`` per-vertex tangent steps, zero for held vertices."""
        out = np.zeros((self.num_vertices, self.block_size))
        free = self.variable_of >= 0
        out[free] = np.asarray(delta).reshape(-1, self.block_size)
        return out


def analyze_pattern(num_vertices: int, edge_from, edge_to, held, block_size: int = BLOCK) -> HessianPattern:
    """Compute the block sparsity of H and the per-edge scatter maps.

    Parameters
    ----------
    num_vertices : int
    edge_from, edge_to : (m,) int arrays
        Vertex indices ``i`` and ``j`` of each edge (``i != j``).
    held : (n,) bool array
        Vertices held constant (fixed vertices and gauge anchors); they get no variables.
    block_size : int
        Tangent dimension ``d`` of the graph's group (``graph.group.dim``): the size of each block.
    """
    n, d = int(num_vertices), int(block_size)
    ei = np.asarray(edge_from, dtype=np.int64)
    ej = np.asarray(edge_to, dtype=np.int64)
    held = np.asarray(held, dtype=bool)
    if held.shape != (n,):
        raise ValueError(f"held must have shape ({n},), got {held.shape}")
    if np.any(ei == ej):
        raise ValueError("edges joining a vertex to itself are not supported")
    variable_of = np.full(n, -1, dtype=np.int64)
    p = int(np.count_nonzero(~held))
    variable_of[~held] = np.arange(p)
    ci, cj = variable_of[ei], variable_of[ej]
    blocks = _block_pattern(ci, cj, p)
    layout = _scalar_layout(blocks, p, d)
    hessian_positions = _hessian_positions(ci, cj, blocks, layout, p, d)
    gradient_table = np.full((p + 1, d), d * p, dtype=np.intp)  # row of g of entry q of vertex c
    gradient_table[:p] = d * np.arange(p)[:, None] + np.arange(d)[None, :]
    gradient_positions = _narrowest(np.stack([gradient_table[ci], gradient_table[cj]], axis=1).reshape(-1), d * p)
    return HessianPattern(
        num_vertices=n,
        variable_of=variable_of,
        num_variables=p,
        indptr=layout.indptr.astype(np.int32),
        indices=layout.indices.astype(np.int32),
        diagonal=layout.indptr[:-1].copy(),  # the diagonal entry is first in each column
        block_indptr=blocks.indptr.astype(np.int32),
        block_indices=blocks.indices,
        hessian_positions=hessian_positions,
        gradient_positions=gradient_positions,
        block_size=d,
    )


@dataclass(frozen=True)
class _Blocks:
    """The lower triangle of the p×p vertex pattern (:func:`_block_pattern`)."""

    key: np.ndarray  # (k,) sorted ``col·stride + row`` of each stored off-diagonal block, row > col
    stride: int
    col: np.ndarray  # (k,) block column of each off-diagonal block
    row: np.ndarray  # (k,) block row
    rank: np.ndarray  # (k,) position s of the block among the off-diagonal blocks of its column
    per_column: np.ndarray  # (p,) number of off-diagonal blocks per block column
    indptr: np.ndarray  # (p + 1,) CSC pointers of the vertex pattern, diagonal included
    indices: np.ndarray  # (p + k,) int32 rows, diagonal first in each column


def _block_pattern(ci: np.ndarray, cj: np.ndarray, p: int) -> _Blocks:
    """Unique (block row, block column) pairs with row > col over the edges joining two free vertices."""
    both = (ci >= 0) & (cj >= 0)
    stride = max(p, 1)
    # sorted by column, then row; sort + mask rather than np.unique, which (numpy 2.4) imports
    # numpy.ma to check for a masked array: 7 ms of every run
    key = np.sort(np.minimum(ci[both], cj[both]) * stride + np.maximum(ci[both], cj[both]))
    key = key[np.concatenate((key[:1] == key[:1], key[1:] != key[:-1]))]
    col, row = key // stride, key % stride
    per_column = np.bincount(col, minlength=p)
    first = np.concatenate(([0], np.cumsum(per_column)))[:-1]  # each column's first block in `key`
    rank = np.arange(key.size) - first[col]
    indptr = np.concatenate(([0], np.cumsum(1 + per_column)))
    indices = np.empty(p + key.size, dtype=np.int32)
    indices[indptr[:-1]] = np.arange(p)
    indices[indptr[col] + 1 + rank] = row
    return _Blocks(key, stride, col, row, rank, per_column, indptr, indices)


@dataclass(frozen=True)
class _Layout:
    """The scalar CSC layout of the lower triangle (:func:`_scalar_layout`)."""

    indptr: np.ndarray  # (dp + 1,) int64
    indices: np.ndarray  # (nnz,) int64
    diagonal_slots: np.ndarray  # (p, d(d+1)/2) data positions of the stored entries of each H_cc
    off_slots: np.ndarray  # (k, d²) data positions of the entries of each off-diagonal block
    lower: np.ndarray  # (d²,) bool: entry a·d + b of a block is on or below its diagonal


def _scalar_layout(blocks: _Blocks, p: int, d: int) -> _Layout:
    """CSC pointers and rows of the lower triangle, and where each block's entries sit in ``data``.

    Column ``d·c + q`` holds ``d − q`` rows of the diagonal block, then ``d`` rows per off-diagonal
    block of block column ``c``. Entry ``(a, b)`` of a block is index ``a·d + b`` of its row-major ravel.
    """
    q = np.arange(d)
    col_len = (d - q)[None, :] + d * blocks.per_column[:, None]  # (p, d)
    indptr = np.concatenate(([0], np.cumsum(col_len.ravel()))).astype(np.int64)
    nnz = int(indptr[-1])
    if nnz > np.iinfo(np.int32).max:
        raise ValueError("system too large for 32-bit sparse indices")
    column_start = indptr[:-1].reshape(p, d)  # data position where column d·c+q begins
    rows, cols = (grid.ravel() for grid in np.meshgrid(q, q, indexing="ij"))
    lower = rows >= cols
    low_row, low_col = rows[lower], cols[lower]
    # diagonal block of variable c: its column d·c+b starts with row d·c+b; the s-th off-diagonal
    # block of block column c: column d·c+b holds it after its d−b diagonal-block rows, at d·s + a
    diagonal_slots = column_start[:, low_col] + (low_row - low_col)
    off_slots = column_start[blocks.col][:, cols] + (d - cols) + d * blocks.rank[:, None] + rows
    indices = np.empty(nnz, dtype=np.int64)
    indices[diagonal_slots] = d * np.arange(p)[:, None] + low_row
    indices[off_slots] = d * blocks.row[:, None] + rows
    return _Layout(indptr, indices, diagonal_slots, off_slots, lower)


def _hessian_positions(ci, cj, blocks: _Blocks, layout: _Layout, p: int, d: int) -> np.ndarray:
    """``(3, d²·m)`` data positions of every entry of every edge's ``H_ii``, ``H_jj``, ``H_ij``.

    Gathered from small tables (one row per variable or stored block, plus a last row of "not
    stored" = nnz that index −1 picks), rather than scattered entry by entry.
    """
    nnz, entries, m = int(layout.indptr[-1]), d * d, ci.shape[0]
    diagonal_table = np.full((p + 1, entries), nnz, dtype=np.intp)  # entry (a, b) of variable c's H_cc
    diagonal_table[:p, np.flatnonzero(layout.lower)] = layout.diagonal_slots
    positions = np.empty((3, m, entries), dtype=np.intp)
    positions[0] = diagonal_table[ci]  # H_ii (ci = −1: held, the last row)
    positions[1] = diagonal_table[cj]  # H_jj
    # H_ij sits at block (ci, cj): stored as is when ci > cj, else as its transpose at (cj, ci);
    # rows k.. of the table are the transposed blocks (entry (a, b) of Bᵀ is entry (b, a) of B).
    k = blocks.key.size
    transpose = np.arange(entries).reshape(d, d).T.ravel()
    off_table = np.full((2 * k + 1, entries), nnz, dtype=np.intp)
    off_table[:k] = layout.off_slots
    off_table[k : 2 * k] = layout.off_slots[:, transpose]
    which_block = np.full(m, 2 * k, dtype=np.intp)
    both = (ci >= 0) & (cj >= 0)
    if np.any(both):
        a, b = ci[both], cj[both]
        which_block[both] = np.searchsorted(blocks.key, np.minimum(a, b) * blocks.stride + np.maximum(a, b)) + k * (a < b)
    positions[2] = off_table[which_block]
    return _narrowest(positions.reshape(3, -1), nnz)


def _narrowest(positions: np.ndarray, largest: int) -> np.ndarray:
    """``positions`` as int32 when every value up to ``largest`` fits (all pose graphs below ~10⁷
    edges): half the memory of the scatter maps, which live as long as the analysis (36 positions an
    SE(3) edge and block, 864 bytes an edge in int64). ``np.bincount`` widens a slice at a time."""
    return positions.astype(np.int32) if largest < np.iinfo(np.int32).max else positions


SLICE_EDGES = 1 << 14
"""Edges whose blocks :func:`hessian_values` adds at a time."""


def hessian_values(pattern: HessianPattern, blocks, slice_edges: int = SLICE_EDGES) -> np.ndarray:
    """CSC ``data`` of the lower triangle of H from the per-edge blocks ``[H_ii, H_jj, H_ij]``.

    ``blocks`` is a sequence of three ``(m, d, d)`` arrays (what :func:`posegraph.solve.linearize.linearize`
    returns, no stacking copy needed), one ``(m, 3, d, d)`` array, or a function ``part -> (H_ii,
    H_jj, H_ij)`` of a ``slice`` of the edges, called ``slice_edges`` edges at a time so that the
    blocks of all edges never exist at once (:meth:`posegraph.solve.linearize.EdgeBlocks.hessian_slice`).
    ``H_ij = A_iᵀ Ω A_j`` is the block at (block row of ``i``, block column of ``j``). Entries are
    added in place (``np.add.at``: no temporary as large as H), slice by slice, then block by block.
    """
    if isinstance(blocks, np.ndarray):
        blocks = [blocks[:, k] for k in range(3)]
    part_blocks = blocks if callable(blocks) else (lambda part: [b[part] for b in blocks])
    entries = pattern.block_size**2
    m = pattern.hessian_positions.shape[1] // entries
    data = np.zeros(pattern.nnz + 1)
    for begin in range(0, m, slice_edges):
        part = slice(begin, min(begin + slice_edges, m))
        where = slice(part.start * entries, part.stop * entries)
        for positions, block in zip(pattern.hessian_positions, part_blocks(part)):
            np.add.at(data, positions[where], np.ascontiguousarray(block, dtype=np.float64).ravel())
    return data[: pattern.nnz]


def gradient_values(pattern: HessianPattern, grads: np.ndarray) -> np.ndarray:
    """``(dp,)`` gradient ``g = Σ Jᵀ Ω e`` from per-edge ``(m, 2, d)`` = ``[A_iᵀ Ω e, A_jᵀ Ω e]``."""
    weights = np.ascontiguousarray(grads, dtype=np.float64).ravel()
    d = pattern.dimension
    return np.bincount(pattern.gradient_positions, weights=weights, minlength=d + 1)[:d]


def lower_matvec(pattern: HessianPattern, data: np.ndarray, x: np.ndarray, chunk: int = 1 << 20) -> np.ndarray:
    """``tril(H) @ x`` for the lower triangle ``data`` of H: ``(dp,)``.

    Column by column, ~``chunk`` entries at a time: no temporary as large as ``data``."""
    d, indptr = pattern.dimension, pattern.indptr
    out = np.zeros(d)
    begin = 0
    while begin < d:
        end = max(begin + 1, int(np.searchsorted(indptr, indptr[begin] + chunk, side="right")) - 1)
        end = min(end, d)
        first, last = int(indptr[begin]), int(indptr[end])
        columns = np.repeat(np.arange(begin, end), np.diff(indptr[begin : end + 1]))
        out += np.bincount(pattern.indices[first:last], weights=data[first:last] * x[columns], minlength=d)
        begin = end
    return out


@dataclass(frozen=True, eq=False)
class PinnedVariables:
    """Free vertices of a pattern held at their pose after all: their variables stay in the system
    but decouple from it — unit diagonal, zero off-diagonal entries and zero gradient — so their
    step is exactly 0 and the other variables solve the system with them eliminated (held)."""

    rows: np.ndarray
    """``(d·q,)`` rows of ``g`` (and of H) of the ``q`` pinned vertices."""
    coupling: np.ndarray
    """``(nnz,)`` bool: entries of ``data`` in a pinned row or column."""
    diagonal: np.ndarray
    """``(d·q,)`` positions in ``data`` of the pinned rows' diagonal entries."""

    @classmethod
    def of(cls, pattern: HessianPattern, vertices: np.ndarray) -> "PinnedVariables":
        """For ``vertices`` ``(n,)`` bool (vertices the pattern already holds are ignored)."""
        vertices = np.asarray(vertices, dtype=bool)
        if vertices.shape != (pattern.num_vertices,):
            raise ValueError(f"held vertices must have shape ({pattern.num_vertices},), got {vertices.shape}")
        variables = pattern.variable_of[vertices & (pattern.variable_of >= 0)]
        rows = (pattern.block_size * variables[:, None] + np.arange(pattern.block_size)).ravel()
        pinned_row = np.zeros(pattern.dimension, dtype=bool)
        pinned_row[rows] = True
        coupling = pinned_row[pattern.indices] | pinned_row[pattern.entry_columns]
        return cls(rows, coupling, pattern.diagonal[rows])

    def decouple(self, data: np.ndarray) -> np.ndarray:
        """The lower-triangle ``data`` of H with the pinned rows and columns made unit (in place)."""
        data[self.coupling] = 0.0
        data[self.diagonal] = 1.0
        return data

    def zero_gradient(self, gradient: np.ndarray) -> np.ndarray:
        """``gradient`` ``(dp,)`` with the pinned rows zeroed (in place)."""
        gradient[self.rows] = 0.0
        return gradient


def lower_csc(pattern: HessianPattern, data: np.ndarray):
    """The lower triangle of H as a ``scipy.sparse.csc_matrix`` (no copy of ``data``; imports scipy)."""
    import scipy.sparse as sp

    d = pattern.dimension
    return sp.csc_matrix((data, pattern.indices, pattern.indptr), shape=(d, d), copy=False)


@dataclass(frozen=True, eq=False)
class SymmetricBlocks:
    """Block-CSR layout of the whole symmetric H (both triangles, d×d blocks, for iterative
    solvers) and, for each of its blocks, the stored lower-triangle block it is read from."""

    indptr: np.ndarray
    """``(p + 1,)`` int64 block-row pointers."""
    indices: np.ndarray
    """``(b,)`` int32 block column of each block, sorted within each block row."""
    source_column: np.ndarray
    """``(b,)`` int32 block column ``c`` of the stored block each block reads (the vertex pattern's)."""
    source_rank: np.ndarray
    """``(b,)`` int32 its rank among column ``c``'s stored blocks (0: the diagonal block)."""
    transposed: np.ndarray
    """``(b,)`` bool: the block is the transpose of its stored block (it lies above the diagonal)."""
    diagonal_blocks: np.ndarray
    """``(p,)`` int64: index of each variable's diagonal block among the ``b``."""


def symmetric_blocks(pattern: HessianPattern) -> SymmetricBlocks:
    """The :class:`SymmetricBlocks` of ``pattern``: every stored block once as is, and every
    off-diagonal one again transposed, sorted by (block row, block column)."""
    p = pattern.num_variables
    stored_column = np.repeat(np.arange(p, dtype=np.int64), np.diff(pattern.block_indptr))
    stored_row = pattern.block_indices.astype(np.int64)
    rank = np.arange(stored_row.size) - pattern.block_indptr[stored_column]
    off = rank > 0
    rows = np.concatenate([stored_row, stored_column[off]])
    columns = np.concatenate([stored_column, stored_row[off]])
    order = np.argsort(rows * max(p, 1) + columns, kind="stable")
    source = np.concatenate([np.arange(stored_row.size), np.flatnonzero(off)])[order]
    return SymmetricBlocks(
        indptr=np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=p))]),
        indices=columns[order].astype(np.int32),
        source_column=stored_column[source].astype(np.int32),
        source_rank=rank[source].astype(np.int32),
        transposed=(np.arange(order.size) >= stored_row.size)[order],
        diagonal_blocks=np.flatnonzero((rows == columns)[order]),
    )


def symmetric_block_values(
    pattern: HessianPattern, layout: SymmetricBlocks, data: np.ndarray, out: np.ndarray | None = None, chunk: int = 1 << 16
) -> np.ndarray:
    """``(b, d, d)`` values of the blocks of ``layout`` from the lower-triangle ``data`` of H.

    Entry ``(a, e)`` of the ``s``-th stored block of block column ``c`` (:func:`_scalar_layout`)
    sits at ``indptr[d·c + e] + (d − e) + d·(s − 1) + a`` for ``s ≥ 1``; a diagonal block stores
    only ``a ≥ e``, at ``indptr[d·c + e] + (a − e)``. Positions are made ``chunk`` blocks at a time,
    so no table as large as ``data`` is kept. ``out``: a buffer of the right shape to fill.
    """
    d = pattern.block_size
    count = layout.indices.size
    out = np.empty((count, d, d)) if out is None else out
    a, e = np.meshgrid(np.arange(d), np.arange(d), indexing="ij")
    for begin in range(0, count, chunk):
        part = slice(begin, min(begin + chunk, count))
        flip = layout.transposed[part][:, None, None]
        row, col = np.where(flip, e, a), np.where(flip, a, e)  # (a, e) of the stored block
        rank = layout.source_rank[part][:, None, None].astype(np.int64)
        diagonal = rank == 0
        row, col = np.where(diagonal, np.maximum(row, col), row), np.where(diagonal, np.minimum(row, col), col)
        start = pattern.indptr[d * layout.source_column[part][:, None, None].astype(np.int64) + col]
        offset = np.where(diagonal, row - col, (d - col) + d * (rank - 1) + row)
        out[part] = data[start + offset]
    return out
