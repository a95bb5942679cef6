"""The growing graph of an incremental optimiser: vertices, edges and priors in arrays with spare room.

Appending a pose every few milliseconds must not copy the whole graph, so every array keeps spare
capacity (doubled when full: amortised O(1) per row) and the live rows are a view of its head.
Vertex ids map to indices through a dict.

Validation lives here too: a batch is checked whole, against the graph and itself, before any row is
written, so a bad batch raises :class:`posegraph.errors.GraphError` naming the first bad item and leaves
the store as it was.
"""

from __future__ import annotations

import numpy as np

from posegraph.errors import GraphError
from posegraph.model.priors import Priors

__all__ = ["Rows", "EdgeTerms", "GraphStore", "check_information", "check_poses", "indices_in"]


class Rows:
    """A growable array of rows ``(cap,) + tail``: :attr:`view` is the live head ``[:n]``."""

    def __init__(self, tail: tuple = (), dtype=np.float64, capacity: int = 64):
        self.data = np.zeros((capacity,) + tuple(tail), dtype=dtype)
        self.n = 0

    @property
    def view(self) -> np.ndarray:
        return self.data[: self.n]

    def extend(self, values) -> None:
        values = np.asarray(values, dtype=self.data.dtype)
        need = self.n + values.shape[0]
        if need > self.data.shape[0]:
            grown = np.zeros((max(need, 2 * self.data.shape[0]),) + self.data.shape[1:], dtype=self.data.dtype)
            grown[: self.n] = self.data[: self.n]
            self.data = grown
        self.data[self.n : need] = values
        self.n = need

    def keep(self, mask: np.ndarray) -> None:
        """Only the live rows where ``mask`` is True, in order."""
        kept = self.view[mask]
        self.data[: kept.shape[0]] = kept
        self.n = kept.shape[0]


class EdgeTerms:
    """Each edge's cost term (``s = eᵀΩe``, or ``ρ(s)`` with a loss), and their sum kept between changes.

    :meth:`total` re-adds the terms only after they changed: an odometry update appends zeros (its edges'
    residuals vanish by construction) and leaves the sum as it was, so the cost after it costs O(1),
    not O(edges).
    """

    def __init__(self):
        self.rows = Rows(())
        self._sum: float | None = 0.0

    @property
    def view(self) -> np.ndarray:
        return self.rows.view

    def append_zeros(self, count: int) -> None:
        self.rows.extend(np.zeros(count))

    def keep(self, mask: np.ndarray) -> None:
        self.rows.keep(mask)
        self._sum = None

    def set(self, positions, values) -> None:
        """``terms[positions] = values`` (``positions`` a slice or an index array)."""
        self.rows.view[positions] = values
        self._sum = None

    def total(self) -> float:
        if self._sum is None:
            self._sum = float(np.sum(self.rows.view))
        return self._sum


def indices_in(index: dict, ids, what: str, noun: str) -> np.ndarray:
    """``(a,)`` the indices ``index`` maps ``ids`` to (``GraphError`` naming the first unknown one: ``what #k:
    <noun> id … is not in the graph``)."""
    out = np.empty(len(ids), dtype=np.int64)
    for position, identifier in enumerate(ids.tolist()):
        found = index.get(identifier)
        if found is None:
            raise GraphError(f"{what} #{position}: {noun} id {identifier} is not in the graph")
        out[position] = found
    return out


def check_information(information: np.ndarray, what: str, dim: int) -> None:
    """``GraphError`` naming the first item whose information matrix is not finite, symmetric and positive definite."""
    if information.ndim != 3 or information.shape[1:] != (dim, dim):
        raise GraphError(f"{what}: information must have shape (count, {dim}, {dim}), got {information.shape}")
    finite = np.isfinite(information).all(axis=(1, 2))
    scale = np.maximum(np.abs(information).max(axis=(1, 2), initial=0.0), 1e-300)
    symmetric = np.abs(information - np.swapaxes(information, 1, 2)).max(axis=(1, 2), initial=0.0) <= 1e-9 * scale
    good = finite & symmetric
    if good.all():
        try:
            np.linalg.cholesky(information)
            return
        except np.linalg.LinAlgError:
            good = np.array([_positive_definite(w) for w in information])
    bad = int(np.flatnonzero(~good)[0])
    raise GraphError(f"{what} #{bad}: information matrix is not finite, symmetric and positive definite")


def _positive_definite(matrix: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(matrix)
        return True
    except np.linalg.LinAlgError:
        return False


def check_poses(poses: np.ndarray, group, what: str) -> None:
    """``GraphError`` naming the first pose that is not a finite ``(k, k)`` matrix of ``group``."""
    k = group.matrix_size
    if poses.ndim != 3 or poses.shape[1:] != (k, k):
        raise GraphError(f"{what}: poses must have shape (count, {k}, {k}), got {poses.shape}")
    finite = np.isfinite(poses).all(axis=(1, 2))
    bottom = np.zeros(k)
    bottom[-1] = 1.0
    affine = np.abs(poses[:, -1, :] - bottom).max(axis=1, initial=0.0) <= 1e-9
    bad = np.flatnonzero(~(finite & affine))
    if bad.size:
        raise GraphError(f"{what} #{int(bad[0])}: not a finite {group.name} matrix")


class GraphStore:
    """Vertices, edges and priors of the graph so far (indices, not ids, inside)."""

    def __init__(self, group):
        self.group = group
        k, d, r = group.matrix_size, group.dim, group.space_dim
        self.ids = Rows((), np.int64)
        self.poses = Rows((k, k))
        self.fixed = Rows((), bool)
        self.index: dict[int, int] = {}
        self.edge_from, self.edge_to = Rows((), np.int64), Rows((), np.int64)
        self.measurements, self.information = Rows((k, k)), Rows((d, d))
        self.edge_keys = Rows((), np.int64)
        self.next_key = 0
        self.pose_prior = (Rows((), np.int64), Rows((k, k)), Rows((d, d)))
        self.position_prior = (Rows((), np.int64), Rows((r,)), Rows((r, r)))

    @property
    def num_vertices(self) -> int:
        return self.ids.n

    @property
    def num_edges(self) -> int:
        return self.edge_from.n

    @property
    def num_priors(self) -> int:
        return self.pose_prior[0].n + self.position_prior[0].n

    def indices_of(self, ids, what: str) -> np.ndarray:
        """Indices of vertex ids (``GraphError`` naming the first unknown one)."""
        return indices_in(self.index, ids, what, "vertex")

    def add_vertices(self, ids: np.ndarray, poses: np.ndarray, fixed: np.ndarray) -> np.ndarray:
        """Append vertices (checked by the caller); their indices."""
        start = self.ids.n
        self.ids.extend(ids)
        self.poses.extend(poses)
        self.fixed.extend(fixed)
        for offset, vertex in enumerate(ids.tolist()):
            self.index[vertex] = start + offset
        return np.arange(start, self.ids.n)

    def add_edges(self, i: np.ndarray, j: np.ndarray, measurements: np.ndarray, information: np.ndarray) -> np.ndarray:
        """Append edges between vertex indices; their keys (stable handles for :meth:`remove_edges`)."""
        keys = np.arange(self.next_key, self.next_key + len(i), dtype=np.int64)
        self.next_key += len(i)
        self.edge_from.extend(i)
        self.edge_to.extend(j)
        self.measurements.extend(measurements)
        self.information.extend(information)
        self.edge_keys.extend(keys)
        return keys

    def edge_positions(self, keys: np.ndarray) -> np.ndarray:
        """Positions of edge keys (``GraphError`` naming the first unknown one)."""
        live = self.edge_keys.view
        found = np.searchsorted(live, keys)  # keys are increasing along the edges
        found = np.clip(found, 0, max(live.shape[0] - 1, 0))
        ok = (live.shape[0] > 0) & (live[found] == keys) if live.shape[0] else np.zeros(keys.shape, bool)
        if not np.all(ok):
            bad = int(np.flatnonzero(~ok)[0])
            raise GraphError(f"edge to remove #{bad}: no edge with key {int(keys[bad])}")
        if np.unique(found).shape[0] != found.shape[0]:
            raise GraphError("edges to remove: a key is given twice")
        return found

    def edge_errors(self, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(relative (k, n, n), residuals (k, d))`` of the edges at positions ``edges`` ``(k,)`` at the
        current poses (:func:`posegraph.solve.residuals.edge_errors` on views of the store)."""
        from posegraph.model.graph import PoseGraph
        from posegraph.solve.residuals import edge_errors

        sub = PoseGraph(ids=self.ids.view, poses=self.poses.view, edge_from=self.edge_from.view[edges],
                        edge_to=self.edge_to.view[edges], measurements=self.measurements.view[edges],
                        information=self.information.view[edges], fixed=self.fixed.view, group=self.group)
        return edge_errors(self.poses.view, sub)

    def remove_edges(self, positions: np.ndarray) -> None:
        """Drop the edges at ``positions``."""
        keep = np.ones(self.edge_from.n, dtype=bool)
        keep[positions] = False
        for rows in (self.edge_from, self.edge_to, self.measurements, self.information, self.edge_keys):
            rows.keep(keep)

    def add_pose_priors(self, vertices, measurements, information) -> None:
        for rows, values in zip(self.pose_prior, (vertices, measurements, information)):
            rows.extend(values)

    def add_position_priors(self, vertices, positions, information) -> None:
        for rows, values in zip(self.position_prior, (vertices, positions, information)):
            rows.extend(values)

    def priors(self, vertex_mask: np.ndarray | None = None) -> Priors | None:
        """The priors (on the vertices of ``vertex_mask`` only, if given) as :class:`Priors`; None if none."""
        if self.num_priors == 0:
            return None
        (pv, pz, pw), (qv, qz, qw) = ((r.view for r in rows) for rows in (self.pose_prior, self.position_prior))
        if vertex_mask is not None:
            a, b = vertex_mask[pv], vertex_mask[qv]
            if not (a.any() or b.any()):
                return None
            pv, pz, pw, qv, qz, qw = pv[a], pz[a], pw[a], qv[b], qz[b], qw[b]
        offsets = np.broadcast_to(np.eye(self.group.matrix_size), pz.shape).copy()
        return Priors(pv.copy(), pz.copy(), offsets, pw.copy(), qv.copy(), qz.copy(), qw.copy())

    def prior_vertex_mask(self) -> np.ndarray:
        mask = np.zeros(self.num_vertices, dtype=bool)
        mask[self.pose_prior[0].view] = True
        mask[self.position_prior[0].view] = True
        return mask
