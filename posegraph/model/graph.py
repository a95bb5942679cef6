"""The pose-graph model: vertices, edges and fixed vertices stored as arrays.

A :class:`PoseGraph` holds everything as numpy arrays so that the solver and
the initialisers never loop over vertices or edges in Python.

Conventions
-----------
* Vertex ``k`` (``0 <= k < n``) has the user's integer id ``ids[k]``; ids need
  not be ``0..n-1`` nor sorted. Edges refer to vertices by *index* ``k``, not id.
* ``group`` is the Lie group of the poses (:class:`posegraph.lie.group.LieGroup`, SE(3) unless
  given): ``poses[k]`` is its ``(k, k)`` matrix ``X_k`` (world-from-body), ``k = group.matrix_size``
  (4 for SE(3)), and residuals, information matrices and solver blocks have ``d = group.dim`` rows
  (6 for SE(3)).
* Edge ``e`` goes from ``edge_from[e] = i`` to ``edge_to[e] = j`` and measures
  ``Z_ij ≈ X_i⁻¹ X_j``; its residual is ``Log(Z_ij⁻¹ X_i⁻¹ X_j)`` in ``[ω; v]``
  order and ``information[e]`` is the ``(6, 6)`` matrix Ω in that same
  ``[ω; v]`` order (the g2o reader permutes g2o's ``[v; ω]`` on reading).
* ``fixed`` is a boolean mask of the vertices held constant (g2o ``FIX``).
* ``edge_source`` optionally keeps the text of the edge lines a reader parsed
  (:class:`EdgeSource`), so that a writer of the same format copies them
  instead of formatting every number again; it is ignored as soon as the
  edges no longer equal what was read.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from posegraph.lie.group import SE3, LieGroup
from posegraph.model.priors import Priors, anchored_components

if TYPE_CHECKING:  # imported where landmarks are read or solved: a pose graph run does without
    from posegraph.model.landmarks import Landmarks

__all__ = ["PoseGraph", "EdgeSource", "GraphFacts", "vertex_ranks", "neighbour_pairs", "connected_components", "component_anchors", "held_vertices", "graph_facts"]


def edge_checksum(graph: "PoseGraph") -> int:
    """CRC-32 of the bytes of the arrays that define ``graph``'s edges, ids included (each as contiguous float64/int64)."""
    crc = 0
    for array, dtype in (
        (graph.ids, np.int64), (graph.edge_from, np.int64), (graph.edge_to, np.int64),
        (graph.measurements, np.float64), (graph.information, np.float64),
    ):  # fmt: skip
        crc = zlib.crc32(np.ascontiguousarray(array, dtype=dtype).data, crc)
    return crc


@dataclass(frozen=True, eq=False)
class EdgeSource:
    """The edge lines of the file a graph was read from, one per edge in edge order.

    A reader keeps them when they state the edges exactly as the graph holds them (same format,
    nothing repaired); a writer of that ``format`` then copies them rather than formatting
    ~30 numbers per edge again (on parking-garage's 6,275 edges: ~30 ms of a 60 ms write), and
    the output differs from the input only in its vertex lines. :meth:`matches` guards against
    edges changed since: the lines are used only while the ids, edge ends, measurements and
    information still have the checksum they had when read.
    """

    format: str
    """The tag of every line, e.g. ``"EDGE_SE3:QUAT"``."""
    lines: list
    """``m`` strings: the text after the tag of each edge line, as read (no newline)."""
    checksum: int
    """:func:`edge_checksum` of the graph when read."""

    @classmethod
    def of(cls, graph: "PoseGraph", format: str, lines: list) -> "EdgeSource":
        """The lines ``lines`` (in ``format``) as the statement of ``graph``'s edges as they are now."""
        return cls(format, lines, edge_checksum(graph))

    def matches(self, graph: "PoseGraph") -> bool:
        """Whether these lines still state ``graph``'s edges (same count and checksum)."""
        return len(self.lines) == graph.num_edges and self.checksum == edge_checksum(graph)


@dataclass(frozen=True, eq=False)
class PoseGraph:
    """A pose graph stored as arrays (see the module docstring for conventions); 3D unless ``group`` says otherwise."""

    ids: np.ndarray
    """``(n,)`` int64 — the user's vertex ids, in file order."""
    poses: np.ndarray
    """``(n, k, k)`` float64 — vertex poses ``X_k`` (initial values as read); ``k = group.matrix_size``."""
    edge_from: np.ndarray
    """``(m,)`` int64 — index ``i`` (into ``ids``) of each edge's first vertex."""
    edge_to: np.ndarray
    """``(m,)`` int64 — index ``j`` of each edge's second vertex."""
    measurements: np.ndarray
    """``(m, k, k)`` float64 — measured relative poses ``Z_ij``."""
    information: np.ndarray
    """``(m, d, d)`` float64 — information matrices Ω in the group's tangent order (``[ω; v]`` for
    SE(3)), ``d = group.dim``."""
    fixed: np.ndarray = field(default=None)  # type: ignore[assignment]
    """``(n,)`` bool — vertices held constant (g2o ``FIX``); all False if None is given."""
    source: str | None = None
    """Path the graph was read from, if any (used in messages)."""
    edge_source: EdgeSource | None = field(default=None, repr=False)
    """The edge lines as read, for a writer to copy (see :class:`EdgeSource`); None if not kept."""
    group: LieGroup = SE3
    """The Lie group of the poses and measurements (:data:`posegraph.lie.group.SE3` by default). The
    solver takes every size from it: tangent dimension ``group.dim`` (the block size of the normal
    equations) and matrix size ``group.matrix_size``; residuals and Jacobians use its functions."""
    edge_lines: np.ndarray | None = field(default=None, repr=False)
    """``(m,)`` int64 — the 1-based line of the file each edge was read from (for messages); None if unknown."""
    priors: Priors | None = field(default=None, repr=False)
    """Unary edges (pose and position priors, :class:`posegraph.model.priors.Priors`), or None: none."""
    kept_lines: tuple = field(default=(), repr=False)
    """Lines of the file that are not vertices or edges of the graph but belong in its output, each
    ``"TAG rest"``, written back as read: TORO's ``EQUIV`` lines and the vertex and edge lines they
    merged away (:mod:`posegraph.io.g2o_toro`)."""
    file_format: object | None = field(default=None, repr=False)
    """What a reader keeps to write the file back as it came (a Sim(3) file's variant and camera numbers:
    :class:`posegraph.io.g2o_sim3.Sim3Format`); None if nothing."""
    landmarks: Landmarks | None = field(default=None, repr=False)
    """Point variables beside the poses and the measurements of them (:class:`posegraph.model.landmarks.Landmarks`),
    or None: a pose graph."""

    def __post_init__(self) -> None:
        if self.fixed is None:
            object.__setattr__(self, "fixed", np.zeros(len(self.ids), dtype=bool))

    @property
    def num_vertices(self) -> int:
        return int(self.ids.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.edge_from.shape[0])

    def with_poses(self, poses: np.ndarray) -> "PoseGraph":
        """The same graph with other vertex poses ``(n, k, k)``."""
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != self.poses.shape:
            raise ValueError(f"poses must have shape {self.poses.shape}, got {poses.shape}")
        return replace(self, poses=poses)

    def with_points(self, points: np.ndarray | None) -> "PoseGraph":
        """The same graph with its landmarks at ``points`` ``(L, s)`` (None, or a graph without landmarks: itself)."""
        if points is None or self.landmarks is None:
            return self
        return replace(self, landmarks=self.landmarks.with_positions(points))

    def index_of(self, ids) -> np.ndarray:
        """Vertex indices of the given ids (``KeyError`` if one is absent)."""
        ids = np.asarray(ids, dtype=np.int64)
        if self.num_vertices == 0:
            if ids.size:
                raise KeyError(f"vertex ids not in graph: {ids.reshape(-1)[:5].tolist()}")
            return np.zeros(ids.shape, dtype=np.int64)
        order = np.argsort(self.ids, kind="stable")
        pos = np.searchsorted(self.ids, ids, sorter=order)
        pos = np.clip(pos, 0, len(order) - 1)
        found = order[pos]
        if not np.all(self.ids[found] == ids):
            missing = ids[self.ids[found] != ids]
            raise KeyError(f"vertex ids not in graph: {missing[:5].tolist()}")
        return found

    def odometry_mask(self) -> np.ndarray:
        """``(m,)`` bool: True for odometry edges, False for loop closures (and loop-closure candidates).

        An edge joins neighbours in id order when ``|rank(id_i) − rank(id_j)| = 1``, where ``rank``
        is the position in the sorted ids. For ids ``0..n−1`` this is ``|id_i − id_j| = 1``; it also
        holds for sparse ids (keyframes 0, 5, 10…) and for files that list the vertices out of order.
        Each such pair has one odometry edge, the first joining it in edge (file) order; a further
        edge between the same two vertices, whichever way round, is a loop closure like the others:
        a front end can emit a wrong edge parallel to the odometry (a duplicate, a false match), and
        robust optimisation must be free to reject it (:func:`posegraph.robust.optimize_robust`
        trusts the odometry edges).
        """
        pair = neighbour_pairs(self)
        neighbours = np.flatnonzero(pair >= 0)
        _, first = np.unique(pair[neighbours], return_index=True)  # each pair's first edge in edge order
        odometry = np.zeros(self.num_edges, dtype=bool)
        odometry[neighbours[first]] = True
        return odometry


def vertex_ranks(graph: PoseGraph) -> np.ndarray:
    """``(n,)`` int64: each vertex's position in the sorted ids (ties in file order)."""
    rank = np.empty(graph.num_vertices, dtype=np.int64)
    rank[np.argsort(graph.ids, kind="stable")] = np.arange(graph.num_vertices)
    return rank


def neighbour_pairs(graph: PoseGraph) -> np.ndarray:
    """``(m,)`` int64: for an edge whose vertices are neighbours in id order
    (``|rank(id_i) − rank(id_j)| = 1``, :func:`vertex_ranks`), the lower rank of the two, which
    names the pair; −1 for every other edge."""
    rank = vertex_ranks(graph)
    rank_from, rank_to = rank[graph.edge_from], rank[graph.edge_to]
    return np.where(np.abs(rank_from - rank_to) == 1, np.minimum(rank_from, rank_to), -1)


def connected_components(graph: PoseGraph) -> tuple[int, np.ndarray]:
    """Connected components of the undirected vertex/edge graph.

    Returns ``(count, labels)`` with ``labels`` ``(n,)`` int in ``[0, count)``, numbered in the order
    of each component's first vertex (as ``scipy.sparse.csgraph.connected_components`` numbers them).

    Union-find on arrays (no ``scipy.sparse.csgraph``, whose import pulls in ``scipy.sparse.linalg``
    and ``scipy.linalg``, ~40 ms of every ``posegraph optimize``): each vertex points to a parent of
    smaller index; every round hooks, across each edge whose ends have different roots, the larger
    root under the smaller one, then compresses every path to its root by pointer jumping
    (``parent ← parent[parent]``). Trees only ever merge along edges, and every round hooks at least
    one root while some edge joins two trees, so it ends with one tree per component, rooted at its
    smallest vertex index; a handful of rounds on pose graphs (each a few array passes over the edges).

    A landmark joins the poses that observe it (:func:`landmark_components`).
    """
    if graph.landmarks is None:
        return edge_components(graph.num_vertices, graph.edge_from, graph.edge_to)
    count, labels = landmark_components(graph)
    return count, labels[: graph.num_vertices]


def landmark_components(graph: PoseGraph) -> tuple[int, np.ndarray]:
    """Components of the poses and landmarks together: ``(count, labels (n + L,))``, the poses first
    (landmarks are vertices ``n + l``, joined to the poses that observe them). Components holding a
    pose are numbered first (``count`` counts only those); a landmark no pose observes gets a label
    ``≥ count``."""
    from posegraph.model.landmarks import observed_pairs

    n, landmarks = graph.num_vertices, graph.landmarks
    pose, landmark = observed_pairs(landmarks)
    total, labels = edge_components(
        n + landmarks.count, np.concatenate([graph.edge_from, pose]), np.concatenate([graph.edge_to, n + landmark])
    )
    # roots are each component's smallest vertex, so the components with a pose come first
    count = int(labels[:n].max()) + 1 if n else 0
    return count, labels


def edge_components(n: int, edge_from, edge_to) -> tuple[int, np.ndarray]:
    """:func:`connected_components` of ``n`` vertices joined by the edges ``edge_from[k]``–``edge_to[k]``."""
    parent = np.arange(n)
    i = np.asarray(edge_from, dtype=np.int64)
    j = np.asarray(edge_to, dtype=np.int64)
    while True:
        root_i, root_j = parent[i], parent[j]
        split = root_i != root_j
        if not split.any():
            break
        low, high = np.minimum(root_i[split], root_j[split]), np.maximum(root_i[split], root_j[split])
        np.minimum.at(parent, high, low)  # roots are their own parents, so this hooks root `high`
        while True:
            grand = parent[parent]
            if np.array_equal(grand, parent):
                break
            parent = grand
    roots, labels = np.unique(parent, return_inverse=True)
    return int(roots.shape[0]), labels.reshape(n)


def component_anchors(graph: PoseGraph) -> np.ndarray:
    """One gauge anchor per connected component that has no fixed vertex and no prior.

    The anchor of such a component is its vertex with the smallest id (gtsam's
    examples and g2o anchor the first pose; for a file in id order that is the
    same vertex). Components with a ``FIX`` vertex need no anchor: the fixed
    vertices already remove the gauge freedom; nor do components a prior reaches
    (``graph.priors``, see :mod:`posegraph.model.priors`). Returns the vertex indices,
    sorted.
    """
    if graph.num_vertices == 0:
        return np.zeros(0, dtype=np.int64)
    count, labels = connected_components(graph)
    has_fixed = np.zeros(count, dtype=bool)
    has_fixed[labels[graph.fixed]] = True
    has_fixed |= anchored_components(graph.priors, labels, count)
    if graph.landmarks is not None:
        has_fixed |= _landmark_anchored(graph, count)
    # Smallest id per component: sort by (label, id) and take the first of each label.
    order = np.lexsort((graph.ids, labels))
    first = order[np.r_[True, labels[order][1:] != labels[order][:-1]]]
    return np.sort(first[~has_fixed[labels[first]]])


def _landmark_anchored(graph: PoseGraph, count: int) -> np.ndarray:
    """``(count,)`` bool: components holding a ``FIX`` landmark or a landmark with a prior (they tie
    the component to the world, as position priors do: a rotation they leave free is left to LM's damping)."""
    _, labels = landmark_components(graph)
    landmarks = graph.landmarks
    tied = np.array(landmarks.fixed, dtype=bool, copy=True)
    for family in landmarks.observations:
        if family.unary:
            tied[family.landmark] = True
    component = labels[graph.num_vertices :][tied]
    anchored = np.zeros(count, dtype=bool)
    anchored[component[component < count]] = True
    return anchored


def held_vertices(graph: PoseGraph) -> np.ndarray:
    """``(n,)`` bool: the vertices held constant, ``FIX`` vertices and :func:`component_anchors`.

    The solver and the initialisers keep these at their given pose; this removes the gauge freedom
    (one rigid motion per connected component) without adding a prior to the cost.
    """
    held = np.array(graph.fixed, dtype=bool, copy=True)
    held[component_anchors(graph)] = True
    return held


@dataclass(frozen=True)
class GraphFacts:
    """Summary counts of a pose graph (what ``posegraph info`` prints)."""

    num_vertices: int
    num_edges: int
    num_fixed: int
    num_components: int
    degree_min: int
    degree_max: int
    degree_mean: float
    degree_median: float
    num_odometry_edges: int
    num_loop_closures: int


def graph_facts(graph: PoseGraph) -> GraphFacts:
    """Counts, components and degree statistics of ``graph``."""
    degree = np.bincount(graph.edge_from, minlength=graph.num_vertices) + np.bincount(
        graph.edge_to, minlength=graph.num_vertices
    )
    count, _ = connected_components(graph)
    odometry = int(np.count_nonzero(graph.odometry_mask()))
    return GraphFacts(
        num_vertices=graph.num_vertices,
        num_edges=graph.num_edges,
        num_fixed=int(np.count_nonzero(graph.fixed)),
        num_components=count,
        degree_min=int(degree.min()) if degree.size else 0,
        degree_max=int(degree.max()) if degree.size else 0,
        degree_mean=float(degree.mean()) if degree.size else 0.0,
        degree_median=float(np.median(degree)) if degree.size else 0.0,
        num_odometry_edges=odometry,
        num_loop_closures=graph.num_edges - odometry,
    )
