"""Putting a checked batch into the graph: new vertices placed by composition, and what the batch touched.

A new vertex reached through a new edge from a vertex already placed is put where the edge says,
breadth first (``X_j = X_i Z`` along the edge, ``X_i = X_j Z⁻¹`` against it); such a *tree* edge has a
zero residual. New vertices no edge reaches from the graph keep their given pose for the first (in id
order) of each new group, the others being placed from it. *Touched* vertices — those Gauss-Newton
must start from — are the ends of every non-tree edge, of every removed edge, the vertices given
priors, and anchors a join or a prior released.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["commit_batch"]


def _place(store, new: np.ndarray, i: np.ndarray, j: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, list]:
    """Poses of the new vertices by composition along the new edges; ``(b,)`` bool: the tree edges, and
    ``[(child, parent, edge)]`` in placement order (``edge`` the batch's index of the tree edge)."""
    poses, group, ids = store.poses.view, store.group, store.ids.view
    incident: dict[int, list[int]] = {int(v): [] for v in new.tolist()}
    for e, (a, b) in enumerate(zip(i.tolist(), j.tolist())):
        if a in incident:
            incident[a].append(e)
        if b in incident:
            incident[b].append(e)
    placed = set(incident) - {v for v in incident if not store.fixed.view[v]}  # FIX vertices keep their pose
    tree = np.zeros(i.shape[0], dtype=bool)
    order = []
    queue = deque(sorted({a for a, b in zip(i.tolist(), j.tolist()) if a not in incident or a in placed}
                         | {b for a, b in zip(i.tolist(), j.tolist()) if b not in incident or b in placed}))
    remaining = sorted(incident, key=lambda v: ids[v])
    while True:
        while queue:
            u = queue.popleft()
            for e in _edges_of(u, i, j, incident, store):
                a, b = int(i[e]), int(j[e])
                w = b if a == u else a
                if w in placed or w not in incident:
                    continue
                poses[w] = poses[u] @ z[e] if a == u else poses[u] @ group.inverse(z[e])
                placed.add(w)
                tree[e] = True
                order.append((w, u, e))
                queue.append(w)
        remaining = [v for v in remaining if v not in placed]
        if not remaining:
            return tree, order
        placed.add(remaining[0])  # the first of a new group keeps its given pose
        queue.append(remaining[0])


def _edges_of(u: int, i, j, incident: dict, store) -> list[int]:
    """The batch's edges at ``u`` (new vertices know theirs; old ones are searched once)."""
    if u in incident:
        return incident[u]
    return np.flatnonzero((i == u) | (j == u)).tolist()


def commit_batch(opt, batch) -> tuple[list[int], bool, np.ndarray]:
    """Add ``batch`` (a checked :class:`~posegraph.incremental.optimizer._Batch`) to ``opt``.

    Returns ``(touched, landmark_work, placed)``: the touched vertices, whether a landmark measurement
    needs a solve (:func:`posegraph.incremental.landmark_commit.commit_landmarks`), and ``placed``
    ``(a, 3)`` int64: ``(child, parent, edge position)`` of each tree edge (vertex indices, store edge
    position), in placement order (a parent before its children).
    """
    from posegraph.incremental.landmark_commit import commit_landmarks, rejoin_through_landmarks

    store, components = opt._store, opt._components
    touched: list[int] = []
    placed = np.zeros((0, 3), dtype=np.int64)
    if batch.ids:
        ids, poses, fixed = (np.concatenate(x) for x in (batch.ids, batch.poses, batch.fixed))
        new = store.add_vertices(ids, poses, fixed)
        for v, f in zip(new.tolist(), fixed.tolist()):
            components.add_vertex(v, f)
    else:
        new = np.zeros(0, dtype=np.int64)
    if batch.removals:
        positions = store.edge_positions(np.concatenate(batch.removals))
        touched += store.edge_from.view[positions].tolist() + store.edge_to.view[positions].tolist()
        store.remove_edges(positions)
        keep = np.ones(opt._terms.view.shape[0], dtype=bool)
        keep[positions] = False
        opt._terms.keep(keep)
        opt._whole.reset()  # the scatter positions follow the edge order
    if batch.edges:
        more, placed = _add_edges(opt, batch, new)
        touched += more
    for kind, add in (("pose_priors", store.add_pose_priors), ("position_priors", store.add_position_priors)):
        for ids, values, information in getattr(batch, kind):
            vertices = store.indices_of(ids, "prior")
            add(vertices, values, information)
            touched += vertices.tolist()
            for v in vertices.tolist():
                touched += components.anchor_by_prior(v, store.fixed.view)
    if batch.landmark_removals:  # before the batch's new measurements go in
        opt._whole.reset()  # the scatter positions follow the measurements' order
        touched += opt._landmarks.remove(np.concatenate(batch.landmark_removals)).tolist()
    released, landmark_work = commit_landmarks(opt, batch) if batch.landmarks or batch.landmark_measurements else ([], False)
    touched += released
    landmark_work = landmark_work or bool(batch.landmark_removals)
    if batch.removals or batch.landmark_removals:
        touched += components.rebuild(store.ids.view, store.fixed.view, store.edge_from.view, store.edge_to.view,
                                      np.flatnonzero(store.prior_vertex_mask()))
        touched += rejoin_through_landmarks(opt)
    return list(dict.fromkeys(touched)), landmark_work, placed


def _add_edges(opt, batch, new: np.ndarray) -> tuple[list[int], np.ndarray]:
    store, components = opt._store, opt._components
    i = store.indices_of(np.concatenate([e[0] for e in batch.edges]), "edge")
    j = store.indices_of(np.concatenate([e[1] for e in batch.edges]), "edge")
    z = np.concatenate([e[2] for e in batch.edges])
    w = np.concatenate([e[3] for e in batch.edges])
    tree, order = _place(store, new, i, j, z) if new.size else (np.zeros(i.shape[0], dtype=bool), [])
    placed = np.array(order, dtype=np.int64).reshape(-1, 3) + [0, 0, store.num_edges]
    store.add_edges(i, j, z, w)
    opt._terms.append_zeros(i.shape[0])  # a tree edge's residual vanishes
    if not tree.all():  # the others' terms now (a solve refreshes them, but none runs between two held vertices)
        opt._refresh_terms(store.num_edges - i.shape[0] + np.flatnonzero(~tree))
    touched = np.concatenate([i[~tree], j[~tree]]).tolist()
    ids, fixed = store.ids.view, store.fixed.view
    released = []
    for a, b in zip(i.tolist(), j.tolist()):
        released += components.join(a, b, ids, fixed)
    # a new vertex released from being its own anchor was placed by composition (a tree edge): it needs no
    # solve; were it joined by a non-tree edge only, that edge's ends are touched already
    first_new = int(new[0]) if new.size else store.num_vertices
    return touched + [v for v in released if v < first_new], placed
