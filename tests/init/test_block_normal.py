"""The relaxation's normal equations (posegraph/init/block_normal.py) and the relaxed start built on
them against the same least squares written densely: equal to round-off."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.init import relaxation
from posegraph.init.block_normal import BlockNormalEquations, Factors
from posegraph.lie.group import SE2, SE3


def _dense(factors: list, sizes: np.ndarray, known: np.ndarray, values: np.ndarray):
    """``(N, g)`` of ``Σ ‖A_a x_a + A_b x_b − y‖²_W`` over the free blocks, written row by row."""
    offsets = np.concatenate(([0], np.cumsum(np.where(known, 0, sizes))))
    N, g = np.zeros((offsets[-1], offsets[-1])), np.zeros(offsets[-1])
    for f in factors:
        for e in range(len(f.a)):
            row, y = np.zeros((f.y.shape[1], offsets[-1])), f.y[e].copy()
            for block, A in ((f.a[e], f.A_a[e]), (f.b[e], f.A_b[e])):
                if block < 0:
                    continue
                if known[block]:
                    y -= A @ values[block, : A.shape[1]]
                else:
                    row[:, offsets[block] : offsets[block] + A.shape[1]] += A
            N += row.T @ (f.w[e][:, None] * row)
            g += row.T @ (f.w[e] * y)
    return N, g


def _full(system: BlockNormalEquations, data: np.ndarray) -> np.ndarray:
    """The symmetric matrix whose lower triangle the CSC ``(data, indices, indptr)`` stores."""
    dense = np.zeros((system.size, system.size))
    columns = np.repeat(np.arange(system.size), np.diff(system.indptr))
    lower = system.indices >= columns
    np.add.at(dense, (system.indices[lower], columns[lower]), data[lower])
    return dense + np.tril(dense, -1).T


def _random_factors(rng, sizes: np.ndarray, size_a: int, size_b: int, count: int = 40, rows: int = 3) -> Factors:
    """Factors from random blocks of size ``size_a`` to random others of size ``size_b`` (both
    orientations of the block order, repeated pairs), a fifth of them unary."""
    a = rng.choice(np.flatnonzero(sizes == size_a), count)
    b = rng.choice(np.flatnonzero(sizes == size_b), count)
    b[(b == a) | (rng.random(count) < 0.2)] = -1
    return Factors(a, b, rng.normal(size=(count, rows, size_a)), rng.normal(size=(count, rows, size_b)),
                   rng.normal(size=(count, rows)), rng.uniform(0.5, 2.0, (count, rows)))  # fmt: skip


def test_the_block_pattern_sums_the_normal_equations_of_every_factor():
    rng = np.random.default_rng(4)
    sizes = np.array([4, 2, 4, 3, 2, 4, 2, 3, 4, 2])
    known = np.zeros(len(sizes), bool)
    known[[3, 6]] = True
    values = rng.normal(size=(len(sizes), 4))
    factors = [_random_factors(rng, sizes, size_a, size_b) for size_a, size_b in ((4, 2), (2, 4), (4, 4), (3, 2), (2, 3))]
    system = BlockNormalEquations(sizes, known, [(f.a, f.b) for f in factors])
    N, g = _dense(factors, sizes, known, values)
    data = system.matrix(factors)
    np.testing.assert_allclose(_full(system, data), N, rtol=0, atol=1e-12)
    np.testing.assert_allclose(system.right_hand_side(factors, values), g, rtol=0, atol=1e-12)
    np.testing.assert_allclose(system.diagonal(data), np.diag(N), rtol=0, atol=1e-12)
    columns = np.repeat(np.arange(system.size), np.diff(system.indptr))
    assert len(set(zip(system.indices.tolist(), columns.tolist()))) == system.nnz  # no entry stored twice
    np.testing.assert_allclose(system.solve(data, g), np.linalg.solve(N, g), rtol=1e-9, atol=1e-9)


def _dense_relaxed_start(graph, passes: int) -> np.ndarray:
    """The relaxation of :func:`posegraph.init.relaxation.relaxed_start` with ``passes`` unit passes, every
    system summed densely, the translation stage over the ``r`` coordinates together."""
    group, n, L = graph.group, graph.num_vertices, graph.landmarks.count
    r = group.space_dim
    basis, poses = relaxation.rotation_basis(r), np.array(graph.poses, copy=True)
    K = len(basis)
    reached_poses, reached_points = relaxation._reached(graph)
    known = np.concatenate([relaxation.relaxation_anchors(graph) | ~reached_poses, graph.landmarks.fixed | ~reached_points])
    values = np.zeros((n + L, K + r))
    values[:n, :K], values[:n, K:], values[n:, :r] = relaxation.rotation_coordinates(poses[:, :r, :r], basis), poses[:, :r, r], graph.landmarks.positions
    sizes = np.concatenate([np.full(n, K + r), np.full(L, r)])
    offsets = np.concatenate(([0], np.cumsum(np.where(known, 0, sizes))))
    N, g = _dense([relaxation._edge_factors(graph, basis, None)] + relaxation._landmark_factors(graph, basis, None, n), sizes, known, values)
    weights = np.array([0.0 if known[i] else np.diag(N)[offsets[i] : offsets[i] + K].mean() for i in range(n)])
    x = np.linalg.solve(N, g)
    for solved in range(passes + 1):
        u = np.array([values[i, :K] if known[i] else x[offsets[i] : offsets[i] + K] for i in range(n)])
        rotations = group.rotations.project(np.einsum("nk,kab->nab", u, basis))
        rotations[known[:n]] = poses[known[:n], :r, :r]
        if solved < passes:
            N_unit, g_unit = _dense([relaxation._unit_factors(rotations, basis, weights)], sizes, known, values)
            x = np.linalg.solve(N + N_unit, g + g_unit)
    factors = [relaxation._edge_factors(graph, basis, rotations)] + relaxation._landmark_factors(graph, basis, rotations, n)
    values = np.concatenate([poses[:, :r, r], graph.landmarks.positions])
    offsets = np.concatenate(([0], np.cumsum(np.where(known, 0, r))))
    x = np.linalg.solve(*_dense(factors, np.full(n + L, r), known, values))
    poses[:, :r, :r] = rotations
    poses[~known[:n], :r, r] = x[offsets[:n][~known[:n], None] + np.arange(r)]
    return poses


@pytest.mark.parametrize("group, kinds, offsets", [
    (SE2, ("position", "prior"), False), (SE2, ("bearing_range", "position"), False), (SE3, ("position", "prior"), True),
])  # fmt: skip
@pytest.mark.parametrize("passes", [0, 2])
def test_the_relaxed_start_equals_its_dense_formulation(group, kinds, offsets, passes):
    graph, _, _ = landmark_graph(group, 12, 7, kinds, noise=0.05, seed=8, offsets=offsets, per_landmark=4)
    fixed = np.zeros(graph.landmarks.count, bool)
    fixed[2] = True  # a known point: its terms on the right-hand side
    graph = replace(graph, landmarks=replace(graph.landmarks, fixed=fixed))
    np.testing.assert_allclose(relaxation.relaxed_start(graph, unit_passes=passes), _dense_relaxed_start(graph, passes), rtol=0, atol=1e-9)


def test_without_cvxopt_superlu_gives_the_same_start(monkeypatch):
    from posegraph.linalg import cholmod

    graph, _, _ = landmark_graph(SE2, 12, 7, ("position", "prior"), noise=0.05, seed=9, per_landmark=4)
    with_cholmod = relaxation.relaxed_start(graph)
    monkeypatch.setattr(cholmod, "load", lambda: None)  # as without cvxopt
    np.testing.assert_allclose(relaxation.relaxed_start(graph), with_cholmod, rtol=0, atol=1e-9)
