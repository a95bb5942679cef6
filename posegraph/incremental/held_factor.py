"""Solves with a held factor plus exact low-rank terms: ``H̃ = H0 + E_K M E_Kᵀ``.

``H0`` is the matrix factorised last (``P H0 Pᵀ = L Lᵀ``, made at an earlier point over the edges then
present); the terms that differ from it are put back exactly, re-linearised at the current point at
every step, as a symmetric matrix ``M`` ``(q, q)`` on a few scalar columns ``K`` ``(q,)`` of H: the
Hessian blocks of the edges added since the factorisation (and of those left out of the held pattern),
minus the unit diagonal the factor gave the vertices added since (they were decoupled in ``H0``).
``M`` need not be definite; ``H̃`` must be. Any term given as "columns + values" can be one (a landmark
measurement's blocks as well as an edge's).

With ``Y_K = L⁻¹ P E_K`` (rows on the elimination-tree paths of ``K`` only,
:meth:`posegraph.linalg.cholmod.SparseCholesky.unit_forward`) and ``G = Y_KᵀY_K``,
``H̃ = Pᵀ L (I + Y_K M Y_Kᵀ) Lᵀ P`` and, by the push-through form of the Woodbury identity,

    H̃⁻¹ g = Pᵀ L⁻ᵀ z,   z = y − Y_K q,   q = M (I + G M)⁻¹ Y_Kᵀ y,   y = L⁻¹ P g,
    ½ gᵀ H̃⁻¹ g = ½ (‖y‖² − (Y_Kᵀ y)ᵀ q).

The Newton decrement comes from the forward half alone (the stopping test runs before the backward
solve is spent). ``Y`` and ``G`` depend on the factor only: they are computed once per column and
factor and kept (:class:`HeldFactor`), so a step costs one forward and one backward solve plus
products of size ``|R| × q`` (``R`` the union of the columns' path rows) and one ``q × q`` solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posegraph.linalg.native_threads import single_threaded_numpy_blas

__all__ = ["HeldFactor", "LowRankTerms", "ForwardHalf", "edge_terms"]


@dataclass
class LowRankTerms:
    """``E_K M E_Kᵀ``: ``columns`` ``(q,)`` distinct scalar columns of H, ``matrix`` ``(q, q)`` symmetric."""

    columns: np.ndarray
    matrix: np.ndarray

    @classmethod
    def empty(cls) -> LowRankTerms:
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 0)))


@dataclass
class ForwardHalf:
    """The forward half of ``H̃⁻¹ g``: ``z`` ``(D,)`` (permuted order) and ``decrement = ½ gᵀH̃⁻¹g``."""

    z: np.ndarray
    decrement: float


def edge_terms(parts, d: int, unit: np.ndarray | None = None) -> LowRankTerms:
    """``Σ`` of edge Hessians minus the unit diagonal of the block columns ``unit`` ``(u,)`` (vertices
    added since the factorisation) as low-rank terms. ``parts``: ``(h_ii, h_jj, h_ij, ci, cj)`` each, the
    blocks ``(p, d, d)`` (``H_ij`` at block row ``ci``, column ``cj``; a re-linearised old edge enters as
    its new blocks and the negated old ones) of edges joining block columns ``ci``, ``cj`` ``(p,)`` (−1:
    held, no block)."""
    unit = np.zeros(0, dtype=np.int64) if unit is None else unit
    h_ii, h_jj, h_ij, ci, cj = (np.concatenate(arrays) for arrays in zip(*parts))
    i_in, j_in = ci >= 0, cj >= 0
    variables = np.unique(np.concatenate([ci[i_in], cj[j_in], unit]))
    q = d * variables.shape[0]
    if q == 0:
        return LowRankTerms.empty()  # every end held
    at = lambda c: d * np.searchsorted(variables, c)[..., None] + np.arange(d)  # noqa: E731
    # A held end takes slot 0 with its blocks zeroed: they add nothing, and no masked copies are made.
    ri, rj = at(np.where(i_in, ci, variables[:1])), at(np.where(j_in, cj, variables[:1]))
    both = (i_in & j_in)[:, None, None]
    rows, columns = np.stack([ri, rj, ri, rj]), np.stack([ri, rj, rj, ri])  # (4, p, d)
    values = np.stack([h_ii * i_in[:, None, None], h_jj * j_in[:, None, None], h_ij * both,
                       np.swapaxes(h_ij, 1, 2) * both])  # (4, p, d, d)
    diagonal = at(unit).ravel() * (q + 1)
    flat = np.concatenate([(q * rows[..., :, None] + columns[..., None, :]).ravel(), diagonal])
    weights = np.concatenate([values.ravel(), -np.ones(diagonal.shape[0])])
    matrix = np.bincount(flat, weights, minlength=q * q).reshape(q, q)  # np.add.at is ~10× slower here
    return LowRankTerms((d * variables[:, None] + np.arange(d)).ravel(), matrix)


class HeldFactor:
    """A numeric factor (:class:`~posegraph.linalg.cholmod.SparseCholesky`, factorised) with the path
    columns ``Y`` and their Gram matrix ``G`` kept for the columns asked so far (module docstring).

    ``vertices``, ``edges``, ``priors``: the counts the factor was made over; ``weighted``: whether it
    carries the loss weights (a covariance's factor does not).
    """

    def __init__(self, factor, vertices: int, edges: int, priors: int, weighted: bool = True, blocks=None):
        self.factor, self.vertices, self.edges, self.priors, self.weighted = factor, vertices, edges, priors, weighted
        self.blocks = blocks  # the linearisation H0 was assembled from (re-linearised old edges subtract theirs)
        self.slot = np.full(factor.n, -1, dtype=np.int64)  # column of Y of each scalar column of H, −1: none
        self.rows = np.zeros(0, dtype=np.int64)  # R: ascending rows of L⁻¹ P E kept
        self.paths = np.zeros((0, 0))  # Y (|R|, c)
        self.gram = np.zeros((0, 0))  # G = YᵀY (c, c)
        self.terms = LowRankTerms.empty()  # the last terms solved with (for the covariances)
        self.flops: float | None = None  # of the numeric factorisation, read on first use

    def _extend(self, columns: np.ndarray) -> np.ndarray:
        """Make ``Y`` and ``G`` cover ``columns`` ``(q,)``; their slots ``(q,)``."""
        new = np.unique(columns[self.slot[columns] < 0])
        if new.shape[0]:
            rows, y = self.factor.unit_forward(new, with_rows=True)
            nonzero = np.any(y != 0.0, axis=1)  # explicit zeros of the decoupled future vertices' paths
            rows, y = rows[nonzero], y[nonzero]
            union = np.union1d(self.rows, rows)
            c = self.paths.shape[1]
            paths = np.zeros((union.shape[0], c + new.shape[0]))
            paths[np.searchsorted(union, self.rows), :c] = self.paths
            paths[np.searchsorted(union, rows), c:] = y
            cross = paths.T @ paths[:, c:]
            gram = np.empty((c + new.shape[0],) * 2)
            gram[:c, :c] = self.gram
            gram[:, c:] = cross
            gram[c:, :c] = cross[:c].T
            self.rows, self.paths, self.gram = union, paths, gram
            self.slot[new] = c + np.arange(new.shape[0])
        return self.slot[columns]

    def affordable(self, count: int, share: float) -> bool:
        """Whether a step with ``count`` columns of terms costs less than ``share`` of one numeric
        factorisation, in floating-point operations: ``3 q³`` for the ``q × q`` system (``G M`` and its
        LU) and ``4 |R| q`` for the products with ``Y``, against the factor's
        (:attr:`~posegraph.linalg.cholmod.SparseCholesky.factor_flops`); True when the factor cannot be read."""
        if self.flops is None:
            self.flops = self.factor.factor_flops or np.inf
        return 3.0 * count**3 + 4.0 * self.rows.shape[0] * count <= share * self.flops

    def _small_solve(self, terms: LowRankTerms, slots: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """``M (I + G_KK M)⁻¹ rhs`` ``(q,)`` or ``(q, r)``."""
        m = terms.matrix
        system = np.eye(m.shape[0]) + self.gram[np.ix_(slots, slots)] @ m
        return m @ np.linalg.solve(system, rhs)

    def _with_terms(self, y: np.ndarray, terms: LowRankTerms) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(z, t, q)`` for ``y = L⁻¹ P g`` ``(D,)`` or ``(D, r)``: ``t = Y_Kᵀ y``, ``q = M (I + G M)⁻¹ t``,
        ``z = y − Y_K q`` (a new array; module docstring)."""
        with single_threaded_numpy_blas():  # products of a few hundred columns: threads only contend
            slots = self._extend(terms.columns)
            part = self.paths[:, slots]
            t = part.T @ y[self.rows]
            q = self._small_solve(terms, slots, t)
            z = y.copy()
            z[self.rows] -= part @ q
        return z, t, q

    def forward(self, g: np.ndarray, terms: LowRankTerms) -> ForwardHalf:
        """The forward half of ``H̃⁻¹ g`` for ``g`` ``(D,)`` and the decrement ``½ gᵀH̃⁻¹g``."""
        self.terms = terms
        y = self.factor.forward(g)
        if terms.columns.shape[0] == 0:
            return ForwardHalf(y, 0.5 * float(y @ y))
        z, t, q = self._with_terms(y, terms)
        return ForwardHalf(z, 0.5 * (float(y @ y) - float(t @ q)))

    def backward(self, half: ForwardHalf) -> np.ndarray:
        """``H̃⁻¹ g`` ``(D,)`` from its forward half."""
        return self.factor.backward(half.z)

    def solve(self, rhs: np.ndarray, terms: LowRankTerms | None = None) -> np.ndarray:
        """``H̃⁻¹ rhs`` for ``rhs`` ``(D,)`` or ``(D, r)`` (``terms``: the last ones solved with, by default)."""
        terms = self.terms if terms is None else terms
        y = self.factor.forward(rhs)
        if terms.columns.shape[0]:
            y = self._with_terms(y, terms)[0]
        return self.factor.backward(y)

    def cover(self, columns: np.ndarray) -> None:
        """Make ``Y`` and ``G`` cover ``columns`` ``(q,)`` now: their path solves are then not paid by the
        next :meth:`inverse_block` (a covariance asked right after an update)."""
        with single_threaded_numpy_blas():
            self._extend(np.asarray(columns, dtype=np.int64))

    def inverse_block(self, columns: np.ndarray) -> np.ndarray:
        """``E_Cᵀ H̃⁻¹ E_C`` ``(c, c)`` for scalar columns ``columns`` ``(c,)``, on the last terms:
        ``G_CC − G_CK M (I + G_KK M)⁻¹ G_KC`` (path solves only)."""
        terms = self.terms
        with single_threaded_numpy_blas():
            asked = self._extend(np.asarray(columns, dtype=np.int64))
            block = self.gram[np.ix_(asked, asked)].copy()
            if terms.columns.shape[0]:
                slots = self._extend(terms.columns)
                cross = self.gram[np.ix_(slots, asked)]
                block -= cross.T @ self._small_solve(terms, slots, cross)
        return 0.5 * (block + block.T)
