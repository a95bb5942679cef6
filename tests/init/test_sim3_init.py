"""Sim(3) starts: chordal rotations, then log-scales and translations by linear least squares; odometry."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from posegraph.model.graph import PoseGraph
from posegraph.init import initialize
from posegraph.init.chordal import translations_given_rotations
from posegraph.init.scales import log_scales, rotation_blocks
from posegraph.model.graph import held_vertices
from posegraph.lie import sim3
from posegraph.lie.group import SIM3
from posegraph.solve.residuals import cost, edge_residuals


def drifted_graph(rng, n=60, loops=25, noise=0.0):
    """A trajectory whose odometry scale drifts, loop closures with the true relative scale; start = odometry
    with a wrong scale per step (camera-to-world Sim(3) poses)."""
    steps = np.concatenate([rng.normal(size=(n - 1, 3)) * 0.15, rng.normal(size=(n - 1, 3)) * 0.3 + [1, 0, 0],
                            rng.normal(size=(n - 1, 1)) * 0.03], axis=1)  # fmt: skip
    truth = [np.eye(4)]
    for step in sim3.exp(steps):
        truth.append(truth[-1] @ step)
    truth = np.array(truth)
    i = np.r_[np.arange(n - 1), rng.integers(0, n, loops)]
    j = np.r_[np.arange(1, n), rng.integers(0, n, loops)]
    keep = i != j
    i, j = i[keep], j[keep]
    Z = sim3.between(truth[i], truth[j]) @ sim3.exp(rng.normal(size=(len(i), 7)) * noise)
    information = np.broadcast_to(np.diag([400.0, 400, 400, 100, 100, 100, 1e3]), (len(i), 7, 7)).copy()
    start = truth @ sim3.exp(rng.normal(size=(n, 7)) * 0.3)
    start[0] = truth[0]
    graph = PoseGraph(ids=np.arange(n), poses=start, edge_from=i, edge_to=j, measurements=Z, information=information, group=SIM3)
    return graph, truth


@pytest.mark.parametrize("method", ["chordal", "odometry"])
def test_noise_free_graph_starts_at_the_truth(method):
    graph, truth = drifted_graph(np.random.default_rng(0))
    assert cost(graph) > 1e3
    start = initialize(graph, method)
    np.testing.assert_allclose(start, truth, rtol=0, atol=1e-9)


def test_log_scales_solve_their_normal_equations():
    graph, _ = drifted_graph(np.random.default_rng(1), noise=0.05)
    held = held_vertices(graph)
    lam = log_scales(graph, held)
    _, measured = rotation_blocks(graph.measurements, SIM3)
    w = graph.information[:, 6, 6]
    error = lam[graph.edge_to] - lam[graph.edge_from] - measured
    gradient = np.bincount(graph.edge_to, w * error, graph.num_vertices) - np.bincount(graph.edge_from, w * error, graph.num_vertices)
    assert np.abs(gradient[~held]).max() < 1e-9 * w.max()
    assert lam[held] == pytest.approx(rotation_blocks(graph.poses[held], SIM3)[1])


def test_translations_minimise_the_exact_cost_given_rotations_and_scales():
    graph, _ = drifted_graph(np.random.default_rng(2), noise=0.05)
    start = initialize(graph, "chordal")
    rotations, _ = rotation_blocks(start, SIM3)
    np.testing.assert_allclose(translations_given_rotations(graph, rotations), start[:, :3, 3], rtol=0, atol=1e-10)
    # Any translation step raises the cost (it is quadratic in them, and this is its minimum).
    rng = np.random.default_rng(3)
    base = cost(graph, start)
    for _ in range(5):
        moved = start.copy()
        moved[1:, :3, 3] += rng.normal(size=(graph.num_vertices - 1, 3)) * 1e-3
        assert cost(graph, moved) > base
    # ... and the residuals' translation parts are orthogonal to every translation direction: the
    # cost's translation gradient Σ Bᵀ(Ω e)_υ vanishes, seen through a symmetric difference.
    h = 1e-6
    for vertex in (5, 17, 40):
        for axis in range(3):
            plus, minus = start.copy(), start.copy()
            plus[vertex, axis, 3] += h
            minus[vertex, axis, 3] -= h
            assert abs(cost(graph, plus) - cost(graph, minus)) / (2 * h) < 1e-6 * max(base, 1.0)


def test_chordal_start_of_a_noisy_drifted_graph_is_close_to_its_optimum():
    from posegraph.solve import SolverParams, optimize

    graph, _ = drifted_graph(np.random.default_rng(4), noise=0.01)
    result = optimize(graph, initial="chordal", params=SolverParams(method="lm"))
    start_cost = cost(graph, initialize(graph, "chordal"))
    file_cost, odometry_cost = cost(graph), cost(graph, initialize(graph, "odometry"))
    assert start_cost < 20 * result.final_cost < file_cost
    assert odometry_cost > 5 * start_cost
