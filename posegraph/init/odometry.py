"""Odometry (spanning-tree) initialisation: compose measurements outward from the held vertices.

Every component is covered by a spanning tree rooted at its held vertices (its fixed vertices,
or else its anchor; :func:`posegraph.model.graph.held_vertices`). A held vertex keeps its file pose; every other
vertex ``v`` with tree parent ``p`` along edge ``e`` gets

    ``X_v = X_p Z_e``     if ``e`` goes ``p → v``,
    ``X_v = X_p Z_e⁻¹``   if ``e`` goes ``v → p``.

Trees (``tree=``):

* ``"bfs"`` (default): breadth-first from the held vertices, so each vertex is reached in the
  fewest compositions (drift grows with their number); between two vertices joined by several
  edges, the one with the largest rotation weight (``tr(Ω_ωω)/3``) is used.
* ``"max_information"``: a maximum spanning tree on the rotation weights (Kruskal on their rank),
  which prefers confident edges even when that makes the paths longer.

Implementation: one virtual root joined to all held vertices turns the forest into a tree, so a
single ``scipy.sparse.csgraph`` call gives the predecessor of every vertex, for any ids and any
number of components. Poses are then composed by *pointer jumping*: each vertex stores the
transform from an ancestor to itself, and every pass replaces ancestor ``a`` by ``a``'s ancestor
while left-multiplying ``a``'s transform — ``⌈log₂ depth⌉`` batched 4×4 matrix products instead
of a Python loop over vertices or tree levels (3×3 products for SE(2) graphs).
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.init.checks import require_usable
from posegraph.model.graph import held_vertices
from posegraph.init.priors import align_to_priors, without_priors
from posegraph.init.weights import rotation_weights

__all__ = ["odometry_initialization", "spanning_tree", "TREES"]

TREES = ("bfs", "max_information")


def _strongest_edge_per_pair(graph: PoseGraph, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted unordered-pair keys ``min·n + max`` and, per key, the edge of largest weight."""
    n = graph.num_vertices
    low = np.minimum(graph.edge_from, graph.edge_to)
    high = np.maximum(graph.edge_from, graph.edge_to)
    keys = low * np.int64(n) + high
    order = np.lexsort((-weights, keys))  # by key, strongest edge first within a key
    sorted_keys = keys[order]
    first = np.ones(sorted_keys.size, dtype=bool)
    first[1:] = sorted_keys[1:] != sorted_keys[:-1]
    return sorted_keys[first], order[first]


def spanning_tree(graph: PoseGraph, tree: str = "bfs") -> tuple[np.ndarray, np.ndarray]:
    """Tree parent and tree edge of every vertex.

    Returns ``(parent, parent_edge)``, both ``(n,)`` int64: held vertices (the roots) have
    ``parent = parent_edge = -1``; every other vertex ``v`` has its parent's index and the index
    of the edge joining them. Self-loops are ignored. See the module docstring for ``tree``.
    """
    if tree not in TREES:
        raise ValueError(f"tree must be one of {TREES}, got {tree!r}")
    # Imported here, not at the top: csgraph pulls in scipy.sparse.linalg and scipy.linalg (~40 ms),
    # which the default (chordal) start of every `posegraph optimize` does not need.
    import scipy.sparse as sp  # here, not at the top: only odometry starts need it
    from scipy.sparse import csgraph

    require_usable(graph)
    n = graph.num_vertices
    held = held_vertices(graph)
    weights = rotation_weights(graph.information, graph.group)
    pair_keys, pair_edge = _strongest_edge_per_pair(graph, weights)
    low, high = pair_keys // max(n, 1), pair_keys % max(n, 1)
    proper = low != high
    low, high, pair_edge = low[proper], high[proper], pair_edge[proper]

    root = n  # the virtual root, joined to every held vertex
    roots = np.flatnonzero(held)
    if tree == "bfs":
        cost = np.ones(low.size)
        root_cost = np.ones(roots.size)
    else:
        # Kruskal only compares costs, so ranks (exact in floating point, all positive) stand in
        # for 1/weight; the root's edges are cheaper than any real edge, hence all in the tree.
        rank = np.empty(low.size)
        rank[np.argsort(-weights[pair_edge], kind="stable")] = np.arange(1, low.size + 1)
        cost = rank
        root_cost = np.full(roots.size, 0.5)
    rows = np.concatenate([low, np.full(roots.size, root)])
    cols = np.concatenate([high, roots])
    adjacency = sp.csr_matrix((np.concatenate([cost, root_cost]), (rows, cols)), shape=(n + 1, n + 1))
    if tree == "max_information":
        adjacency = csgraph.minimum_spanning_tree(adjacency)
    _, predecessors = csgraph.breadth_first_order(adjacency, root, directed=False, return_predecessors=True)

    parent = np.asarray(predecessors[:n], dtype=np.int64)
    parent[held] = -1
    child = np.flatnonzero(parent >= 0)
    a, b = np.minimum(child, parent[child]), np.maximum(child, parent[child])
    parent_edge = np.full(n, -1, dtype=np.int64)
    parent_edge[child] = pair_edge[np.searchsorted(low * np.int64(n) + high, a * np.int64(n) + b)]
    return parent, parent_edge


def odometry_initialization(graph: PoseGraph, tree: str = "bfs") -> np.ndarray:
    """``(n, k, k)`` poses (the graph's group) composed along a spanning tree from each component's held vertices.

    Held vertices (fixed, or the component's anchor) keep their file pose exactly; a component
    that priors reach is then moved rigidly to fit them (:mod:`posegraph.init.priors`).
    """
    if graph.priors is not None:
        return align_to_priors(graph, odometry_initialization(without_priors(graph), tree))
    n = graph.num_vertices
    parent, parent_edge = spanning_tree(graph, tree)
    # local[v]: transform from parent(v)'s frame to v's; for roots, from the world frame.
    local = np.array(graph.poses, dtype=np.float64, copy=True)
    child = np.flatnonzero(parent >= 0)
    edge = parent_edge[child]
    forward = graph.edge_from[edge] == parent[child]
    measured = graph.measurements[edge]
    local[child] = np.where(forward[:, None, None], measured, graph.group.inverse(measured))

    # Pointer jumping: ancestor[v] = -1 means local[v] is already the world pose.
    ancestor = parent.copy()
    while True:
        pending = np.flatnonzero(ancestor >= 0)
        if pending.size == 0:
            break
        up = ancestor[pending]
        local[pending] = local[up] @ local[pending]
        ancestor[pending] = ancestor[up]
    return local
