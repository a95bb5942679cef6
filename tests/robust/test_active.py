"""ActiveEdgeSolves: a solve over an analysed edge superset with some edges at weight 0 equals the
solve over the subgraph without them (vertices they leave unconstrained held at their pose), and
the analysis is remade only as ``reanalyse_fraction`` says."""

from __future__ import annotations

import numpy as np
import pytest

from datasets.synthetic import inject_outliers, sphere
from posegraph.init.chordal import chordal_initialization
from posegraph.robust.active import ActiveEdgeSolves, edge_subgraph
from posegraph.solve import SolverParams, optimize

TIGHT = SolverParams(relative_tolerance=1e-14, absolute_tolerance=1e-20)
"""LM run to the optimum itself, so two solves of one problem agree to round-off, not to a tolerance."""


@pytest.fixture(scope="module")
def case():
    """``(graph, weights, lone, pair)``: a 6 × 8 sphere with 20 % outliers; weights 0 on the outliers,
    on every edge of vertex ``lone`` and on every edge of vertices ``pair`` but the one joining them
    (a component of two that holds no vertex of the graph's anchor), fractional elsewhere."""
    graph, outliers = inject_outliers(sphere(6, 8, seed=1).graph, fraction=0.2, seed=1)
    weights = np.random.default_rng(0).uniform(0.2, 1.0, graph.num_edges)
    weights[outliers] = 0.0
    lone, pair = 47, (44, 45)
    touches = lambda v: (graph.edge_from == v) | (graph.edge_to == v)  # noqa: E731
    weights[touches(lone)] = 0.0
    joining = (graph.edge_from == pair[0]) & (graph.edge_to == pair[1])
    assert np.count_nonzero(joining) == 1  # the odometry edge 44 -> 45
    weights[(touches(pair[0]) | touches(pair[1])) & ~joining] = 0.0
    return graph, weights, lone, pair


def _analysed_over_all_edges(graph, fraction=0.0):
    solves = ActiveEdgeSolves(graph, TIGHT, reanalyse_fraction=fraction)
    solves.chordal(np.ones(graph.num_edges))
    solves.least_squares(graph.poses, np.ones(graph.num_edges))
    assert solves.analyses == 2
    return solves


def test_chordal_over_all_edges_equals_the_chordal_start_of_the_subgraph(case):
    graph, weights, lone, pair = case
    solves = _analysed_over_all_edges(graph)
    poses = solves.chordal(weights)
    assert solves.analyses == 2  # served by the analysis over every edge
    subgraph = edge_subgraph(graph, np.flatnonzero(weights > 0), weights)
    np.testing.assert_allclose(poses, chordal_initialization(subgraph), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(poses[lone], graph.poses[lone])  # held at its file pose
    np.testing.assert_array_equal(poses[pair[0]], graph.poses[pair[0]])  # the pair's anchor
    joining = np.flatnonzero((graph.edge_from == pair[0]) & (graph.edge_to == pair[1]))[0]
    np.testing.assert_allclose(poses[pair[1]], poses[pair[0]] @ graph.measurements[joining], atol=1e-9)  # its one edge


def test_least_squares_over_all_edges_equals_lm_on_the_subgraph(case):
    graph, weights, lone, pair = case
    solves = _analysed_over_all_edges(graph)
    start = chordal_initialization(graph)
    fitted = solves.least_squares(start, weights)
    assert solves.analyses == 2
    subgraph = edge_subgraph(graph, np.flatnonzero(weights > 0), weights)
    direct = optimize(subgraph, initial=start, params=TIGHT)
    # The costs agree to round-off; the poses to what round-off moves along the flattest direction
    # of this weighted problem (3.4e-8 m in 100 m with one OpenBLAS build, 1e-10 with another).
    np.testing.assert_allclose(fitted.poses, direct.poses, rtol=0, atol=1e-7)
    assert fitted.final_cost == pytest.approx(direct.final_cost, rel=1e-12)
    np.testing.assert_array_equal(fitted.poses[lone], start[lone])  # held at its start pose
    np.testing.assert_array_equal(fitted.poses[pair[0]], start[pair[0]])
    joining = np.flatnonzero((graph.edge_from == pair[0]) & (graph.edge_to == pair[1]))[0]
    np.testing.assert_allclose(fitted.poses[pair[1]], start[pair[0]] @ graph.measurements[joining], atol=1e-9)
    assert fitted.converged and fitted.final_cost < fitted.initial_cost


@pytest.mark.parametrize(
    "fraction, expected",
    [(0.0, [1, 1, 1, 1]), (0.9, [1, 1, 2, 3]), (1.0, [1, 2, 3, 4])],
)
def test_analyses_are_remade_only_as_the_policy_says(case, fraction, expected):
    """Active sets: all edges; 95 % of them; 85 % (a subset of those); then one more edge, outside
    every analysed set but the first (analyse-once still holds that one)."""
    graph, _, _, _ = case
    m = graph.num_edges
    order = np.random.default_rng(1).permutation(m)
    solves = ActiveEdgeSolves(graph, reanalyse_fraction=fraction)
    counts = []
    for keep in (m, int(0.95 * m), int(0.85 * m)):
        weights = np.zeros(m)
        weights[order[:keep]] = 1.0
        solves.chordal(weights)
        counts.append(solves.analyses)
    weights[order[-1]] = 1.0
    solves.chordal(weights)
    counts.append(solves.analyses)
    assert counts == expected


def test_reanalyse_fraction_outside_0_1_is_refused(case):
    with pytest.raises(ValueError, match="reanalyse_fraction"):
        ActiveEdgeSolves(case[0], reanalyse_fraction=1.5)


def test_weighted_solves_order_by_nested_dissection_unless_told(case):
    """'auto' means nested dissection here (random wrong loop closures fill less under it); an explicit
    ordering is kept; either way the solves reach the same poses."""
    import importlib.util

    from posegraph.robust.active import ROBUST_ORDERING

    graph, weights, _, _ = case
    auto = ActiveEdgeSolves(graph, TIGHT)
    expected = ROBUST_ORDERING if importlib.util.find_spec("pymetis") is not None else "amd"
    assert auto.params.ordering == expected
    amd = ActiveEdgeSolves(graph, SolverParams(relative_tolerance=1e-14, absolute_tolerance=1e-20, ordering="amd"))
    assert amd.params.ordering == "amd"
    fitted = [solves.least_squares(solves.chordal(weights), weights) for solves in (auto, amd)]
    if fitted[0].linear_solver.startswith("cholmod"):
        assert f"supernodal, {expected}" in fitted[0].linear_solver and "supernodal, amd" in fitted[1].linear_solver
    np.testing.assert_allclose(fitted[0].poses, fitted[1].poses, atol=1e-8)
