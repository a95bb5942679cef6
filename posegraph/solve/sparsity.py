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
    "HessianPattern", "PointVariables", "PointFamily", "analyze_pattern", "hessian_values", "gradient_values", "lower_matvec", "lower_csc", "PinnedVariables",
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
    hessian_positions: np.ndarray | None
    """``(3, d²·m)`` int32 (int64 past 2³¹ stored entries): row ``k`` holds the position in ``data`` of each entry of the ``k``-th
    per-edge blocks ``(m, d, d)`` raveled, ``k = 0, 1, 2`` for ``H_ii, H_jj, H_ij``; ``nnz`` for
    entries that are not stored (None: not made, ``analyze_pattern(positions=False)``)."""
    gradient_positions: np.ndarray | None
    """``(2d·m,)`` int32 (int64 past 2³¹): row of ``g`` of each entry of ``grads.ravel()``, for ``grads`` of shape
    ``(m, 2, d)`` stacking ``[g_i, g_j]`` of each edge; ``dp`` for held vertices' entries (None: not made)."""
    block_size: int = BLOCK
    """Block size ``d`` of the poses: the tangent dimension of the graph's group (6 for SE(3))."""
    sizes: np.ndarray | None = None
    """``(p,)`` int64 block size of each variable: ``d`` for the poses, then ``s`` for the landmarks."""
    offsets: np.ndarray | None = None
    """``(p + 1,)`` int64 first row of each variable's block (``offsets[-1]`` the system's size)."""
    point_variable_of: np.ndarray | None = None
    """``(L,)`` int64 variable of each landmark, −1 for held ones; empty for a pose graph."""
    point_size: int = 0
    """The landmarks' block size ``s`` (0 for a pose graph)."""
    family_positions: tuple = ()
    """Per landmark family (:class:`PointFamily`): ``(hessian, gradient)`` scatter maps
    (:func:`_family_positions`), in the order of ``PointVariables.families``; empty with ``positions=False``."""
    placement: "_System | None" = None
    """With ``positions=False``: where the entries of factors placed later go (:meth:`_System.pair_positions`,
    :meth:`_System.diagonal_positions`, :meth:`_System.rows`), for a caller that places them itself."""

    @property
    def dimension(self) -> int:
        """Size of the linear system: ``dp`` for a pose graph, ``d·P + s·Q`` with landmarks."""
        return int(self.offsets[-1])

    @property
    def num_pose_variables(self) -> int:
        """Number ``P`` of free poses (the first ``P`` variables)."""
        return int(np.count_nonzero(self.variable_of >= 0))

    @property
    def pose_dimension(self) -> int:
        """Rows ``d·P`` of the poses' steps (the landmarks' follow)."""
        return self.block_size * self.num_pose_variables

    def expand_points(self, delta: np.ndarray) -> np.ndarray:
        """``(D,)`` solution vector -> ``(L, s)`` per-landmark steps, zero for held landmarks."""
        out = np.zeros((self.point_variable_of.size, self.point_size))
        free = self.point_variable_of >= 0
        out[free] = np.asarray(delta)[self.pose_dimension :].reshape(-1, self.point_size)
        return out

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
        out[free] = np.asarray(delta)[: self.pose_dimension].reshape(-1, self.block_size)
        return out


def analyze_pattern(
    num_vertices: int, edge_from, edge_to, held, block_size: int = BLOCK, points: "PointVariables | None" = None,
    positions: bool = True,
) -> HessianPattern:
    """Compute the block sparsity of H and the per-edge scatter maps.

    Parameters
    ----------
    num_vertices : int
    edge_from, edge_to : (m,) int arrays
        Vertex indices ``i`` and ``j`` of each edge (``i != j``).
    held : (n,) bool array
        Vertices held constant (fixed vertices and gauge anchors); they get no variables.
    block_size : int
        Tangent dimension ``d`` of the graph's group (``graph.group.dim``): the size of each pose block.
    points : PointVariables, optional
        Landmark variables (``s``-sized blocks, numbered after the poses) and the families of
        measurements joining them to poses (:class:`PointVariables`); None: a pose graph.
    positions : bool
        False: no per-edge scatter maps (None) nor the families' (empty), for a caller that places them itself
        (``incremental.whole``, through ``placement``).
    """
    n, d = int(num_vertices), int(block_size)
    ei = np.asarray(edge_from, dtype=np.int64)
    ej = np.asarray(edge_to, dtype=np.int64)
    held = np.asarray(held, dtype=bool)
    if held.shape != (n,):
        raise ValueError(f"held must have shape ({n},), got {held.shape}")
    if np.any(ei == ej):
        raise ValueError("edges joining a vertex to itself are not supported")
    points = PointVariables.none() if points is None else points
    variable_of, point_variable_of, sizes = _number_variables(held, points, d)
    p, offsets = sizes.size, np.concatenate(([0], np.cumsum(sizes))).astype(np.int64)
    ci, cj = variable_of[ei], variable_of[ej]
    families = [(variable_of[f.pose] if f.pose is not None else None, point_variable_of[f.point]) for f in points.families]
    binary = [(a, b) for a, b in families if a is not None]
    blocks = _block_pattern(np.concatenate([ci] + [a for a, _ in binary]), np.concatenate([cj] + [b for _, b in binary]), p)
    system = _scalar_layout(blocks, sizes, offsets)
    layout, placement = system.layout, None if positions else system
    hessian_positions, gradient_positions, family_positions = (
        _scatter_maps(system, ci, cj, d, families, points.size) if positions else (None, None, ()))
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
        sizes=sizes,
        offsets=offsets,
        point_variable_of=point_variable_of,
        point_size=points.size,
        family_positions=family_positions,
        placement=placement,
    )


def _scatter_maps(system: "_System", ci: np.ndarray, cj: np.ndarray, d: int, families: list, s: int) -> tuple:
    """``(hessian_positions, gradient_positions, family_positions)`` of :class:`HessianPattern`: where the
    edges joining variables ``ci``, ``cj`` and each landmark family's measurements put their entries."""
    hessian = _narrowest(np.stack(system.pair_positions(ci, cj, d, d)).reshape(3, -1), system.nnz)
    rows = np.stack([system.rows(ci, d), system.rows(cj, d)], axis=1).reshape(-1)
    return hessian, _narrowest(rows, system.dimension), tuple(_family_positions(system, a, b, d, s) for a, b in families)


@dataclass(frozen=True, eq=False)
class PointFamily:
    """One family of landmark measurements as the pattern sees it: which pose sees which point."""

    pose: np.ndarray | None
    """``(q,)`` int64 vertex index of each measurement's pose, or None for a unary family (point priors)."""
    point: np.ndarray
    """``(q,)`` int64 landmark index of each measurement."""


@dataclass(frozen=True, eq=False)
class PointVariables:
    """The landmark variables of a pattern: ``count`` points of dimension ``size``, some held."""

    count: int
    """Number of landmarks ``L``."""
    size: int
    """Their dimension ``s`` (2 or 3): the size of their blocks."""
    held: np.ndarray
    """``(L,)`` bool: landmarks without variables (``FIX``)."""
    families: tuple = ()
    """The measurement families (:class:`PointFamily`), in the order the solver linearises them."""

    @classmethod
    def none(cls) -> "PointVariables":
        return cls(0, 0, np.zeros(0, dtype=bool), ())


def _number_variables(held: np.ndarray, points: PointVariables, d: int):
    """Variables: the free poses in vertex order, then the free landmarks; their block sizes."""
    variable_of = np.full(held.size, -1, dtype=np.int64)
    poses = int(np.count_nonzero(~held))
    variable_of[~held] = np.arange(poses)
    point_variable_of = np.full(points.count, -1, dtype=np.int64)
    free_points = ~np.asarray(points.held, dtype=bool)
    point_variable_of[free_points] = poses + np.arange(int(np.count_nonzero(free_points)))
    sizes = np.concatenate([np.full(poses, d), np.full(int(np.count_nonzero(free_points)), points.size)]).astype(np.int64)
    return variable_of, point_variable_of, sizes


def _family_positions(system: "_System", pose_var, point_var, d: int, s: int) -> tuple:
    """The scatter maps of one landmark family: ``(hessian, gradient)``.

    Binary: ``hessian`` = data positions of ``H_pose,pose (q·d²)``, ``H_point,point (q·s²)``,
    ``H_pose,point (q·d·s)``, each raveled, one after the other, and ``gradient`` ``(q·(d+s),)`` rows
    of ``[g_pose, g_point]`` per measurement; unary: of ``H_point,point`` and ``(q·s,)``. ``nnz`` /
    the system's size where not stored (held variables, upper halves of diagonal blocks).
    """
    if pose_var is None:
        hessian, gradient = system.diagonal_positions(point_var, s), system.rows(point_var, s)
    else:
        hessian = np.concatenate([b.reshape(-1) for b in system.pair_positions(pose_var, point_var, d, s)])
        gradient = np.concatenate([system.rows(pose_var, d), system.rows(point_var, s)], axis=1)
    return _narrowest(hessian.reshape(-1), system.nnz), _narrowest(gradient.reshape(-1), system.dimension)


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

    indptr: np.ndarray  # (D + 1,) int64, D = Σ sizes
    indices: np.ndarray  # (nnz,) int64
    row_start: np.ndarray  # (k,) int64: rows of column c's off-diagonal part above the block's first row


def _scalar_layout(blocks: _Blocks, sizes: np.ndarray, offsets: np.ndarray) -> "_System":
    """CSC pointers and rows of the lower triangle, for blocks of sizes ``sizes`` ``(p,)``, returned
    with the positions of the blocks' entries in it (:class:`_System`, its ``layout``).

    Variable ``c`` owns rows and columns ``offsets[c] .. offsets[c] + z_c − 1`` (``z_c = sizes[c]``).
    Its column ``offsets[c] + b`` holds ``z_c − b`` rows of the diagonal block, then, block by block
    in row order, the ``z_r`` rows of each off-diagonal block (row variable ``r``) of block column ``c``.
    """
    p, k = sizes.size, blocks.key.size
    dimension = int(offsets[-1])
    row_sizes = sizes[blocks.row]
    off_rows = np.bincount(blocks.col, weights=row_sizes, minlength=p).astype(np.int64)
    column_variable = np.repeat(np.arange(p), sizes)
    local = np.arange(dimension) - offsets[column_variable]
    indptr = np.concatenate(([0], np.cumsum(sizes[column_variable] - local + off_rows[column_variable]))).astype(np.int64)
    nnz = int(indptr[-1])
    if nnz > np.iinfo(np.int32).max:
        raise ValueError("system too large for 32-bit sparse indices")
    before = np.cumsum(row_sizes) - row_sizes  # rows of all earlier blocks, then of the column's earlier ones
    column_first = (np.concatenate(([0], np.cumsum(blocks.per_column)))[:-1])[blocks.col]
    row_start = before - before[column_first] if k else np.zeros(0, dtype=np.int64)
    layout = _Layout(indptr, np.empty(nnz, dtype=np.int64), row_start.astype(np.int64))
    system = _System(blocks, layout, offsets, nnz)
    for z in _distinct(sizes):
        variables = np.flatnonzero(sizes == z)
        a, b = _grid(int(z), int(z))
        keep = a >= b
        layout.indices[system.diagonal_slots(variables, int(z))[:, keep]] = offsets[variables][:, None] + a[keep]
    column_sizes = sizes[blocks.col]
    stride = int(sizes.max(initial=0)) + 1
    for pair in _distinct(row_sizes * stride + column_sizes):  # the (row size, column size) pairs present
        zr, zc = divmod(pair, stride)
        which = np.flatnonzero((row_sizes == zr) & (column_sizes == zc))
        a, _ = _grid(zr, zc)
        layout.indices[system.off_slots(which, zr, zc)] = offsets[blocks.row[which]][:, None] + a
    return system


def _distinct(values: np.ndarray) -> list:
    """The distinct values of an int array, ascending, as Python ints (sort + mask: ``np.unique``
    imports ``numpy.ma`` on first use, ~7 ms of a run; the block sizes take one or two values)."""
    ordered = np.sort(values)
    return ordered[np.concatenate(([True], ordered[1:] != ordered[:-1]))].tolist() if ordered.size else []


def _grid(rows: int, columns: int):
    """Row and column ``(rows·columns,)`` of each entry of a ``rows``×``columns`` block raveled row-major."""
    return np.repeat(np.arange(rows), columns), np.tile(np.arange(columns), rows)


@dataclass(frozen=True)
class _System:
    """Where the entries of blocks sit in the CSC ``data`` of a layout, and rows of ``g``."""

    blocks: _Blocks
    layout: _Layout
    offsets: np.ndarray
    nnz: int

    @property
    def dimension(self) -> int:
        return int(self.offsets[-1])

    def diagonal_slots(self, variables: np.ndarray, z: int) -> np.ndarray:
        """``(v, z²)`` data position of entry ``(a, b)``, ``a ≥ b``, of each variable's diagonal block
        (only those entries are meaningful): ``indptr[offsets[c] + b] + a − b``."""
        a, b = _grid(z, z)
        return self.layout.indptr[self.offsets[variables][:, None] + b] + (a - b)

    def off_slots(self, which: np.ndarray, zr: int, zc: int) -> np.ndarray:
        """``(w, zr·zc)`` data position of entry ``(a, b)`` of the stored off-diagonal blocks ``which``:
        ``indptr[offsets[col] + b] + (zc − b) + row_start + a``."""
        a, b = _grid(zr, zc)
        start = self.layout.indptr[self.offsets[self.blocks.col[which]][:, None] + b]
        return start + (zc - b) + self.layout.row_start[which][:, None] + a

    def diagonal_positions(self, variables: np.ndarray, z: int) -> np.ndarray:
        """``(m, z²)`` data positions of ``H_cc`` for variables ``c`` of size ``z`` (−1: held); ``nnz``
        where not stored. Gathered from a table of one row per variable (and a last "not stored" row
        that index −1 picks), rather than computed entry by entry for every factor."""
        a, b = _grid(z, z)
        sizes = np.diff(self.offsets)
        table = np.full((sizes.size + 1, z * z), self.nnz, dtype=np.intp)
        own = np.flatnonzero(sizes == z)
        lower = np.flatnonzero(a >= b)
        table[own[:, None], lower] = self.diagonal_slots(own, z)[:, lower]
        return table[variables]

    def pair_positions(self, ci: np.ndarray, cj: np.ndarray, zi: int, zj: int):
        """``(H_ii (m, zi²), H_jj (m, zj²), H_ij (m, zi·zj))`` data positions for factors joining
        variables ``ci`` (size ``zi``) and ``cj`` (size ``zj``). ``H_ij`` sits at block (``ci``, ``cj``):
        stored as is when ``ci > cj``, else as its transpose at (``cj``, ``ci``), entry ``(a, b)`` at
        ``(b, a)``: rows ``0..k−1`` of the gathered table hold the stored blocks, rows ``k..2k−1``
        their transposes, row ``2k`` "not stored"."""
        k, blocks = self.blocks.key.size, self.blocks
        sizes = np.diff(self.offsets)
        table = np.full((2 * k + 1, zi * zj), self.nnz, dtype=np.intp)
        as_is = np.flatnonzero((sizes[blocks.row] == zi) & (sizes[blocks.col] == zj))
        table[as_is] = self.off_slots(as_is, zi, zj)
        flipped = np.flatnonzero((sizes[blocks.row] == zj) & (sizes[blocks.col] == zi))
        table[k + flipped] = self.off_slots(flipped, zj, zi).reshape(-1, zj, zi).swapaxes(1, 2).reshape(-1, zi * zj)
        which = np.full(ci.shape[0], 2 * k, dtype=np.intp)
        both = (ci >= 0) & (cj >= 0)
        if np.any(both):
            a, b = ci[both], cj[both]
            which[both] = np.searchsorted(blocks.key, np.minimum(a, b) * blocks.stride + np.maximum(a, b)) + k * (a < b)
        return self.diagonal_positions(ci, zi), self.diagonal_positions(cj, zj), table[which]

    def rows(self, variables: np.ndarray, z: int) -> np.ndarray:
        """``(m, z)`` rows of ``g`` of each variable's entries; ``dimension`` for held variables."""
        free = variables >= 0
        safe = np.where(free, variables, 0) if self.offsets.size > 1 else np.zeros_like(variables)
        return np.where(free[:, None], self.offsets[safe][:, None] + np.arange(z), self.dimension)


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
    # float64 even with no edge (numpy's bincount of no weights is int64)
    return np.bincount(pattern.gradient_positions, weights=weights, minlength=d + 1)[:d].astype(np.float64, copy=False)


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
    """``(d·q + s·l,)`` rows of ``g`` (and of H) of the ``q`` pinned vertices and ``l`` pinned landmarks."""
    coupling: np.ndarray
    """``(nnz,)`` bool: entries of ``data`` in a pinned row or column."""
    diagonal: np.ndarray
    """``(d·q,)`` positions in ``data`` of the pinned rows' diagonal entries."""

    @classmethod
    def of(cls, pattern: HessianPattern, vertices: np.ndarray, points: np.ndarray | None = None) -> "PinnedVariables":
        """For ``vertices`` ``(n,)`` bool and, with landmarks, ``points`` ``(L,)`` bool (those the
        pattern already holds are ignored)."""
        vertices = np.asarray(vertices, dtype=bool)
        if vertices.shape != (pattern.num_vertices,):
            raise ValueError(f"held vertices must have shape ({pattern.num_vertices},), got {vertices.shape}")
        variables = pattern.variable_of[vertices & (pattern.variable_of >= 0)]
        rows = (pattern.block_size * variables[:, None] + np.arange(pattern.block_size)).ravel()
        if points is not None and pattern.point_size:
            points = np.asarray(points, dtype=bool)
            if points.shape != pattern.point_variable_of.shape:
                raise ValueError(f"held points must have shape {pattern.point_variable_of.shape}, got {points.shape}")
            free_rank = pattern.point_variable_of[points & (pattern.point_variable_of >= 0)] - pattern.num_pose_variables
            point_rows = pattern.pose_dimension + pattern.point_size * free_rank[:, None] + np.arange(pattern.point_size)
            rows = np.r_[rows, point_rows.ravel()].astype(np.int64)
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
