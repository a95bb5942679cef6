"""Normal equations of weighted linear factors over blocks of several sizes, laid out once.

The relaxation of a landmark graph (:mod:`posegraph.init.relaxation`) minimises

    ``Σ_f ‖A_a x_a + A_b x_b − y‖²_W``   (``W`` diagonal, one factor per edge or measurement)

over blocks ``x_c`` of two sizes (a pose's relaxed rotation and translation, a point). Its normal
matrix ``N = Σ_f A_fᵀ W_f A_f`` has a dense block wherever a factor couples two blocks. Summing
per-entry triplets of those products and sorting them (≈36 an observation in 2D, 1.2 M on a dense
world) is what cost most; here the *block* pattern is sorted instead (one key per factor) and the
CSC position of every entry follows from arithmetic:

with the stored blocks sorted by (block column ``C``, block row ``R ≥ C``), scalar column
``offsets[C] + y`` holds the rows of column ``C``'s blocks one after another, ``h_C`` entries in
all, so entry ``(x, y)`` of a stored block sits at ``base_C + y·h_C + above + x`` (``base_C`` the
entries of the columns before, ``above`` the rows of the blocks above it in its column). Diagonal
blocks are stored whole (the first of their column); CHOLMOD reads the lower triangle.

Blocks ``known`` (held poses, fixed points) have no variables; their factors' terms move to the
right-hand side (:meth:`BlockNormalEquations.right_hand_side`). A factor couples two different blocks
or is unary (``b = −1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posegraph.linalg import cholmod as cholmod_library

__all__ = ["Factors", "BlockNormalEquations"]


@dataclass
class Factors:
    """A batch of linear equations ``A_a x_a + A_b x_b = y`` between blocks ``a`` and ``b`` (``b`` −1: unary)."""

    a: np.ndarray  # (m,) block of the first unknown
    b: np.ndarray  # (m,) block of the second, −1 for none
    A_a: np.ndarray  # (m, rows, size_a)
    A_b: np.ndarray  # (m, rows, size_b)
    y: np.ndarray  # (m, rows)
    w: np.ndarray  # (m, rows) weight of each row


class BlockNormalEquations:
    """The block pattern of ``N`` for blocks ``sizes (B,)``, ``known (B,)`` bool, and factors coupling
    the block pairs ``pairs`` (a list of ``(a (m,), b (m,))``; every free block gets its diagonal);
    :meth:`matrix` its values for factors on those pairs, :meth:`solve` by CHOLMOD (from the cvxopt
    wheel, the scalar pattern ordered by AMD and analysed at the first solve) or SuperLU without it.

    ``offsets (B + 1,)``: block ``c``'s variables are ``offsets[c] .. offsets[c + 1]`` (none if known);
    ``indptr``, ``indices``: the CSC pattern (both triangles of the diagonal blocks, the lower
    triangle elsewhere)."""

    def __init__(self, sizes: np.ndarray, known: np.ndarray, pairs: list):
        self.sizes, self.known = np.asarray(sizes, np.int64), np.asarray(known, bool)
        free, count = ~self.known, len(self.sizes)
        self.offsets = np.concatenate(([0], np.cumsum(np.where(free, self.sizes, 0))))
        self.size = int(self.offsets[-1])
        rows, cols = [np.flatnonzero(free)], [np.flatnonzero(free)]
        for a, b in pairs:
            both = (b >= 0) & free[a] & free[np.maximum(b, 0)]
            rows.append(np.maximum(a, b)[both])
            cols.append(np.minimum(a, b)[both])
        keys = np.sort(np.concatenate(cols) * count + np.concatenate(rows))  # (np.unique imports numpy.ma: 7 ms)
        self._keys = keys[np.concatenate((keys[:1] == keys[:1], keys[1:] != keys[:-1]))]
        block_row, block_col = self._keys % count, self._keys // count
        heights = self.sizes[block_row]
        self._height = np.bincount(block_col, heights, minlength=count).astype(np.int64)  # h_C
        before = np.cumsum(heights) - heights
        first = np.searchsorted(block_col, np.arange(count))  # each column's first stored block (its diagonal)
        self._above = before - before[first[block_col]]  # rows of the blocks above in the same column
        self._base = np.concatenate(([0], np.cumsum(self.sizes * self._height)))[:-1]
        self.nnz = int(np.sum(self.sizes * self._height))
        self.indptr = np.concatenate(([0], np.cumsum(np.repeat(self._height[free], self.sizes[free]))))
        self.indices = self._row_indices(block_row, block_col)
        self._factor = None

    def _row_indices(self, block_row: np.ndarray, block_col: np.ndarray) -> np.ndarray:
        """``(nnz,)`` the scalar row of every stored entry (one batch per pair of block sizes, ≤ 4)."""
        indices = np.empty(self.nnz, np.int64)
        size_pairs = self.sizes[block_row] * (self.sizes.max() + 1) + self.sizes[block_col]
        for pair in set(size_pairs.tolist()):
            stored = np.flatnonzero(size_pairs == pair)
            R, C = block_row[stored, None, None], block_col[stored, None, None]
            x, y = np.arange(self.sizes[R[0, 0, 0]])[:, None], np.arange(self.sizes[C[0, 0, 0]])[None, :]
            at = self._base[C] + y * self._height[C] + self._above[stored, None, None] + x  # (stored, x, y)
            indices[at.ravel()] = np.broadcast_to(self.offsets[R] + x, at.shape).ravel()
        return indices

    def _stored(self, row_block: np.ndarray, col_block: np.ndarray) -> np.ndarray:
        """The index, among the stored blocks, of block ``(row_block, col_block)`` (``row ≥ col``, stored)."""
        return np.searchsorted(self._keys, col_block * len(self.sizes) + row_block)

    def _positions(self, a: np.ndarray, b, size_a: int, size_b: int) -> np.ndarray:
        """``(m, size_a, size_b)``: where entry ``(p, q)`` of ``A_aᵀ W A_b`` lands: in ``a``'s diagonal
        block when ``b`` is None; else in the stored block ``(max, min)``, transposed when ``a < b``."""
        p, q = np.arange(size_a), np.arange(size_b)
        if b is None:  # the diagonal block: entry (p, q) at base + q·h + p
            return (self._base[a][:, None] + p)[:, :, None] + self._height[a][:, None, None] * q
        lower, column = a > b, np.minimum(a, b)
        start = self._base[column] + self._above[self._stored(np.maximum(a, b), column)]
        stride_p = np.where(lower, 1, self._height[a])[:, None, None]
        stride_q = np.where(lower, self._height[b], 1)[:, None, None]
        return start[:, None, None] + stride_p * p[:, None] + stride_q * q

    def matrix(self, factors: list) -> np.ndarray:
        """``(nnz,)`` the values of ``Σ_f A_fᵀ W_f A_f`` over the free blocks (the factors' pairs in the pattern)."""
        positions, values = [], []
        for f in factors:
            b = np.where(f.b >= 0, f.b, 0)
            free_a, free_b = ~self.known[f.a], (f.b >= 0) & ~self.known[b]
            weighted_a, weighted_b = f.A_a * f.w[:, :, None], f.A_b * f.w[:, :, None]
            for u, A_u, v, weighted_v, both in (  # N is stored once per block pair: (a, a), (a, b), (b, b)
                (f.a, f.A_a, None, weighted_a, free_a), (f.a, f.A_a, b, weighted_b, free_a & free_b), (b, f.A_b, None, weighted_b, free_b),
            ):  # fmt: skip
                if not both.all():  # (masks copy: skipped when every block is free)
                    u, A_u, v, weighted_v = u[both], A_u[both], None if v is None else v[both], weighted_v[both]
                values.append((np.swapaxes(A_u, 1, 2) @ weighted_v).ravel())
                positions.append(self._positions(u, v, A_u.shape[2], weighted_v.shape[2]).ravel())
        return np.bincount(np.concatenate(positions), np.concatenate(values), minlength=self.nnz)

    def diagonal(self, data: np.ndarray) -> np.ndarray:
        """``(size,)`` the diagonal of the matrix with values ``data``."""
        free = np.flatnonzero(~self.known)
        y = np.arange(self.sizes.max())
        at = self._base[free][:, None] + y * (self._height[free][:, None] + 1)
        keep = y < self.sizes[free][:, None]
        return data[at[keep]]

    def right_hand_side(self, factors: list, values: np.ndarray) -> np.ndarray:
        """``(size,)`` ``g = Σ_f A_fᵀ W_f (y − A x_known)`` over the free blocks, the known blocks' terms
        moved to the right (``values (B, max size)``: the known blocks' values)."""
        g, known = np.zeros(self.size), self.known
        for f in factors:
            y = f.y - np.einsum("mrs,ms->mr", f.A_a, np.where(known[f.a][:, None], values[f.a, : f.A_a.shape[2]], 0.0))
            has_b = f.b >= 0
            b = np.where(has_b, f.b, 0)
            y = y - np.einsum("mrs,ms->mr", f.A_b, np.where((has_b & known[b])[:, None], values[b, : f.A_b.shape[2]], 0.0))
            for block, A, free in ((f.a, f.A_a, ~known[f.a]), (b, f.A_b, has_b & ~known[b])):
                at = self.offsets[block][:, None] + np.arange(A.shape[2])
                pull = np.einsum("mrs,mr->ms", A, f.w * y)
                g += np.bincount(at[free].ravel(), pull[free].ravel(), minlength=self.size)
        return g

    def solve(self, data: np.ndarray, g: np.ndarray) -> np.ndarray:
        """``x = N⁻¹ g`` for ``N`` with values ``data`` (:meth:`matrix`): CHOLMOD, its analysis made at
        the first call and kept, else SuperLU. Raises
        :class:`~posegraph.linalg.cholmod.NotPositiveDefiniteError` (CHOLMOD) when ``N`` is singular."""
        if self.size == 0:
            return np.zeros(0)
        if cholmod_library.load() is not None:
            if self._factor is None:
                self._factor = cholmod_library.SparseCholesky(self.indptr, self.indices, self.size, "amd")
            self._factor.factorize(data)
            return self._factor.solve(g)
        import scipy.sparse as sp
        from scipy.sparse.linalg import spsolve

        lower = sp.tril(sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size)))
        return spsolve((lower + sp.tril(lower, -1).T).tocsc(), g)
