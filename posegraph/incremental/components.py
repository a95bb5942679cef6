"""Which vertices an incremental graph holds: FIX vertices and one anchor per component, kept as edges arrive.

The gauge is the batch solver's (:func:`posegraph.model.graph.held_vertices`): a connected component
with no ``FIX`` vertex and no prior is anchored at its vertex with the smallest id. Union-find with,
per root, the component's smallest-id vertex and whether a ``FIX`` vertex or a prior anchors it, so
that joining a vertex or a component costs O(α) and tells which anchor, if any, is released (the
released vertex must then be solved for). Removing edges can split a component: :meth:`Components.rebuild`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Components"]


class Components:
    """Union-find over vertex indices; :attr:`held` the held vertices."""

    def __init__(self):
        self.parent: list[int] = []
        self.smallest: list[int] = []
        self.anchored: list[bool] = []
        self.held: list[bool] = []

    def find(self, v: int) -> int:
        parent = self.parent
        root = v
        while parent[root] != root:
            root = parent[root]
        while parent[v] != root:
            parent[v], v = root, parent[v]
        return root

    def add_vertex(self, v: int, fixed: bool) -> None:
        self.parent.append(v)
        self.smallest.append(v)
        self.anchored.append(bool(fixed))
        self.held.append(True)  # fixed, or the anchor of its own component

    def _anchor(self, root: int) -> int | None:
        return None if self.anchored[root] else self.smallest[root]

    def join(self, a: int, b: int, ids, fixed) -> list[int]:
        """Merge the components of ``a`` and ``b``; the vertices no longer held."""
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return []
        before = {self._anchor(ra), self._anchor(rb)} - {None}
        sa, sb = self.smallest[ra], self.smallest[rb]
        self.parent[rb] = ra
        self.smallest[ra] = sa if ids[sa] <= ids[sb] else sb
        self.anchored[ra] = self.anchored[ra] or self.anchored[rb]
        return self._release(before, ra, fixed)

    def anchor_by_prior(self, v: int, fixed) -> list[int]:
        """A prior on ``v`` anchors its component; the vertices no longer held."""
        root = self.find(v)
        before = {self._anchor(root)} - {None}
        self.anchored[root] = True
        return self._release(before, root, fixed)

    def _release(self, before: set, root: int, fixed) -> list[int]:
        after = self._anchor(root)
        released = [v for v in before if v != after and not fixed[v]]
        for v in released:
            self.held[v] = False
        if after is not None:
            self.held[after] = True
        return released

    def rebuild(self, ids, fixed, edge_from, edge_to, prior_vertices) -> list[int]:
        """Start again from the whole graph (after removals); the vertices no longer held."""
        was = list(self.held)
        self.__init__()
        for v, f in enumerate(np.asarray(fixed).tolist()):
            self.add_vertex(v, f)
        for a, b in zip(np.asarray(edge_from).tolist(), np.asarray(edge_to).tolist()):
            self.join(a, b, ids, fixed)
        for v in np.asarray(prior_vertices).tolist():
            self.anchor_by_prior(v, fixed)
        return [v for v, (old, new) in enumerate(zip(was, self.held)) if old and not new]

    def held_mask(self) -> np.ndarray:
        return np.array(self.held, dtype=bool)
