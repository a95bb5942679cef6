"""GNC weighs the priors like the edges: a wrong GNSS fix is rejected like a wrong loop closure."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import grid, inject_outliers
from posegraph.model.priors import Priors
from posegraph.robust.pipeline import optimize_robust
from posegraph.solve import optimize
from posegraph.solve.residuals import cost


def graph_with_priors(seed=1, wrong=(2,)):
    """A 4×4×3 grid with wrong loop closures, GNSS-like position priors (σ = 0.1) on every 4th
    vertex, the whole graph moved away from the origin by them, and the priors ``wrong`` off by 30 m."""
    data = grid(4, 4, 3, seed=seed)
    clean = data.graph
    rng = np.random.default_rng(seed)
    every = np.arange(0, clean.num_vertices, 4)
    world = np.eye(4)
    world[:3, 3] = [100.0, -50.0, 20.0]
    truth = world @ data.ground_truth
    points = truth[every, :3, 3] + rng.normal(scale=0.1, size=(len(every), 3))
    points[list(wrong)] += 30.0
    priors = Priors(
        np.zeros(0, np.int64), np.zeros((0, 4, 4)), np.zeros((0, 4, 4)), np.zeros((0, 6, 6)),
        every, points, np.tile(np.eye(3) * 100.0, (len(every), 1, 1)),
    )  # fmt: skip
    corrupted, outliers = inject_outliers(clean, fraction=0.2, seed=seed)
    return replace(corrupted, priors=priors), clean, outliers, priors


@pytest.mark.parametrize("seed", [1, 2])
def test_gnc_rejects_a_wrong_prior_and_the_wrong_loop_closures(seed):
    graph, clean, outliers, priors = graph_with_priors(seed)
    robust = optimize_robust(graph)
    assert robust.prior_weights.shape == (len(priors),)
    assert np.flatnonzero(robust.prior_weights < 0.5).tolist() == [2]
    np.testing.assert_array_equal(robust.outlier_edges, np.sort(outliers))
    # the answer is the optimum of the clean graph with the right priors (no vertex held)
    keep = np.flatnonzero(np.arange(len(priors)) != 2)
    right = replace(clean, priors=replace(priors, position_vertex=priors.position_vertex[keep],
                                           position_measurements=priors.position_measurements[keep],
                                           position_information=priors.position_information[keep]))
    reference = optimize(right)
    assert cost(right, robust.poses) == pytest.approx(reference.final_cost, rel=1e-7)
    assert np.linalg.norm(robust.poses[0, :3, 3] - [100.0, -50.0, 20.0]) < 1.0
