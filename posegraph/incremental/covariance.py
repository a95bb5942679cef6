"""Marginal and joint covariances of the incremental optimiser's poses, kept from update to update.

Convention of :mod:`posegraph.analysis.covariance`: ``Σ = H⁻¹`` at the current poses, H without robust
loss weights, priors included, held vertices (FIX, anchors) without variables (their covariance zero).
A data-association front end asks the latest pose's covariance and a pair's after every update; what
it pays:

* **Odometry is O(1), exactly.** An update of only *tree edges* (``commit.py``: each new vertex ``c``
  placed from a placed ``p`` by one edge, zero residual; no prior, removal or landmark) adds leaves:
  marginalising a leaf joined by one full-rank edge gives back the old distribution, so every
  covariance among the old poses is unchanged, and with the edge's residual Jacobians ``A_c``, ``A_p``
  at the current poses (:func:`posegraph.solve.residuals.residual_jacobian_factors`; ``δ_c = M δ_p + n``)

      M = −A_c⁻¹ A_p,   N = A_c⁻¹ Ω⁻¹ A_c⁻ᵀ,   Σ_c = M Σ_p Mᵀ + N,   Σ_{c,x} = M Σ_{p,x}  (x older than c).

  So the leaves since the last change are kept as ``child → (parent, edge)`` and a covariance is
  propagated down from the nearest pose whose one is known (cached, held, or a *base* pose: one in the
  graph at the last change).
* **Base poses use the held analysis** (:mod:`posegraph.incremental.whole`): one numeric factorisation
  at the current poses per change (the last solve's linearisation reused when it is of these poses),
  then for unknowns ``E`` (the ``d`` rows of each pose asked) ``Eᵀ H⁻¹ E = G_EE − G_EK M (I + G_KK M)⁻¹ G_KE``,
  ``G = YᵀY``, ``Y = L⁻¹ P [E, E_K]`` on the elimination-tree paths only (:meth:`SparseCholesky.unit_forward`),
  the second term the left-out edges' blocks ``M`` on their columns ``K``
  (:meth:`posegraph.incremental.held_factor.HeldFactor.inverse_block`).
* **Everything is cached** until an update that is not pure odometry (a solve, a removal, a prior, a
  landmark, :meth:`IncrementalOptimizer.optimize`) drops it.
"""

from __future__ import annotations

import numpy as np

from posegraph.solve.residuals import residual_jacobian_factors

__all__ = ["Covariances", "MAX_CHAIN"]

MAX_CHAIN = 1000
"""Longest walk of propagation (leaf to parent) before a pose is solved for on a new factorisation at the
current poses instead (a pose asked after thousands of odometry updates with no covariance asked)."""


class Covariances:
    """The covariance cache of one :class:`~posegraph.incremental.optimizer.IncrementalOptimizer` (module docstring).

    ``store``: its :class:`~posegraph.incremental.store.GraphStore`; ``whole``: its
    :class:`~posegraph.incremental.whole.WholeGraph`; ``held``: a callable giving the held vertices, a
    sequence of bools indexable by vertex (``Components.held``); ``held_mask``: the same as an ``(n,)`` array.
    """

    def __init__(self, store, whole, held, held_mask):
        self.store, self.whole, self.held, self.held_mask = store, whole, held, held_mask
        self.version = 0
        self.factorizations = 0  # made here, in all (for the benchmark and the tests)
        self.clear()

    def clear(self) -> None:
        self.parent: dict[int, tuple[int, int]] = {}  # leaf → (parent, edge position), since the last change
        self.placed: dict[int, int] = {}  # leaf → its rank in placement order (a parent before its children)
        self.links: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # leaf → (M, N)
        self.pending: list[int] = []  # leaves whose (M, N) is not made yet
        self.sigma: dict[int, np.ndarray] = {}  # pose → Σ (d, d)
        self.cross: dict[tuple[int, int], np.ndarray] = {}  # (a, b), a > b → Σ_ab (d, d)
        self.joints: dict[tuple[int, ...], np.ndarray] = {}
        self.factored = None  # (factor, factorisation count, poses covered) of the last factorisation made here

    def advance(self, previous: int, version: int, placed: np.ndarray | None) -> None:
        """The optimiser went from update ``previous`` to ``version``: ``placed`` ``(a, 3)`` the tree edges
        ``(child, parent, edge)`` of a pure odometry update (every covariance so far unchanged), or None
        (anything else: all dropped)."""
        if placed is None or self.version != previous:
            self.clear()
        else:
            for child, parent, edge in placed.tolist():
                self.parent[child] = (parent, edge)
                self.placed[child] = len(self.placed)
                self.pending.append(child)
        self.version = version

    def _sync(self, version: int) -> None:
        if version != self.version:  # the estimate changed outside update() (optimize)
            self.clear()
            self.version = version

    def marginal(self, vertex: int, version: int) -> np.ndarray:
        """``(d, d)`` marginal covariance of the pose at index ``vertex`` (zero if held)."""
        self._sync(version)
        return self._marginal(vertex).copy()

    def joint(self, vertices: list[int], version: int) -> np.ndarray:
        """``(k·d, k·d)`` joint covariance of the poses at indices ``vertices`` ``(k,)``, blocks in that order."""
        self._sync(version)
        key = tuple(vertices)
        if key not in self.joints:
            self.joints[key] = self._joint(list(key))
        return self.joints[key].copy()

    # ------------------------------------------------------------------ propagation along leaves

    def _link(self, child: int) -> tuple[np.ndarray, np.ndarray]:
        """``(M, N)`` of a leaf (module docstring), made with those of every leaf not made yet: the Lie-group
        functions cost ~0.1 ms a call whatever the batch, so a pose asked after many odometry updates
        costs one batched call, not one per leaf."""
        if child not in self.links:
            pending = [c for c in self.pending if c not in self.links]
            self.pending = []
            for c, link in zip(pending, zip(*self._links(pending))):
                self.links[c] = link
        return self.links[child]

    def _links(self, children: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """``(M, N)`` ``(a, d, d)`` of leaves ``children`` from their tree edges' Jacobians at the current poses:
        ``e = Log(Z⁻¹ X_i⁻¹ X_j)``, ``A_j = B = Jr⁻¹(e)``, ``A_i = −B Ad(X_j⁻¹ X_i)``; ``A_c``, ``A_p`` the child's
        and the parent's (the child at either end)."""
        store, group = self.store, self.store.group
        edges = np.array([self.parent[c][1] for c in children], dtype=np.int64)
        j = store.edge_to.view[edges]
        relative, residual = store.edge_errors(edges)
        b, adjoint = residual_jacobian_factors(group, residual, relative)
        a_i = -b @ adjoint
        at_j = (j == np.array(children))[:, None, None]
        a_c, a_p = np.where(at_j, b, a_i), np.where(at_j, a_i, b)
        inverse = np.linalg.inv(a_c)
        noise = inverse @ np.linalg.inv(store.information.view[edges]) @ np.swapaxes(inverse, 1, 2)
        return -inverse @ a_p, 0.5 * (noise + np.swapaxes(noise, 1, 2))

    def _marginal(self, vertex: int) -> np.ndarray:
        """Σ of ``vertex`` (cached): propagated down from the nearest known ancestor, or solved for."""
        d = self.store.group.dim
        held = self.held()
        if held[vertex]:
            return np.zeros((d, d))
        path, u = [], vertex
        while u not in self.sigma and u in self.parent and not held[u] and len(path) < MAX_CHAIN:
            path.append(u)
            u = self.parent[u][0]
        if u in self.sigma or held[u]:
            sigma = self.sigma.get(u, np.zeros((d, d)))
        elif u not in self.parent:
            sigma = self.sigma[u] = self._base([u])
        else:  # a chain too long to walk: this pose solved for on a factorisation covering it
            self.sigma[vertex] = self._base([vertex])
            return self.sigma[vertex]
        for child in reversed(path):
            m, n = self._link(child)
            sigma = m @ sigma @ m.T + n
            self.sigma[child] = sigma = 0.5 * (sigma + sigma.T)
        return sigma

    def _later(self, a: int, b: int) -> tuple[int, int]:
        """``(a, b)`` or ``(b, a)``, the one placed later first: a leaf after every base pose, leaves in
        placement order (not index order: a batch's new poses are placed from each other in any order)."""
        rank = lambda v: (1, self.placed[v]) if v in self.placed else (0, v)  # noqa: E731
        return (a, b) if rank(a) > rank(b) else (b, a)

    def _cross(self, a: int, b: int) -> np.ndarray:
        """``Σ_ab`` ``(d, d)`` for ``a ≠ b`` (cached): the one placed later replaced by its parent while it
        is a leaf (``Σ_{c,x} = M Σ_{p,x}``: ``x`` is no descendant of ``c``), down to a cached, held or base pair."""
        d, held = self.store.group.dim, self.held()
        x, y = first = self._later(a, b)
        steps = []  # (x, y, swapped): Σ_xy = M_x Σ_{p,y}, Σ_{p,y} the next pair's value (transposed if swapped)
        while True:
            if held[x] or held[y]:
                value = np.zeros((d, d))
                break
            if (x, y) in self.cross:
                value = self.cross[(x, y)]
                break
            if x not in self.parent or len(steps) >= MAX_CHAIN:
                value = self.cross[(x, y)] = self._base([x, y])[:d, d:]
                break
            p = self.parent[x][0]
            if p == y:
                steps.append((x, y, False))
                value = self._marginal(y)
                break
            later = self._later(p, y)
            steps.append((x, y, later[0] == y))
            x, y = later
        for x, y, swapped in reversed(steps):
            value = self._link(x)[0] @ (value.T if swapped else value)
            self.cross[(x, y)] = value
        return value if first[0] == a else value.T

    def _joint(self, vertices: list[int]) -> np.ndarray:
        """The joint covariance: one base solve when every free pose asked is a base pose, else block by block."""
        d, k, held = self.store.group.dim, len(vertices), self.held()
        out = np.zeros((k * d, k * d))
        free = [s for s, v in enumerate(vertices) if not held[v]]
        if free and not any(vertices[s] in self.parent for s in free):
            rows = (d * np.array(free)[:, None] + np.arange(d)).ravel()
            out[np.ix_(rows, rows)] = self._base([vertices[s] for s in free])
            return out
        for s, a in enumerate(vertices):
            out[s * d : s * d + d, s * d : s * d + d] = self._marginal(a)
            for t in range(s):
                b = vertices[t]
                block = self._marginal(a) if a == b else self._cross(a, b)
                out[s * d : s * d + d, t * d : t * d + d] = block
                out[t * d : t * d + d, s * d : s * d + d] = block.T
        return out

    # ------------------------------------------------------------------ the held analysis

    def _base(self, vertices: list[int]) -> np.ndarray:
        """``(k·d, k·d)`` block of ``H⁻¹`` of free ``vertices``: ``YᵀY − Z_E C⁻¹ Z_Eᵀ`` (module docstring)
        on a factorisation at the current poses covering them (made here at most once per change, unless
        the analysis was redone or a pose asked came after it)."""
        whole = self.whole
        if whole.current is not None and whole.current[0] == whole.factorizations and self.factored is None:
            self.factored = (whole.factor, whole.factorizations, whole.current[1])  # the solve ended on one
        if self.factored is None or self.factored[:2] != (whole.factor, whole.factorizations) or max(vertices) >= self.factored[2]:
            whole.factorize_unweighted(self.held_mask())
            self.factored = (whole.factor, whole.factorizations, self.store.num_vertices)
            self.factorizations += 1
        d = self.store.group.dim
        columns = (d * whole.pattern.variable_of[np.asarray(vertices)][:, None] + np.arange(d)).ravel()
        return whole.held_factor.inverse_block(columns)
