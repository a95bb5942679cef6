"""Forward solves with a few unit right-hand sides on CHOLMOD's supernodal factor, along its elimination tree.

A block of ``A⁻¹`` for a few unknowns ``E`` (``n × c`` unit columns) is ``Eᵀ A⁻¹ E = YᵀY`` with
``Y = L⁻¹ P E`` (``P A Pᵀ = L Lᵀ``). ``Y``'s column for unknown ``j`` is nonzero only on the path of
the elimination tree from ``j``'s column to the root, so the solve needs the supernodes on those paths,
not the whole factor: CHOLMOD's ``cholmod_solve2`` with a sparse right-hand side would do this, but
cvxopt exposes only the dense ``solve`` (every supernode, forward and backward: 24 ms for 3 columns
at 66,000 unknowns, against ~0.4 ms on the path here).

cvxopt hands out no accessor for the factor, so :class:`SupernodalPaths` reads CHOLMOD 3's
``cholmod_factor`` in place (:func:`posegraph.linalg.factor_struct.read_factor`): ``Perm``, ``super``
(first column of each supernode), ``pi``/``s`` (each supernode's row indices, its own columns first),
``px``/``x`` (its values, column-major ``rows × columns``). The read is trusted only when it describes this factor (``n``, supernodal LLᵀ, 64-bit indices, real double,
consistent bounds); otherwise the caller falls back to the dense solve. The dense kernels are those
of the BLAS cvxopt's CHOLMOD itself calls (``dtrsm_``, ``dgemm_``, found through cvxopt's ``blas``
module): single-threaded in the Linux wheel, and no import of scipy. scipy's ``dtrsm`` wrapper takes no
leading dimension, so each diagonal block would be copied out of the supernode first, and its OpenBLAS
runs threads of its own: the latest pose of a 20,000-pose graph took 3.7–10 ms with it against 1.6 ms
here (measured side by side on this machine, under load).

The arrays are views of CHOLMOD's memory: valid until the next numeric factorisation or the factor's
release; :class:`posegraph.linalg.cholmod.SparseCholesky` drops its instance at each of them.
"""

from __future__ import annotations

import ctypes

import numpy as np

from posegraph.linalg.factor_struct import read_factor

__all__ = ["SupernodalPaths", "fortran_blas"]

_LONG, _REAL, _DOUBLE = 2, 1, 0  # CHOLMOD_LONG, CHOLMOD_REAL, CHOLMOD_DOUBLE

_BLAS: list = []


def fortran_blas():
    """``(dtrsm_, dgemm_)`` of the BLAS cvxopt is linked to (ctypes functions, LP64 ints), or None."""
    if not _BLAS:
        try:
            from cvxopt import blas

            library = ctypes.CDLL(blas.__file__)  # dlsym searches its dependencies: cvxopt's OpenBLAS
            _BLAS.append((library.dtrsm_, library.dgemm_))
        except (ImportError, OSError, AttributeError):
            _BLAS.append(None)
    return _BLAS[0]


def _struct(capsule, n: int) -> dict | None:
    """The fields of the numeric supernodal factor in cvxopt's ``capsule`` (addresses and sizes), or None."""
    fields = read_factor(capsule)
    if fields is None:
        return None
    wanted = {"n": n, "is_ll": 1, "is_super": 1, "itype": _LONG, "xtype": _REAL, "dtype": _DOUBLE}
    if any(fields[key] != value for key, value in wanted.items()):
        return None
    if not 0 < fields["nsuper"] <= n or not all(fields[key] for key in ("Perm", "super", "pi", "px", "s", "x")):
        return None
    return fields


def _array(address: int, count: int, kind) -> np.ndarray:
    return np.ctypeslib.as_array((kind * count).from_address(address))


class SupernodalPaths:
    """A read-only view of a numeric supernodal ``L`` (module docstring) and forward solves on its paths.

    Build with :meth:`read`; ``n`` unknowns, ``perm`` ``(n,)`` (``A[perm][:, perm] = L Lᵀ``).
    """

    def __init__(self, fields: dict, blas):
        n, count = int(fields["n"]), int(fields["nsuper"])
        self.n, self.blas = n, blas
        self.perm = _array(fields["Perm"], n, ctypes.c_int64)
        self.super = _array(fields["super"], count + 1, ctypes.c_int64)
        self.pi = _array(fields["pi"], count + 1, ctypes.c_int64)
        self.px = _array(fields["px"], count + 1, ctypes.c_int64)
        self.s = _array(fields["s"], int(fields["ssize"]), ctypes.c_int64)
        self.x_address = int(fields["x"])
        widths = np.diff(self.super)
        self.node_of = np.repeat(np.arange(count), widths)  # supernode of each (permuted) column
        heights = np.diff(self.pi)
        below = heights > widths
        self.parent = np.full(count, -1, dtype=np.int64)  # the supernode of the first row below the diagonal block
        self.parent[below] = self.node_of[self.s[self.pi[:-1][below] + widths[below]]]
        self.inverse = np.empty(n, dtype=np.int64)
        self.inverse[self.perm] = np.arange(n)
        self._where = np.full(n, -1, dtype=np.int64)

    @classmethod
    def read(cls, capsule, n: int) -> SupernodalPaths | None:
        """The view of cvxopt's factor ``capsule`` of ``n`` unknowns, or None when it cannot be trusted
        (another layout, not numeric supernodal LLᵀ, inconsistent bounds, no BLAS found)."""
        fields, blas = _struct(capsule, n), fortran_blas()
        if fields is None or blas is None:
            return None
        paths = cls(fields, blas)
        sizes_ok = paths.super[0] == 0 and paths.super[-1] == n and paths.pi[-1] == fields["ssize"]
        if not (sizes_ok and paths.px[-1] <= fields["xsize"] and np.all(np.diff(paths.super) > 0)):
            return None
        if not (paths.perm.min() >= 0 and paths.perm.max() < n and np.all(np.bincount(paths.perm, minlength=n) == 1)):
            return None  # not a permutation
        if np.any(paths.parent[paths.parent >= 0] <= np.flatnonzero(paths.parent >= 0)):
            return None  # not postordered: the forward solve visits supernodes in index order
        return paths

    @property
    def flops(self) -> float:
        """Floating-point operations of the numeric factorisation of this pattern: per supernode of
        ``w`` columns and ``h`` rows, ``w³/3`` (its diagonal block) ``+ (h−w)w²`` (the rows below)
        ``+ (h−w)²w`` (its update of the ancestors), i.e. ``w h² − (2/3) w³``."""
        w, h = np.diff(self.super).astype(float), np.diff(self.pi).astype(float)
        return float(np.sum(w * h * h - 2.0 / 3.0 * w**3))

    def _nodes(self, starts: np.ndarray) -> np.ndarray:
        """Sorted supernodes on the paths from ``starts`` to the roots (a parent's index exceeds its child's)."""
        seen: set[int] = set()
        for node in np.unique(starts).tolist():
            while node >= 0 and node not in seen:
                seen.add(node)
                node = int(self.parent[node])
        return np.array(sorted(seen), dtype=np.int64)

    def forward(self, columns) -> np.ndarray:
        """``Y`` ``(r, c)``: the nonzero rows of ``L⁻¹ P E`` for the unit columns ``E`` at unknowns ``columns``
        ``(c,)`` (rows of the elimination-tree paths, in elimination order), so that ``Eᵀ A⁻¹ E = YᵀY``."""
        return self.forward_rows(columns)[1]

    def forward_rows(self, columns) -> tuple[np.ndarray, np.ndarray]:
        """``(rows (r,), Y (r, c))``: :meth:`forward` with the row of ``L⁻¹ P E`` each row of ``Y`` is
        (ascending positions in the elimination order, i.e. of the permuted system ``P A Pᵀ``)."""
        starts = self.inverse[np.asarray(columns, dtype=np.int64)]
        nodes = self._nodes(self.node_of[starts])
        first, widths = self.super[nodes], np.diff(self.super)[nodes]
        offsets = np.concatenate(([0], np.cumsum(widths)))
        rows = np.repeat(first - offsets[:-1], widths) + np.arange(offsets[-1])
        where, c, size = self._where, starts.shape[0], int(offsets[-1])
        where[rows] = np.arange(size)
        y = np.zeros((size, c), order="F")
        y[where[starts], np.arange(c)] = 1.0
        try:
            for node, offset, width in zip(nodes.tolist(), offsets[:-1].tolist(), widths.tolist()):
                self._eliminate(node, offset, width, y, where)
        finally:
            where[rows] = -1
        return rows, y

    def _eliminate(self, node: int, offset: int, width: int, y: np.ndarray, where: np.ndarray) -> None:
        """One supernode of the forward solve: ``y_k ← L_kk⁻¹ y_k``, then ``y_below −= L_below y_k``
        (``L_k`` column-major ``height × width`` at ``x + px[k]``, leading dimension ``height``)."""
        trsm, gemm = self.blas
        height, size, c = int(self.pi[node + 1] - self.pi[node]), y.shape[0], y.shape[1]
        block = self.x_address + 8 * int(self.px[node])
        target = y.ctypes.data + 8 * offset
        byref, one, zero = ctypes.byref, ctypes.c_double(1.0), ctypes.c_double(0.0)
        ints = [ctypes.c_int(v) for v in (width, c, height, size)]
        trsm(b"L", b"L", b"N", b"N", byref(ints[0]), byref(ints[1]), byref(one), ctypes.c_void_p(block),
             byref(ints[2]), ctypes.c_void_p(target), byref(ints[3]), 1, 1, 1, 1)
        rest = height - width
        if rest:
            product = np.empty((rest, c), order="F")
            m = ctypes.c_int(rest)
            gemm(b"N", b"N", byref(m), byref(ints[1]), byref(ints[0]), byref(one), ctypes.c_void_p(block + 8 * width),
                 byref(ints[2]), ctypes.c_void_p(target), byref(ints[3]), byref(zero), product.ctypes.data_as(ctypes.c_void_p),
                 byref(m), 1, 1)
            below = self.s[self.pi[node] + width : self.pi[node + 1]]
            y[where[below]] -= product
