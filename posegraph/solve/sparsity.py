"""Block sparsity of the normal equations, analysed once per graph.

The Gauss-Newton matrix ``H = Σ_e J_eᵀ Ω_e J_e`` of a pose graph has one
6×6 block per free vertex on the diagonal and one 6×6 block per pair of free
vertices joined by at least one edge. Only the **lower triangle** is stored,
in CSC form (the layout CHOLMOD reads with ``stype = -1``): diagonal blocks
keep their 21 entries on and below the diagonal, off-diagonal blocks all 36.

:func:`analyze_pattern` computes that layout once, together with the position
in the CSC ``data`` array of every entry of every edge's blocks ``H_ii``,
``H_jj`` and ``H_ij``. Each iteration :func:`hessian_values` and
:func:`gradient_values` then scatter-add the new per-edge blocks with one
``np.bincount`` each — no Python loop over edges. Entries that are not stored
(upper halves of diagonal blocks, blocks of held vertices) point at one extra
slot past the end, which is dropped.

numpy only: no scipy.sparse here (its import costs ~0.1 s per process, see
:mod:`posegraph.cholmod`); :func:`lower_csc` builds a scipy matrix on request.

Variables: vertex ``k`` is *free* unless ``held[k]``; free vertices are
numbered ``0..p-1`` in vertex order and vertex ``k``'s tangent occupies rows
``6·c .. 6·c+5`` of the system, ``c = variable_of[k]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HessianPattern", "analyze_pattern", "hessian_values", "gradient_values", "lower_matvec", "lower_csc"]

BLOCK = 6
"""Tangent dimension of SE(3): the block size."""


@dataclass(frozen=True, eq=False)
class HessianPattern:
    """Lower-triangular CSC layout of H and the scatter maps from per-edge blocks into it."""

    num_vertices: int
    """Number of graph vertices ``n``."""
    variable_of: np.ndarray
    """``(n,)`` int64: block column of each vertex, ``-1`` for held (fixed or anchored) vertices."""
    num_variables: int
    """Number of free vertices ``p``; the system has dimension ``6p``."""
    indptr: np.ndarray
    """``(6p + 1,)`` int32 CSC column pointers of the lower triangle."""
    indices: np.ndarray
    """``(nnz,)`` int32 CSC row indices, sorted within each column (diagonal entry first)."""
    diagonal: np.ndarray
    """``(6p,)`` int64 positions of the diagonal entries in ``data``."""
    block_indptr: np.ndarray
    """``(p + 1,)`` int32 CSC column pointers of the *vertex* pattern: the lower triangle of the
    p×p graph of free vertices, one entry per stored 6×6 block (for block orderings)."""
    block_indices: np.ndarray
    """``(p + number of off-diagonal blocks,)`` int32 rows of that pattern, diagonal first in each column."""
    entry_columns: np.ndarray
    """``(nnz,)`` int32 column of each stored entry (for :func:`lower_matvec`)."""
    hessian_positions: np.ndarray
    """``(3, 36·m)`` intp: row ``k`` holds the position in ``data`` of each entry of the ``k``-th
    per-edge blocks ``(m, 6, 6)`` raveled, ``k = 0, 1, 2`` for ``H_ii, H_jj, H_ij``; ``nnz`` for
    entries that are not stored."""
    gradient_positions: np.ndarray
    """``(12·m,)`` intp: row of ``g`` of each entry of ``grads.ravel()``, for ``grads`` of shape
    ``(m, 2, 6)`` stacking ``[g_i, g_j]`` of each edge; ``6p`` for held vertices' entries."""

    @property
    def dimension(self) -> int:
        """Size ``6p`` of the linear system."""
        return BLOCK * self.num_variables

    @property
    def nnz(self) -> int:
        """Number of stored (lower-triangle) entries."""
        return int(self.indices.shape[0])

    def expand(self, delta: np.ndarray) -> np.ndarray:
        """``(6p,)`` solution vector -> ``(n, 6)`` per-vertex tangent steps, zero for held vertices."""
        out = np.zeros((self.num_vertices, BLOCK))
        free = self.variable_of >= 0
        out[free] = np.asarray(delta).reshape(-1, BLOCK)
        return out


def analyze_pattern(num_vertices: int, edge_from, edge_to, held) -> HessianPattern:
    """Compute the block sparsity of H and the per-edge scatter maps.

    Parameters
    ----------
    num_vertices : int
    edge_from, edge_to : (m,) int arrays
        Vertex indices ``i`` and ``j`` of each edge (``i != j``).
    held : (n,) bool array
        Vertices held constant (fixed vertices and gauge anchors); they get no variables.
    """
    n = int(num_vertices)
    ei = np.asarray(edge_from, dtype=np.int64)
    ej = np.asarray(edge_to, dtype=np.int64)
    held = np.asarray(held, dtype=bool)
    if held.shape != (n,):
        raise ValueError(f"held must have shape ({n},), got {held.shape}")
    if np.any(ei == ej):
        raise ValueError("edges joining a vertex to itself are not supported")
    m = ei.shape[0]

    variable_of = np.full(n, -1, dtype=np.int64)
    free = ~held
    p = int(np.count_nonzero(free))
    variable_of[free] = np.arange(p)
    ci, cj = variable_of[ei], variable_of[ej]

    # --- block pattern (lower triangle): unique (block row, block col) pairs with row > col.
    both = (ci >= 0) & (cj >= 0)
    brow = np.maximum(ci[both], cj[both])
    bcol = np.minimum(ci[both], cj[both])
    stride = max(p, 1)
    # sorted by column, then row; sort + mask rather than np.unique, which (numpy 2.4) imports
    # numpy.ma to check for a masked array: 7 ms of every run
    key = np.sort(bcol * stride + brow)
    key = key[np.concatenate((key[:1] == key[:1], key[1:] != key[:-1]))]
    off_col, off_row = key // stride, key % stride
    off_per_col = np.bincount(off_col, minlength=p)
    # start of each block column's off-diagonal blocks in the sorted key list
    off_start = np.concatenate(([0], np.cumsum(off_per_col)))[:-1]

    # --- scalar CSC layout. Column 6c+q holds (6-q) diagonal-block rows then 6 rows per off-diagonal block.
    q = np.arange(BLOCK)
    col_len = (BLOCK - q)[None, :] + BLOCK * off_per_col[:, None]  # (p, 6)
    indptr = np.concatenate(([0], np.cumsum(col_len.ravel()))).astype(np.int64)
    nnz = int(indptr[-1])
    if nnz > np.iinfo(np.int32).max:
        raise ValueError("system too large for 32-bit sparse indices")
    column_start = indptr[:-1].reshape(p, BLOCK)  # data position where column 6c+q begins

    # Entry (row a, col b) of a 6×6 block, as index a·6+b of its row-major ravel: the 21 stored
    # entries of a diagonal block (a >= b), and all 36 of an off-diagonal one.
    pp, qq = np.meshgrid(q, q, indexing="ij")
    lower = (pp >= qq).ravel()
    low_row, low_col = pp.ravel()[lower], qq.ravel()[lower]
    full_row, full_col = pp.ravel(), qq.ravel()
    transpose = (full_col * BLOCK + full_row)  # entry (a, b) of Bᵀ is entry (b, a) of B
    # Data positions, one row per block: diagonal block of variable c (21 entries: its column 6c+b
    # starts with row 6c+b), and the s-th off-diagonal block of block column c (36 entries: column
    # 6c+b holds it after its 6−b diagonal-block rows, at 6·s + a).
    diagonal_slots = column_start[:, low_col] + (low_row - low_col)  # (p, 21)
    rank = np.arange(key.size) - off_start[off_col]  # s
    off_slots = column_start[off_col][:, full_col] + (BLOCK - full_col) + BLOCK * rank[:, None] + full_row  # (k, 36)

    indices = np.empty(nnz, dtype=np.int64)
    indices[diagonal_slots] = BLOCK * np.arange(p)[:, None] + low_row
    indices[off_slots] = BLOCK * off_row[:, None] + full_row
    diagonal = indptr[:-1].copy()  # diagonal entry is first in each column
    block_indptr = np.concatenate(([0], np.cumsum(1 + off_per_col)))
    block_indices = np.empty(p + key.size, dtype=np.int32)
    block_indices[block_indptr[:-1]] = np.arange(p)
    block_indices[block_indptr[off_col] + 1 + rank] = off_row

    # --- per-edge scatter into data: blocks (m, 3, 6, 6) = [H_ii, H_jj, H_ij], raveled per edge.
    # Gathered from small tables (one row per variable or stored block, plus a last row of "not
    # stored" = nnz that index −1 picks), rather than scattered entry by entry.
    entries = BLOCK * BLOCK
    diagonal_table = np.full((p + 1, entries), nnz, dtype=np.intp)  # entry (a, b) of variable c's H_cc
    diagonal_table[:p, np.flatnonzero(lower)] = diagonal_slots
    positions = np.empty((3, m, entries), dtype=np.intp)
    positions[0] = diagonal_table[ci]  # H_ii (ci = −1: held, the last row)
    positions[1] = diagonal_table[cj]  # H_jj
    # H_ij sits at block (ci, cj): stored as is when ci > cj, else as its transpose at (cj, ci);
    # rows k.. of the table are the transposed blocks.
    k = key.size
    off_table = np.full((2 * k + 1, entries), nnz, dtype=np.intp)
    off_table[:k] = off_slots
    off_table[k : 2 * k] = off_slots[:, transpose]
    which_block = np.full(m, 2 * k, dtype=np.intp)
    if np.any(both):
        a, b = ci[both], cj[both]
        which_block[both] = np.searchsorted(key, np.minimum(a, b) * stride + np.maximum(a, b)) + k * (a < b)
    positions[2] = off_table[which_block]
    hessian_positions = positions.reshape(3, -1)

    # --- gradient scatter: grads (m, 2, 6) = [g_i, g_j]
    gradient_table = np.full((p + 1, BLOCK), BLOCK * p, dtype=np.intp)
    gradient_table[:p] = BLOCK * np.arange(p)[:, None] + q[None, :]
    gradient_positions = np.stack([gradient_table[ci], gradient_table[cj]], axis=1).reshape(-1)

    return HessianPattern(
        num_vertices=n,
        variable_of=variable_of,
        num_variables=p,
        indptr=indptr.astype(np.int32),
        indices=indices.astype(np.int32),
        diagonal=diagonal,
        block_indptr=block_indptr.astype(np.int32),
        block_indices=block_indices,
        entry_columns=np.repeat(np.arange(BLOCK * p, dtype=np.int32), np.diff(indptr)),
        hessian_positions=hessian_positions,
        gradient_positions=gradient_positions,
    )


def hessian_values(pattern: HessianPattern, blocks) -> np.ndarray:
    """CSC ``data`` of the lower triangle of H from the per-edge blocks ``[H_ii, H_jj, H_ij]``.

    ``blocks`` is a sequence of three ``(m, 6, 6)`` arrays (what :func:`posegraph.solve.linearize.linearize`
    returns, no stacking copy needed) or one ``(m, 3, 6, 6)`` array. ``H_ij = A_iᵀ Ω A_j`` is the
    block at (block row of ``i``, block column of ``j``).
    """
    if isinstance(blocks, np.ndarray):
        blocks = [blocks[:, k] for k in range(3)]
    length = pattern.nnz + 1
    data = np.zeros(length)
    for positions, block in zip(pattern.hessian_positions, blocks):
        data += np.bincount(positions, weights=np.ascontiguousarray(block, dtype=np.float64).ravel(), minlength=length)
    return data[: pattern.nnz]


def gradient_values(pattern: HessianPattern, grads: np.ndarray) -> np.ndarray:
    """``(6p,)`` gradient ``g = Σ Jᵀ Ω e`` from per-edge ``(m, 2, 6)`` = ``[A_iᵀ Ω e, A_jᵀ Ω e]``."""
    weights = np.ascontiguousarray(grads, dtype=np.float64).ravel()
    d = pattern.dimension
    return np.bincount(pattern.gradient_positions, weights=weights, minlength=d + 1)[:d]


def lower_matvec(pattern: HessianPattern, data: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``tril(H) @ x`` for the lower triangle ``data`` of H: ``(6p,)``."""
    d = pattern.dimension
    return np.bincount(pattern.indices, weights=data * x[pattern.entry_columns], minlength=d)


def lower_csc(pattern: HessianPattern, data: np.ndarray):
    """The lower triangle of H as a ``scipy.sparse.csc_matrix`` (no copy of ``data``; imports scipy)."""
    import scipy.sparse as sp

    d = pattern.dimension
    return sp.csc_matrix((data, pattern.indices, pattern.indptr), shape=(d, d), copy=False)
