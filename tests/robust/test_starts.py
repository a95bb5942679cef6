"""Starts for robust optimisation: the inlier chain ignores loop closures, the down-weighted and
robust chordal starts discount them, and GNC over chordal starts finds injected outliers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from datasets.synthetic import grid, inject_outliers, sphere
from posegraph.lie import se3
from posegraph.robust.starts import (
    downweighted_chordal_start,
    inlier_chain_start,
    robust_chordal_start,
)
from posegraph.robust.measurements import squared_residuals, weighted_graph
from posegraph.solve.residuals import edge_residuals


def _corrupted(seed=1):
    clean = sphere(6, 8, seed=seed).graph
    graph, indices = inject_outliers(clean, fraction=0.2, seed=seed)
    outlier = np.zeros(graph.num_edges, bool)
    outlier[indices] = True
    return clean, graph, outlier


def test_inlier_chain_start_composes_the_odometry_only():
    clean, graph, _ = _corrupted()
    start = inlier_chain_start(graph)
    # The odometry edges are met exactly; changing any loop closure changes nothing.
    odometry = graph.odometry_mask()
    assert np.abs(edge_residuals(start, graph)[odometry]).max() < 1e-9
    shuffled = graph.measurements.copy()
    shuffled[~odometry] = se3.exp(np.random.default_rng(0).standard_normal((np.count_nonzero(~odometry), 6)))
    other = inlier_chain_start(dataclasses.replace(graph, measurements=shuffled, edge_source=None))
    np.testing.assert_array_equal(other, start)
    np.testing.assert_array_equal(start[0], graph.poses[0])  # the anchor keeps its pose


def test_weighted_graph_scales_the_cost():
    _, graph, _ = _corrupted()
    weights = np.random.default_rng(2).uniform(0, 1, graph.num_edges)
    s = squared_residuals(graph, graph.poses)
    np.testing.assert_allclose(squared_residuals(weighted_graph(graph, weights), graph.poses), weights * s, rtol=1e-12)


def test_downweighted_chordal_start_moves_towards_the_chain():
    _, graph, outlier = _corrupted()
    full = downweighted_chordal_start(graph, 1.0)
    light = downweighted_chordal_start(graph, 1e-9)
    chain = inlier_chain_start(graph)
    # With loop closures weighing nothing the chordal start is the chain's (up to rounding).
    assert np.abs(light - chain).max() < 1e-4 < np.abs(full - chain).max()
    with pytest.raises(ValueError, match="factor"):
        downweighted_chordal_start(graph, 0.0)


@pytest.mark.parametrize("seed", [1, 2])
def test_robust_chordal_start_rejects_the_outliers_and_gnc_recovers_the_inliers(seed):
    """On a coarse sphere (8 poses a ring) the chordal rotations are rough — inliers' s reaches
    ~400 at the chordal start with the outliers known — so GNC over chordal starts rejects every
    outlier and many inliers besides; GNC over LM, started from it with its weights, keeps
    the outliers and a few inliers of the χ² tail."""
    from posegraph.init import initialize
    from posegraph.robust.gnc import run_gnc
    from posegraph.solve import optimize
    from posegraph.solve.residuals import cost

    clean, graph, outlier = _corrupted(seed)
    start = robust_chordal_start(graph)
    assert not np.any(start.inliers & outlier)
    assert cost(clean, start.poses) < 0.01 * cost(clean, initialize(graph, "chordal"))

    result = run_gnc(
        lambda poses: squared_residuals(graph, poses),
        lambda poses, weights: optimize(weighted_graph(graph, weights), initial=poses).poses,
        start.poses,
        graph.odometry_mask(),
        initial_weights=start.weights,
    )
    assert not np.any(result.inliers & outlier)
    # A TLS fixed point: the rejected edges are beyond the threshold at the result, the kept
    # ones within it; few inliers are lost (those at the clean optimum's χ² tail).
    s = squared_residuals(graph, result.poses)
    threshold = 16.811893829770927
    assert np.all(s[~result.inliers] > threshold) and np.all(s[result.inliers] <= threshold * 1.01)
    inlier_loops = ~graph.odometry_mask() & ~outlier
    assert np.count_nonzero(~result.inliers & inlier_loops) <= 0.05 * np.count_nonzero(inlier_loops)


def test_robust_chordal_start_on_a_grid():
    clean = grid(4, 4, 3, seed=1).graph
    graph, indices = inject_outliers(clean, fraction=0.2, seed=3)
    result = robust_chordal_start(graph)
    assert set(np.flatnonzero(~result.inliers)) == set(indices.tolist())


def test_known_inliers_shape_is_checked():
    _, graph, _ = _corrupted()
    with pytest.raises(ValueError, match="known_inliers"):
        inlier_chain_start(graph, np.ones(3, bool))
