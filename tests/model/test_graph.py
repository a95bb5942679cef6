"""The graph model on small hand-built graphs: components, anchors, degrees, odometry, index_of."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.model.graph import PoseGraph, component_anchors, connected_components, graph_facts


def make_graph(ids, edges, fixed_ids=()):
    """A graph with identity poses/measurements; ``edges`` are (id_i, id_j) pairs."""
    ids = np.asarray(ids, dtype=np.int64)
    index = {int(i): k for k, i in enumerate(ids)}
    m = len(edges)
    return PoseGraph(
        ids=ids,
        poses=np.tile(np.eye(4), (len(ids), 1, 1)),
        edge_from=np.array([index[i] for i, _ in edges], dtype=np.int64),
        edge_to=np.array([index[j] for _, j in edges], dtype=np.int64),
        measurements=np.tile(np.eye(4), (m, 1, 1)),
        information=np.tile(np.eye(6), (m, 1, 1)),
        fixed=np.isin(ids, np.asarray(fixed_ids, dtype=np.int64)),
    )


# Three components, ids unordered and stepping by ten:
#   A = {10, 20, 30}: 10→20, 20→30, 30→10 (a loop closure)
#   B = {40, 50}: 50→40 and 40→50 (a repeated measurement), with 50 fixed
#   C = {60}: isolated
IDS = [30, 10, 20, 50, 40, 60]
EDGES = [(10, 20), (20, 30), (30, 10), (50, 40), (40, 50)]


@pytest.fixture
def graph():
    return make_graph(IDS, EDGES, fixed_ids=[50])


def test_counts_and_default_fixed():
    g = make_graph(IDS, EDGES)
    assert (g.num_vertices, g.num_edges) == (6, 5)
    assert g.fixed.dtype == bool and not g.fixed.any()


def test_connected_components(graph):
    count, labels = connected_components(graph)
    assert count == 3
    groups = {frozenset(np.asarray(IDS)[labels == label].tolist()) for label in range(count)}
    assert groups == {frozenset({10, 20, 30}), frozenset({40, 50}), frozenset({60})}


def edge_graph(n, edge_from, edge_to):
    m = len(edge_from)
    return PoseGraph(
        ids=np.arange(n), poses=np.tile(np.eye(4), (n, 1, 1)),
        edge_from=np.asarray(edge_from, dtype=np.int64), edge_to=np.asarray(edge_to, dtype=np.int64),
        measurements=np.tile(np.eye(4), (m, 1, 1)), information=np.tile(np.eye(6), (m, 1, 1)),
    )


@pytest.mark.parametrize("seed", range(40))
def test_connected_components_equal_scipys_labels(seed):
    """Same count and the same labels (numbered by each component's first vertex) as csgraph's,
    on random graphs with isolated vertices, repeated edges, self-loops and both edge directions."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as scipy_components

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 80))
    m = int(rng.integers(0, 2 * n))
    i, j = rng.integers(0, n, m), rng.integers(0, n, m)
    count, labels = connected_components(edge_graph(n, i, j))
    expected_count, expected = scipy_components(coo_matrix((np.ones(m), (i, j)), shape=(n, n)), directed=False)
    assert count == expected_count
    np.testing.assert_array_equal(labels, expected)


@pytest.mark.parametrize("order", ["forward", "backward", "shuffled"])
def test_connected_components_of_long_chains(order):
    """A 20,000-vertex chain (the worst case for label propagation), edges in any order: one
    component, and two once the middle edge is cut."""
    n = 20_000
    i = np.arange(n - 1)
    if order == "backward":
        i = i[::-1]
    elif order == "shuffled":
        i = np.random.default_rng(0).permutation(i)
    assert connected_components(edge_graph(n, i, i + 1))[0] == 1
    keep = i != n // 2
    count, labels = connected_components(edge_graph(n, i[keep], i[keep] + 1))
    assert count == 2
    assert (labels[: n // 2 + 1] == 0).all() and (labels[n // 2 + 1 :] == 1).all()


def test_component_anchors_are_smallest_ids_of_unfixed_components(graph):
    anchors = component_anchors(graph)
    # A is anchored at id 10 (index 1, not the first vertex of the file); B has a FIX; C anchors itself.
    assert anchors.tolist() == [1, 5]
    assert graph.ids[anchors].tolist() == [10, 60]


def test_every_component_needs_an_anchor_without_fixes():
    g = make_graph(IDS, EDGES)
    assert g.ids[component_anchors(g)].tolist() == [10, 40, 60]


def test_a_fixed_vertex_anywhere_in_a_component_removes_its_anchor():
    g = make_graph(IDS, EDGES, fixed_ids=[30, 60])
    assert g.ids[component_anchors(g)].tolist() == [40]


def test_graph_facts(graph):
    facts = graph_facts(graph)
    assert (facts.num_vertices, facts.num_edges, facts.num_fixed, facts.num_components) == (6, 5, 1, 3)
    # Degrees (ids 30, 10, 20, 50, 40, 60): 2, 2, 2, 2, 2, 0.
    assert (facts.degree_min, facts.degree_max) == (0, 2)
    assert facts.degree_mean == pytest.approx(10 / 6)
    assert facts.degree_median == 2.0
    assert (facts.num_odometry_edges, facts.num_loop_closures) == (3, 2)  # 40→50 parallels 50→40


def test_odometry_means_neighbours_in_id_order(graph):
    # Sorted ids 10 20 30 40 50 60: 10→20, 20→30, 50→40, 40→50 join neighbours; 30→10 skips 20.
    # 40→50 joins the pair 50→40 already joined: a loop-closure candidate, not odometry.
    assert graph.odometry_mask().tolist() == [True, True, False, True, False]


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_the_odometry_of_a_pair_is_its_first_edge_in_file_order(order):
    edges = [(0, 1), (1, 2), (2, 3)]
    duplicates = [(2, 1), (1, 2)]  # parallel to 1→2, one each way round
    g = make_graph([0, 1, 2, 3], [edges[0], duplicates[order[0]], edges[1], edges[2], duplicates[order[1]]])
    assert g.odometry_mask().tolist() == [True, True, False, True, False]


def test_odometry_with_consecutive_ids_is_unit_id_difference():
    g = make_graph([0, 1, 2, 3, 4], [(0, 1), (1, 2), (2, 3), (3, 4), (0, 3), (4, 2)])
    expected = [abs(i - j) == 1 for i, j in [(0, 1), (1, 2), (2, 3), (3, 4), (0, 3), (4, 2)]]
    assert g.odometry_mask().tolist() == expected


def test_odometry_across_a_missing_id():
    g = make_graph([0, 1, 3], [(0, 1), (1, 3), (0, 3)])
    assert g.odometry_mask().tolist() == [True, True, False]


def test_index_of(graph):
    assert graph.index_of([20, 60, 30]).tolist() == [2, 5, 0]
    assert graph.index_of(40) == 4
    assert graph.index_of(np.array([[10, 50]])).tolist() == [[1, 3]]
    np.testing.assert_array_equal(graph.ids[graph.index_of(IDS)], IDS)


def test_index_of_missing_ids(graph):
    with pytest.raises(KeyError, match="15"):
        graph.index_of([10, 15])
    with pytest.raises(KeyError):
        graph.index_of([70])  # beyond the largest id
    with pytest.raises(KeyError):
        graph.index_of([5])  # before the smallest id


def test_index_of_on_an_empty_graph():
    empty = make_graph([], [])
    assert empty.index_of([]).tolist() == []
    with pytest.raises(KeyError):
        empty.index_of([0])


def test_with_poses(graph):
    moved = graph.poses.copy()
    moved[:, 0, 3] = np.arange(6)
    other = graph.with_poses(moved)
    np.testing.assert_array_equal(other.poses, moved)
    assert other.ids is graph.ids and graph.poses[:, 0, 3].tolist() == [0.0] * 6
    with pytest.raises(ValueError, match="shape"):
        graph.with_poses(moved[:3])


def test_the_group_defaults_to_se3_and_travels_with_the_graph(graph):
    from posegraph.lie.group import SE3

    assert graph.group is SE3 and (graph.group.dim, graph.group.matrix_size) == (6, 4)
    assert graph.with_poses(graph.poses).group is SE3
