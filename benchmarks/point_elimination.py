"""Point elimination for landmark graphs, the two forms measured against CHOLMOD's AMD (issue 44).

Not used by the solver: ``benchmarks/bench_point_elimination.py`` measured both slower than today's
path on every landmark file tried (``docs/landmarks.md``, *Point elimination*), so they live here,
beside the measurement, as :class:`~posegraph.solve.linear.LinearSolver` backends that
:func:`posegraph.solve.optimizer.optimize` takes through its ``analysis``.

The system, variables ordered as :func:`posegraph.solve.sparsity.analyze_pattern` numbers them (the
``P`` free poses, blocks of ``d``, then the ``Q`` free points, blocks of ``s``)::

    [ Hxx  Hxp ] [δx]   [bx]
    [ Hpx  Hpp ] [δp] = [bp]        Hpp block diagonal (no term joins two points)

* :class:`PointsFirstCholmod`: CHOLMOD with an ordering that eliminates every point first, then the
  poses in the AMD order of the reduced pose graph (poses joined when they share a point). The same
  elimination as the Schur complement, inside the supernodal factorisation.
* :class:`SchurComplementSolver`: g2o's block solvers' form, explicitly. Each factorisation inverts
  the ``s×s`` blocks of ``Hpp`` (damped) in one batch, forms ``S = Hxx − Hxp Hpp⁻¹ Hpx`` on a pattern
  analysed once (one ``d×d`` product per pair of poses that see a point, summed into ``S``'s CSC
  ``data`` with one ``np.bincount``) and factorises ``S`` by CHOLMOD (AMD); each solve is
  ``S δx = bx − Hxp Hpp⁻¹ bp``, then ``δp = Hpp⁻¹ (bp − Hpx δx)``.
"""

from __future__ import annotations

import numpy as np

from posegraph.linalg import cholmod as cholmod_library
from posegraph.solve.linear import CholmodSolver, LinearSolver, NotPositiveDefiniteError, shifted
from posegraph.solve.sparsity import HessianPattern, analyze_pattern

__all__ = ["PointsFirstCholmod", "SchurComplementSolver", "point_incidence", "points_first_order", "reduced_pose_graph"]


def point_incidence(pattern: HessianPattern):
    """``(pose (K,), point (K,))``: the stored pose–point blocks of the vertex pattern, by point then pose
    (pose in ``0..P−1``, point in ``0..Q−1``)."""
    count = pattern.num_pose_variables
    columns = np.repeat(np.arange(pattern.num_variables), np.diff(pattern.block_indptr))
    rows = pattern.block_indices.astype(np.int64)
    joined = (columns < count) & (rows >= count)
    pose, point = columns[joined], rows[joined] - count
    order = np.lexsort((pose, point))
    return pose[order], point[order]


def _pose_pairs(pattern: HessianPattern):
    """``(row, column)`` with ``row > column`` of the stored pose–pose blocks of the vertex pattern."""
    count = pattern.num_pose_variables
    columns = np.repeat(np.arange(pattern.num_variables), np.diff(pattern.block_indptr))
    rows = pattern.block_indices.astype(np.int64)
    off = (columns < count) & (rows < count) & (rows != columns)
    return rows[off], columns[off]


def _pairs_within_points(point: np.ndarray):
    """``(first (N,), second (N,))``: every pair of pose–point blocks ``first ≥ second`` of one point
    (blocks sorted by point), ``N = Σ k(k+1)/2`` over points seen ``k`` times."""
    count = point.size
    start = np.searchsorted(point, point, side="left")  # each block's point's first block
    lengths = np.arange(count) - start + 1
    first = np.repeat(np.arange(count), lengths)
    within = np.arange(first.size) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return first, start[first] + within


def reduced_pose_graph(pattern: HessianPattern) -> HessianPattern:
    """The pattern of the Schur complement ``S`` on the poses: a pose–pose block wherever ``H`` has one,
    and between every two poses that see one point (block size ``d``, every pose free)."""
    pose, point = point_incidence(pattern)
    first, second = _pairs_within_points(point)
    rows, columns = _pose_pairs(pattern)
    shared_a, shared_b = pose[first], pose[second]
    off = shared_a != shared_b
    count = pattern.num_pose_variables
    return analyze_pattern(
        count, np.concatenate([rows, shared_a[off]]), np.concatenate([columns, shared_b[off]]), np.zeros(count, dtype=bool),
        pattern.block_size, positions=False,
    )  # fmt: skip


def points_first_order(pattern: HessianPattern) -> np.ndarray:
    """``(p,)`` variables in elimination order: every point, then the poses in the AMD order of
    :func:`reduced_pose_graph`."""
    reduced = reduced_pose_graph(pattern)
    poses = cholmod_library.fill_reducing_order(reduced.block_indptr, reduced.block_indices, reduced.num_variables, "amd")
    return np.concatenate([np.arange(pattern.num_pose_variables, pattern.num_variables), poses])


class PointsFirstCholmod(CholmodSolver):
    """CHOLMOD on the whole ``H``, the points eliminated first (:func:`points_first_order`)."""

    def __init__(self, pattern: HessianPattern, blas_threads: int | None = 1):
        self.ordering = "points first"
        self._pattern = pattern
        permutation = cholmod_library.block_permutation(points_first_order(pattern), pattern.sizes)
        self._cholesky = cholmod_library.SparseCholesky(
            pattern.indptr, pattern.indices, pattern.dimension, threads=blas_threads, permutation=permutation)
        self.name = "cholmod (supernodal, points first, then AMD of the reduced pose graph) via cvxopt"


def _entry_keys(pattern_indptr: np.ndarray, pattern_indices: np.ndarray, size: int) -> np.ndarray:
    """``(nnz,)`` ``column·size + row`` of each stored entry of a CSC pattern: ascending (rows sorted)."""
    columns = np.repeat(np.arange(size, dtype=np.int64), np.diff(pattern_indptr))
    return columns * size + pattern_indices


def _positions(keys: np.ndarray, rows: np.ndarray, columns: np.ndarray, size: int) -> np.ndarray:
    """Positions in ``data`` of entries ``(rows, columns)`` (any shape) that the pattern of ``keys`` stores."""
    wanted = np.asarray(columns, dtype=np.int64) * size + rows
    found = np.searchsorted(keys, wanted)
    if not np.array_equal(keys[np.minimum(found, keys.size - 1)], wanted):
        raise ValueError("an entry is not in the pattern")
    return found


class SchurComplementSolver(LinearSolver):
    """The points eliminated explicitly: ``S = Hxx − Hxp Hpp⁻¹ Hpx`` factorised by CHOLMOD, the points
    back-substituted (module docstring). The gathers and scatters are made once, here."""

    CHUNK = 1 << 16
    """Pairs of pose–point blocks whose products are made at a time (bounded temporaries)."""

    def __init__(self, pattern: HessianPattern, blas_threads: int | None = 1):
        d, s, poses = pattern.block_size, pattern.point_size, pattern.num_pose_variables
        self._pattern, self._sizes = pattern, (poses, pattern.num_variables - poses, d, s)
        size, reduced = pattern.dimension, reduced_pose_graph(pattern)
        keys = _entry_keys(pattern.indptr.astype(np.int64), pattern.indices.astype(np.int64), size)
        self._pose, self._point = point_incidence(pattern)
        self._hpp, self._hpx = self._point_gathers(keys)
        self._first, self._second = _pairs_within_points(self._point)
        self._reduced, self._scatter = reduced, self._reduced_scatters(keys, reduced)
        self._cholesky = cholmod_library.block_cholesky(
            reduced.indptr, reduced.indices, reduced.block_indptr, reduced.block_indices, poses, d, "amd", blas_threads)
        self._values = None  # (Hpp⁻¹ (Q, s, s), Hpx (K, s, d)) of the last factorisation
        self.name = "schur complement on the points, cholmod (supernodal, amd) on the poses via cvxopt"

    def _point_gathers(self, keys: np.ndarray):
        """Positions in ``data`` of ``Hpp`` ``(Q, s, s)`` (both triangles read from the lower) and of the
        pose–point blocks ``Hpx`` ``(K, s, d)`` (row: the point's, column: the pose's)."""
        poses, points, d, s = self._sizes
        size, first = self._pattern.dimension, d * poses
        a, b = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
        base = first + s * np.arange(points)[:, None, None]
        hpp = _positions(keys, base + np.maximum(a, b), base + np.minimum(a, b), size)
        a, e = np.meshgrid(np.arange(s), np.arange(d), indexing="ij")
        rows = first + s * self._point[:, None, None] + a
        hpx = _positions(keys, rows, d * self._pose[:, None, None] + e, size)
        return hpp, hpx

    def _reduced_scatters(self, keys: np.ndarray, reduced: HessianPattern):
        """``(source, target, pairs)``: ``Hxx``'s entries (positions in ``data``) and where they go in
        ``S``'s ``data``; ``(N, d, d)`` where each pair's product goes (``S.nnz``: an upper entry of a
        diagonal block, not stored)."""
        poses, _, d, _ = self._sizes
        size, reduced_size = self._pattern.dimension, reduced.dimension
        rows, columns = keys % size, keys // size
        source = np.flatnonzero((rows < reduced_size) & (columns < reduced_size))
        reduced_keys = _entry_keys(reduced.indptr.astype(np.int64), reduced.indices.astype(np.int64), reduced_size)
        target = _positions(reduced_keys, rows[source], columns[source], reduced_size)
        a, e = np.meshgrid(np.arange(d), np.arange(d), indexing="ij")
        pair_rows = d * self._pose[self._first][:, None, None] + a  # pose of the first block ≥ the second's
        pair_columns = d * self._pose[self._second][:, None, None] + e
        lower = pair_rows >= pair_columns
        pairs = np.full(pair_rows.shape, reduced.nnz, dtype=np.int64)
        pairs[lower] = _positions(reduced_keys, pair_rows[lower], pair_columns[lower], reduced_size)
        return source, target, pairs

    def factorize(self, data: np.ndarray, shift: np.ndarray | None = None) -> None:
        """``Hpp`` (damped) inverted block by block, ``S`` formed and factorised; :class:`NotPositiveDefiniteError`
        when a point block or ``S`` is not positive definite."""
        self._values = None
        full = shifted(self._pattern, np.asarray(data, dtype=np.float64), shift)
        if not np.isfinite(full).all():
            raise NotPositiveDefiniteError("matrix has non-finite entries")
        hpp = full[self._hpp]
        try:
            np.linalg.cholesky(hpp)
        except np.linalg.LinAlgError as err:
            raise NotPositiveDefiniteError("a point's block is not positive definite") from err
        inverse, hpx = np.linalg.inv(hpp), full[self._hpx]
        self._cholesky.factorize(self._complement(full, inverse, hpx))
        self._values = (inverse, hpx)

    def _complement(self, full: np.ndarray, inverse: np.ndarray, hpx: np.ndarray) -> np.ndarray:
        """``data`` of ``S = Hxx − Σ_points Hxp Hpp⁻¹ Hpx`` (lower triangle, :func:`reduced_pose_graph`'s layout)."""
        source, target, pairs = self._scatter
        weighted = inverse[self._point] @ hpx  # Hpp⁻¹ Hpx per pose–point block (K, s, d)
        out = np.zeros(self._reduced.nnz + 1)
        for begin in range(0, self._first.size, self.CHUNK):
            part = slice(begin, begin + self.CHUNK)
            products = np.matmul(hpx[self._first[part]].swapaxes(1, 2), weighted[self._second[part]])
            out -= np.bincount(pairs[part].ravel(), weights=products.ravel(), minlength=out.size)
        out[target] += full[source]
        return out[:-1]

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``δx`` from ``S δx = bx − Hxp Hpp⁻¹ bp``, then ``δp = Hpp⁻¹ (bp − Hpx δx)``."""
        if self._values is None:
            raise RuntimeError("factorize() must succeed before solve()")
        poses, points, d, s = self._sizes
        inverse, hpx = self._values
        rhs = np.asarray(rhs, dtype=np.float64)
        bx, bp = rhs[: d * poses], rhs[d * poses :].reshape(points, s)
        eliminated = np.einsum("kae,ka->ke", hpx, np.einsum("qab,qb->qa", inverse, bp)[self._point])
        pose_rows = (d * self._pose[:, None] + np.arange(d)).ravel()
        step_x = self._cholesky.solve(bx - np.bincount(pose_rows, weights=eliminated.ravel(), minlength=d * poses))
        coupled = np.einsum("kae,ke->ka", hpx, step_x.reshape(poses, d)[self._pose])
        point_rows = (s * self._point[:, None] + np.arange(s)).ravel()
        coupled = np.bincount(point_rows, weights=coupled.ravel(), minlength=s * points).reshape(points, s)
        return np.concatenate([step_x, np.einsum("qab,qb->qa", inverse, bp - coupled).ravel()])

    def factor(self, release: bool = False):
        raise NotImplementedError("the Schur complement solver gives no factor of the whole H")
