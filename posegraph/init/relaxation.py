"""A landmark graph's start: one linear least-squares relaxation over its poses and points together.

The pose-only chordal start (:mod:`posegraph.init.chordal`) sees the pose edges alone; in a landmark
graph the loops are closed by the landmarks (Victoria Park's poses form a bare odometry chain), so it
starts LM from dead reckoning. Relaxing each rotation ``R_i`` to a free linear combination of a basis
(SE(2): ``R = c I + s J``, 2 unknowns; SE(3): the 9 entries), every pose edge and every landmark
measurement but a bearing becomes *linear* in the unknowns ``(R_i, t_i)`` of the poses and ``p_l`` of
the points::

    pose edge i→j, Z = (R_Z, t_Z):   R_j − R_i R_Z = 0   (weight κ = tr Ω_ωω / dim ω, each entry)
                                     t_j − t_i − R_i t_Z = 0   (weight τ = tr Ω_vv / r)
    "position" (offset O):           p_l − t_i − R_i v = 0,  v = R_O z + t_O   (weight tr Ω / r)
    "bearing_range":                 the same with v = z_r [cos z_θ, sin z_θ]  (weight tr Ω' / 2,
                                     Ω' the information of v to first order)
    "prior" (on a point):            p_l − z = 0

— the chordal relaxation (Martinez-Cantin and Castellanos; Carlone et al., ICRA 2015) with the
landmarks in it. One sparse least-squares solve gives all unknowns; each ``R_i`` is projected to the
nearest rotation; the same system is solved again (:data:`UNIT_PASSES` times, more until 99 % of
the rotations turn by no more than :data:`SETTLED_DEGREES`) with one more equation per pose,
``⟨ū_i, u_i⟩ = ‖ū_i‖²`` at the last projection ``ū_i``, which keeps the relaxed rotations from
shrinking (:func:`_relaxed_rotations`); a last solve, rotations held, gives the translations and points, one scalar system for the ``r``
coordinates (:func:`_translations`). All stages hold the held poses (:func:`relaxation_anchors`)
and the ``FIX`` landmarks known, their terms moved to the right-hand side; the normal equations are
laid out on their block pattern once per stage (:mod:`posegraph.init.block_normal`). Bearings, being bilinear, enter only through the landmarks' own start
(:func:`posegraph.init.landmarks.initialize_landmarks`) and the solver.

Measured (``docs/landmarks.md``, ``docs/initialisation.md``): Victoria Park from this start converges
in 6 LM iterations to χ² 390, from the pose-only chordal start in 98 to χ² 7,706 (g2o, from the file's
poses: 87,156); DLR in 5 (8 after two unit passes, 18 from the relaxation without them).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.init.block_normal import BlockNormalEquations, Factors
from posegraph.init.landmarks import range_point_information
from posegraph.model.graph import PoseGraph, connected_components, held_vertices

__all__ = ["relaxed_start", "relaxation_anchors", "rotation_basis", "relaxation_entries", "MAX_ENTRIES", "UNIT_PASSES", "MAX_UNIT_PASSES", "SETTLED_DEGREES"]

MAX_ENTRIES = 30_000_000
"""Largest number of normal-equation block entries (before duplicates are summed) the relaxation
assembles, ~1 GB at the peak (≈ 34 bytes an entry: world-1000's 2.05 M entries peak at 69 MB);
larger graphs (a 3D landmark graph of ~70,000 pose edges: 12×12 blocks) start from their pose edges
alone (:func:`posegraph.init.initialize`)."""

UNIT_PASSES = 2
"""Solves of the rotation stage with the unit equations (:func:`_relaxed_rotations`) after the plain
one, at least; each refactorises the same pattern (DLR: 18 LM iterations from the plain relaxation,
8 after two passes)."""

MAX_UNIT_PASSES = 6
"""At most this many unit passes: after :data:`UNIT_PASSES`, one more while the last turned the
rotations by more than :data:`SETTLED_DEGREES` (:func:`_turn`)."""

SETTLED_DEGREES = 3.0
"""The unit passes are a fixed-point iteration; a pass that turns 99 % of the rotations by no more
than this leaves the start settled (the percentile, not the largest turn, so that one loosely held
pose cannot keep the passes going). Measured (``docs/initialisation.md``): the second pass turns
0.09–1.04° on Victoria Park and the g2o worlds (they stop there), 17.7° on DLR, whose third and
fourth passes turn 4.5° and 2.4° and take LM from 8 iterations to 5 (a pass costs a factorisation
of the relaxed system, well under an LM iteration)."""


def relaxation_entries(graph: PoseGraph) -> int:
    """The block entries :func:`relaxed_start`'s first solve assembles: ``(q + q)²`` per pose edge,
    ``(q + r)²`` per landmark measurement (``q = K + r`` the pose block)."""
    r = graph.group.space_dim
    q = len(rotation_basis(r)) + r
    return (2 * q) ** 2 * graph.num_edges + (q + r) ** 2 * graph.landmarks.num_measurements


def rotation_basis(r: int) -> np.ndarray:
    """``(K, r, r)`` matrices ``B_k`` with ``R = Σ u_k B_k``: ``I, J`` in 2D (``J`` the quarter turn), the
    9 unit matrices in 3D (row-major)."""
    if r == 2:
        return np.array([[[1.0, 0.0], [0.0, 1.0]], [[0.0, -1.0], [1.0, 0.0]]])
    return np.eye(9).reshape(9, 3, 3)


def rotation_coordinates(rotations: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``(n, K)`` coordinates ``u`` of rotations ``(n, r, r)`` in ``basis`` (least squares; exact for rotations)."""
    flat = basis.reshape(len(basis), -1)
    return np.linalg.lstsq(flat.T, rotations.reshape(len(rotations), -1).T, rcond=None)[0].T


def relaxation_anchors(graph: PoseGraph) -> np.ndarray:
    """``(n,)`` bool: the held vertices, and in each component that holds none (priors or ``FIX``
    landmarks tie it to the world) its smallest-id pose, so that the relaxation has a frame."""
    held = held_vertices(graph)
    count, labels = connected_components(graph)
    has = np.zeros(count, dtype=bool)
    has[labels[held]] = True
    order = np.lexsort((graph.ids, labels))
    first = order[np.r_[True, labels[order][1:] != labels[order][:-1]]] if graph.num_vertices else order
    held[first[~has[labels[first]]]] = True
    return held


def _edge_factors(graph: PoseGraph, basis: np.ndarray, rotations) -> Factors:
    """The pose edges' equations; pass 1 (``rotations`` None) over ``(u, t)``, pass 2 over ``t`` alone."""
    from posegraph.init.weights import rotation_weights, translation_information

    r, K, m = basis.shape[1], len(basis), graph.num_edges
    i, j = graph.edge_from, graph.edge_to
    R_Z, t_Z = graph.measurements[:, :r, :r], graph.measurements[:, :r, r]
    tau = np.trace(translation_information(graph.information, graph.group), axis1=1, axis2=2) / r
    eye = np.broadcast_to(np.eye(r), (m, r, r))
    if rotations is not None:  # t_j − t_i = R_i t_Z
        y = np.einsum("mab,mb->ma", rotations[i], t_Z)
        return Factors(i, j, -eye, eye, y, np.repeat(tau[:, None], r, axis=1))
    q = K + r
    A_i, A_j = np.zeros((m, r * r + r, q)), np.zeros((m, r * r + r, q))
    A_j[:, : r * r, :K] = basis.reshape(K, -1).T  # vec(R_j)
    A_i[:, : r * r, :K] = -np.einsum("kab,mbc->mack", basis, R_Z).reshape(m, r * r, K)  # −vec(R_i R_Z)
    A_i[:, r * r :, :K] = -np.einsum("kab,mb->mak", basis, t_Z)  # −R_i t_Z
    A_i[:, r * r :, K:], A_j[:, r * r :, K:] = -eye, eye
    kappa = rotation_weights(graph.information, graph.group)
    w = np.concatenate([np.repeat(kappa[:, None], r * r, axis=1), np.repeat(tau[:, None], r, axis=1)], axis=1)
    return Factors(i, j, A_i, A_j, np.zeros((m, r * r + r)), w)


def _sighting_vectors(family, r: int):
    """``(v (q, r), weight (q,))``: where each position or bearing-range measurement puts its point
    in the body frame, and the isotropic weight of that point; None for other kinds."""
    z, omega = np.asarray(family.measurements, np.float64), np.asarray(family.information, np.float64)
    if family.kind == "position":
        v, weight = z, np.trace(omega, axis1=1, axis2=2) / r
        if family.offsets is not None:
            v = np.einsum("qab,qb->qa", family.offsets[:, :r, :r], v) + family.offsets[:, :r, r]
        return v, weight
    if family.kind == "bearing_range":
        v = z[:, 1:2] * np.stack([np.cos(z[:, 0]), np.sin(z[:, 0])], axis=1)
        return v, np.trace(range_point_information(z, omega), axis1=1, axis2=2) / r
    return None


def _landmark_factors(graph: PoseGraph, basis: np.ndarray, rotations, n: int) -> list:
    """The landmark measurements' equations (blocks: poses ``0..n−1``, landmark ``l`` is ``n + l``)."""
    r, K = basis.shape[1], len(basis)
    out = []
    for family in graph.landmarks.observations:  # ≤ 4 families
        q, eye = family.count, np.broadcast_to(np.eye(r), (family.count, r, r))
        if family.kind == "prior":
            y, w = np.asarray(family.measurements, np.float64), np.trace(family.information, axis1=1, axis2=2) / r
            out.append(Factors(n + family.landmark, -np.ones(q, np.int64), eye, np.zeros((q, r, 0)), y, np.repeat(w[:, None], r, 1)))
            continue
        sighted = _sighting_vectors(family, r)
        if sighted is None:
            continue
        v, w = sighted
        i, w = family.pose, np.repeat(w[:, None], r, axis=1)
        if rotations is not None:  # p − t_i = R_i v
            out.append(Factors(i, n + family.landmark, -eye, eye, np.einsum("qab,qb->qa", rotations[i], v), w))
            continue
        A_i = np.concatenate([-np.einsum("kab,qb->qak", basis, v), -eye], axis=2)  # −R_i v − t_i
        out.append(Factors(i, n + family.landmark, A_i, eye, np.zeros((q, r)), w))
    return out


def _reached(graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
    """``(poses (n,), landmarks (L,))`` bool: those some linear term of the relaxation reaches (the
    others, e.g. seen only by bearings, are held where they are: they would make it singular)."""
    poses = np.zeros(graph.num_vertices, dtype=bool)
    poses[graph.edge_from] = poses[graph.edge_to] = True
    points = np.zeros(graph.landmarks.count, dtype=bool)
    for family in graph.landmarks.observations:
        if family.kind in ("position", "bearing_range", "prior"):
            points[family.landmark] = True
            if not family.unary:
                poses[family.pose] = True
    return poses, points


def _blocks(x: np.ndarray, offsets: np.ndarray, blocks: np.ndarray, size: int, known: np.ndarray, values: np.ndarray):
    """``(len(blocks), size)``: each block's solved values, or its known ones."""
    at = offsets[blocks][:, None] + np.arange(size)
    solved = x[np.where(known[blocks][:, None], 0, at)] if x.size else np.zeros(at.shape)
    return np.where(known[blocks][:, None], values[blocks, :size], solved)


def _unit_factors(rotations: np.ndarray, basis: np.ndarray, weights: np.ndarray) -> Factors:
    """One equation per pose, ``⟨ū_i, u_i⟩ = ‖ū_i‖²`` (``ū_i`` the coordinates of ``rotations[i]``):
    the relaxed rotation keeps its size along the last estimate and turns freely across it (weight
    ``weights (n,)``)."""
    n, K, r = len(rotations), len(basis), basis.shape[1]
    u_bar = rotation_coordinates(rotations, basis)
    A = np.zeros((n, 1, K + r))
    A[:, 0, :K] = u_bar
    y = np.einsum("nk,nk->n", u_bar, u_bar)[:, None]
    return Factors(np.arange(n), -np.ones(n, np.int64), A, np.zeros((n, 1, 0)), y, weights[:, None])


def _relaxed_rotations(graph: PoseGraph, basis: np.ndarray, known: np.ndarray, values: np.ndarray, passes: int, max_passes: int) -> np.ndarray:
    """``(n, r, r)`` rotations of the first stage: the relaxation solved, projected, then solved again
    with :func:`_unit_factors` at the last projection, projected each time: ``passes`` times, then
    while the last pass turned the rotations by more than :data:`SETTLED_DEGREES` (:func:`_turn`),
    ``max_passes`` at most (one pattern, analysed once; the unit terms add to the poses' diagonal blocks).

    The relaxed rotations alone shrink: every term is homogeneous in the poses' rotations,
    translations and the points (the map at a smaller scale fits them all better) but for the held
    anchor, so far from it ``‖u_i‖`` decays (DLR: median 0.08) and the projection keeps a noisy
    direction (median heading error 23°). The unit equations, weighted as each pose's own diagonal
    of the normal equations, stop the decay (DLR: ‖u‖ → 1.00, start χ² 474,828 → 59,108 against
    the optimum's 56,858)."""
    n, r, K = graph.num_vertices, basis.shape[1], len(basis)
    sizes = np.concatenate([np.full(n, K + r), np.full(graph.landmarks.count, r)])
    factors = [_edge_factors(graph, basis, None)] + _landmark_factors(graph, basis, None, n)
    system = BlockNormalEquations(sizes, known, [(f.a, f.b) for f in factors])
    data, g = system.matrix(factors), system.right_hand_side(factors, values)
    weights = np.zeros(n)
    if max_passes:
        at = system.offsets[:n, None] + np.arange(K)
        weights = np.where(known[:n], 0.0, system.diagonal(data)[np.where(known[:n, None], 0, at)].mean(axis=1))
    x, rotations = system.solve(data, g), None
    for solved in range(max_passes + 1):
        u = _blocks(x, system.offsets, np.arange(n), K, known, values)
        projected = graph.group.rotations.project(np.einsum("nk,kab->nab", u, basis))
        projected[known[:n]] = graph.poses[known[:n], :r, :r]
        settled = rotations is not None and _turn(rotations, projected, graph.group) <= SETTLED_DEGREES
        rotations = projected
        if solved == max_passes or (solved >= passes and settled):
            return rotations
        unit = [_unit_factors(rotations, basis, weights)]
        x = system.solve(data + system.matrix(unit), g + system.right_hand_side(unit, values))


def _turn(before: np.ndarray, after: np.ndarray, group) -> float:
    """The 99th percentile, in degrees, of the angles between rotations ``before`` and ``after``
    ``(n, r, r)`` (0 if none): how far a unit pass turned the map, one loosely held pose aside."""
    if not len(after):
        return 0.0
    angles = np.linalg.norm(group.rotations.log(np.swapaxes(before, 1, 2) @ after).reshape(len(after), -1), axis=1)
    return float(np.degrees(np.percentile(angles, 99)))


def _translations(graph: PoseGraph, basis: np.ndarray, rotations: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``(n + L, r)``: the poses' translations and the points' positions of the last stage, rotations
    held. Its factors (``t_j − t_i = R_i t_Z``, ``p − t_i = R_i v``, ``p = z``) are ``±I`` with an
    isotropic weight, so the ``r`` coordinates do not interact: one scalar system over the ``n + L``
    blocks with ``r`` right-hand sides, ``r²`` times fewer entries than the coordinates together."""
    n, r = graph.num_vertices, basis.shape[1]
    factors = [_edge_factors(graph, basis, rotations)] + _landmark_factors(graph, basis, rotations, n)
    scalar = [replace(f, A_a=f.A_a[:, :1, :1], A_b=f.A_b[:, :1, :1], w=f.w[:, :1]) for f in factors]
    system = BlockNormalEquations(np.ones(len(known), np.int64), known, [(f.a, f.b) for f in scalar])
    values = np.concatenate([graph.poses[:, :r, r], graph.landmarks.positions])
    g = np.stack([system.right_hand_side([replace(f, y=f.y[:, axis, None]) for f in scalar], values[:, axis, None])
                  for axis in range(r)], axis=1)  # fmt: skip
    x = system.solve(system.matrix(scalar), g)
    return _blocks(x.reshape(-1), system.offsets * r, np.arange(len(known)), r, known, values)  # (offset·r: x row-major)


def relaxed_start(graph: PoseGraph, *, unit_passes: int | None = None) -> np.ndarray:
    """Poses ``(n, k, k)`` of a landmark graph from the relaxation (module docstring); held ones as given.

    ``unit_passes``: how many times the rotation stage is solved again with the unit equations
    (:func:`_relaxed_rotations`; 0: the plain relaxation); None: :data:`UNIT_PASSES`, then more until
    settled (:data:`SETTLED_DEGREES`), :data:`MAX_UNIT_PASSES` at most.

    Raises :class:`~posegraph.linalg.cholmod.NotPositiveDefiniteError` when the relaxed system is
    singular (a pose or point its terms do not fix), for the caller to start otherwise.
    """
    group, n, L = graph.group, graph.num_vertices, graph.landmarks.count
    r = group.space_dim
    basis, poses = rotation_basis(r), np.array(graph.poses, dtype=np.float64, copy=True)
    K = len(basis)
    reached_poses, reached_points = _reached(graph)
    known = np.concatenate([relaxation_anchors(graph) | ~reached_poses, np.asarray(graph.landmarks.fixed, bool) | ~reached_points])
    values = np.zeros((n + L, K + r))
    values[:n, :K], values[:n, K:] = rotation_coordinates(poses[:, :r, :r], basis), poses[:, :r, r]
    values[n:, :r] = graph.landmarks.positions
    passes = (UNIT_PASSES, MAX_UNIT_PASSES) if unit_passes is None else (unit_passes, unit_passes)
    rotations = _relaxed_rotations(replace(graph, poses=poses), basis, known, values, *passes)
    poses[:, :r, :r], poses[:, :r, r] = rotations, _translations(graph, basis, rotations, known)[:n]
    return poses
