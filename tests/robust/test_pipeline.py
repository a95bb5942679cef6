"""optimize_robust: exact outlier sets and the clean optimum on graphs with injected outliers;
solves over the edges of nonzero weight agree with the weighted graph; analyses are reused."""

from __future__ import annotations

import numpy as np
import pytest

from datasets.synthetic import grid, inject_outliers, sphere
from posegraph.init.chordal import chordal_initialization, chordal_problem
from posegraph.robust.active import ActiveEdgeSolves, edge_subgraph
from posegraph.robust.gnc import GncParams
from posegraph.robust.pipeline import known_inlier_mask, optimize_robust
from posegraph.robust.measurements import weighted_graph
from posegraph.solve import SolverParams, analyze, optimize


def _corrupted(clean, fraction=0.2, seed=1):
    graph, indices = inject_outliers(clean, fraction=fraction, seed=seed)
    outlier = np.zeros(graph.num_edges, bool)
    outlier[indices] = True
    return graph, outlier


@pytest.mark.parametrize("seed", [1, 2])
def test_finds_exactly_the_outliers_and_the_clean_optimum_on_a_grid(seed):
    clean = grid(4, 4, 3, seed=seed).graph
    graph, outlier = _corrupted(clean, seed=seed)
    robust = optimize_robust(graph)
    np.testing.assert_array_equal(robust.outlier_edges, np.flatnonzero(outlier))
    reference = optimize(clean)
    from posegraph.solve.residuals import cost

    assert cost(clean, robust.poses) == pytest.approx(reference.final_cost, rel=1e-7)


def test_by_default_no_outer_iteration_analyses_anew():
    """One symbolic analysis of the chordal system and one of the LM system for the outer iterations
    and TLS rounds, however many, and one for the re-admission trial's step over every edge (it
    ends there: the outliers raise the TLS objective); re-analysing on every change of the edge set
    finds the same outliers."""
    graph, outlier = _corrupted(grid(4, 4, 3, seed=3).graph)
    once = optimize_robust(graph)
    assert len(once.history) > 3 and once.analyses == 3 and once.readmitted.size == 0
    every = optimize_robust(graph, reanalyse_fraction=1.0)
    assert every.analyses > once.analyses
    np.testing.assert_array_equal(once.outlier_edges, np.flatnonzero(outlier))
    np.testing.assert_array_equal(every.outlier_edges, once.outlier_edges)
    np.testing.assert_allclose(every.poses, once.poses, atol=1e-8)


def test_small_grid3d_with_half_outliers(shared_dataset):
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.residuals import cost

    clean = read_g2o(shared_dataset("smallGrid3D"))
    graph, outlier = _corrupted(clean, fraction=0.5)
    robust = optimize_robust(graph)
    np.testing.assert_array_equal(robust.outlier_edges, np.flatnonzero(outlier))
    assert cost(clean, robust.poses) == pytest.approx(optimize(clean).final_cost, rel=1e-7)
    assert robust.history[-1].mu == np.inf  # ended on a TLS round, after the GNC start
    assert robust.start.iterations == len([h for h in robust.history if np.isfinite(h.mu)])


def test_gnc_over_least_squares_from_given_poses_finds_the_outliers():
    graph, outlier = _corrupted(grid(4, 4, 3, seed=1).graph)
    from posegraph.robust.starts import inlier_chain_start

    robust = optimize_robust(graph, initial=inlier_chain_start(graph))
    np.testing.assert_array_equal(robust.outlier_edges, np.flatnonzero(outlier))


def test_geman_mcclure_surrogate_down_weights_the_outliers():
    graph, outlier = _corrupted(grid(4, 4, 3, seed=1).graph)
    robust = optimize_robust(graph, gnc=GncParams(loss="gm"))
    assert np.all(robust.weights[outlier] < 0.5) and np.all(robust.weights[~outlier] > 0.5)


def test_known_inliers_none_and_masks():
    graph, _ = _corrupted(grid(3, 3, 2, seed=1).graph)
    assert not known_inlier_mask(graph, "none").any()
    np.testing.assert_array_equal(known_inlier_mask(graph, None), graph.odometry_mask())
    with pytest.raises(ValueError, match="known_inliers"):
        known_inlier_mask(graph, "loops")
    with pytest.raises(ValueError, match="bool mask"):
        known_inlier_mask(graph, np.ones(3, bool))


def test_active_edge_solves_equal_solves_of_the_weighted_graph():
    """Dropping weight-0 edges changes nothing (they contribute nothing); the analyses are reused
    while the edge set stays the same and remade when it changes."""
    graph, outlier = _corrupted(sphere(6, 8, seed=1).graph)
    weights = np.where(outlier, 0.0, np.random.default_rng(0).uniform(0.2, 1.0, graph.num_edges))
    solves = ActiveEdgeSolves(graph)
    chordal = solves.chordal(weights)
    np.testing.assert_allclose(chordal, chordal_initialization(weighted_graph(graph, weights)), atol=1e-9)
    fitted = solves.least_squares(chordal, weights)
    direct = optimize(weighted_graph(graph, weights), initial=chordal)
    np.testing.assert_allclose(fitted.poses, direct.poses, atol=1e-7)
    assert solves.analyses == 2
    solves.chordal(weights * 0.5)
    solves.least_squares(chordal, weights * 0.5)
    assert solves.analyses == 2  # same edge set: nothing analysed again
    solves.chordal(np.where(outlier, 0.0, 1.0))
    assert solves.analyses == 2
    solves.chordal(np.ones(graph.num_edges))
    assert solves.analyses == 3
    with pytest.raises(ValueError, match="weights"):
        solves.chordal(-np.ones(graph.num_edges))
    with pytest.raises(ValueError, match="loss=None"):
        ActiveEdgeSolves(graph, SolverParams(loss=object.__new__(_Unit)))


class _Unit:
    def rho(self, s):
        return s

    def weight(self, s):
        return np.ones_like(s)


def test_optimize_with_a_reused_analysis_is_bit_identical():
    graph = sphere(6, 8, seed=2).graph
    start = chordal_initialization(graph)
    analysis = analyze(graph)
    once = optimize(graph, initial=start)
    again = optimize(weighted_graph(graph, np.ones(graph.num_edges)), initial=start, analysis=analysis)
    np.testing.assert_array_equal(once.poses, again.poses)
    assert once.records[-1].cost == again.records[-1].cost
    other = edge_subgraph(graph, np.arange(graph.num_edges - 1))
    with pytest.raises(ValueError, match="other edges"):
        optimize(other, initial=start, analysis=analysis)


def test_chordal_with_a_reused_problem_is_bit_identical():
    graph = sphere(6, 8, seed=2).graph
    problem = chordal_problem(graph)
    np.testing.assert_array_equal(chordal_initialization(graph, problem=problem), chordal_initialization(graph))
    with pytest.raises(ValueError, match="other edges"):
        chordal_initialization(edge_subgraph(graph, np.arange(5)), problem=problem)


def test_edge_subgraph_keeps_the_file_lines_only_while_they_state_the_edges(tmp_path):
    from posegraph.io.g2o import read_g2o, write_g2o

    graph, _ = _corrupted(grid(3, 3, 2, seed=1).graph)
    path = tmp_path / "g.g2o"
    write_g2o(path, graph)
    read = read_g2o(path)
    assert read.edge_source is not None
    keep = np.flatnonzero(read.odometry_mask() | (np.arange(read.num_edges) % 2 == 0))
    sub = edge_subgraph(read, keep)
    assert sub.edge_source is not None and sub.edge_source.matches(sub)
    assert sub.edge_source.lines == [read.edge_source.lines[k] for k in keep]
    assert edge_subgraph(read, keep, np.full(read.num_edges, 0.5)).edge_source is None
    write_g2o(tmp_path / "sub.g2o", sub)
    back = read_g2o(tmp_path / "sub.g2o")
    np.testing.assert_array_equal(back.measurements, read.measurements[keep])
    np.testing.assert_array_equal(back.information, read.information[keep])


@pytest.mark.parametrize("name", ["tinyGrid3D", "smallGrid3D"])
def test_clean_graphs_lose_no_edge_and_reach_the_least_squares_optimum(shared_dataset, name):
    from posegraph.io.g2o import read_g2o

    graph = read_g2o(shared_dataset(name))
    robust = optimize_robust(graph)
    assert len(robust.outlier_edges) == 0
    assert robust.final_cost == pytest.approx(optimize(graph).final_cost, rel=1e-9)


@pytest.mark.parametrize("seed", [1, 2])
def test_planar_graph_exact_outlier_set(seed):
    """SE(2): the same pipeline, χ² thresholds of a 3-dimensional residual; the robust chordal
    start alone keeps ~98 % of the inlier loop closures here, the TLS rounds all of them."""
    from datasets.synthetic import NoiseParams, generate

    dataset = generate("manhattan", 500, noise=NoiseParams(outlier_fraction=0.2), seed=seed)
    robust = optimize_robust(dataset.graph)
    np.testing.assert_array_equal(robust.outlier_edges, np.flatnonzero(dataset.outliers))
    assert robust.poses.shape == (dataset.graph.num_vertices, 3, 3)
