"""Spanning-tree (odometry) initialisation: exact on noise-free graphs, trees as documented."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import csgraph, csr_matrix

from posegraph.errors import GraphError
from posegraph.model.graph import PoseGraph
from posegraph.init import held_vertices, initialize, odometry_initialization, spanning_tree
from posegraph.init.weights import rotation_weights
from posegraph.lie import se3

from . import synthetic

TREES = ("bfs", "max_information")


GRAPHS = list(synthetic.noise_free_cases())


@pytest.mark.parametrize("tree", TREES)
@pytest.mark.parametrize("name, graph, truth", GRAPHS, ids=[g[0] for g in GRAPHS])
def test_noise_free_measurements_give_the_truth_in_the_gauge(name, graph, truth, tree):
    poses = odometry_initialization(graph, tree=tree)
    expected = synthetic.expected_poses(graph, truth)
    np.testing.assert_allclose(poses, expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("tree", TREES)
def test_held_vertices_keep_their_file_pose_bit_for_bit(tree):
    graph, _ = synthetic.hard_graph(4, noise=True)
    held = held_vertices(graph)
    assert held.sum() == 2 + 2  # two FIX vertices, plus the anchors of the two components without one
    poses = odometry_initialization(graph, tree=tree)
    assert np.array_equal(poses[held], graph.poses[held])
    assert not np.allclose(poses[~held], graph.poses[~held])


def _follow_to_root(parent: np.ndarray) -> np.ndarray:
    """Number of tree edges from each vertex to its root (fails the test on a cycle)."""
    depth = np.zeros(parent.size, dtype=int)
    for v in range(parent.size):
        u, steps = v, 0
        while parent[u] >= 0:
            u, steps = parent[u], steps + 1
            assert steps <= parent.size, "parent pointers form a cycle"
        depth[v] = steps
    return depth


@pytest.mark.parametrize("tree", TREES)
def test_spanning_tree_is_a_tree_of_real_edges_rooted_at_held_vertices(tree):
    graph, _ = synthetic.hard_graph(5)
    parent, parent_edge = spanning_tree(graph, tree)
    held = held_vertices(graph)
    assert np.all(parent[held] == -1) and np.all(parent_edge[held] == -1)
    child = np.flatnonzero(~held)
    assert np.all(parent[child] >= 0)
    ends = np.sort(np.stack([graph.edge_from[parent_edge[child]], graph.edge_to[parent_edge[child]]], 1), 1)
    np.testing.assert_array_equal(ends, np.sort(np.stack([child, parent[child]], 1), 1))
    _follow_to_root(parent)


def test_bfs_tree_reaches_each_vertex_in_the_fewest_edges():
    graph, _ = synthetic.hard_graph(6)
    parent, _ = spanning_tree(graph, "bfs")
    held = held_vertices(graph)
    n = graph.num_vertices
    adjacency = csr_matrix((np.ones(graph.num_edges), (graph.edge_from, graph.edge_to)), shape=(n, n))
    hops = csgraph.shortest_path(adjacency, directed=False, unweighted=True, indices=np.flatnonzero(held)).min(0)
    np.testing.assert_array_equal(_follow_to_root(parent), hops)


def _maximum_forest_weight(graph: PoseGraph, weights: np.ndarray) -> float:
    """Kruskal by hand: held vertices start merged (they share the virtual root)."""
    held = held_vertices(graph)
    root = {v: (-1 if held[v] else v) for v in range(graph.num_vertices)}

    def find(v):
        while root[v] != v and root[v] != -1:
            v = root[v]
        return root[v]

    total = 0.0
    for e in np.argsort(-weights, kind="stable"):
        a, b = find(graph.edge_from[e]), find(graph.edge_to[e])
        if a != b:
            if a == -1:
                a, b = b, a
            root[a] = b
            total += weights[e]
    return total


def test_max_information_tree_has_the_largest_total_weight():
    graph, _ = synthetic.hard_graph(7)
    weights = rotation_weights(graph.information)
    _, parent_edge = spanning_tree(graph, "max_information")
    tree_weight = weights[parent_edge[parent_edge >= 0]].sum()
    assert tree_weight == pytest.approx(_maximum_forest_weight(graph, weights), rel=1e-12)
    _, bfs_edge = spanning_tree(graph, "bfs")
    assert weights[bfs_edge[bfs_edge >= 0]].sum() < tree_weight  # the two trees do differ here


@pytest.mark.parametrize("tree", TREES)
def test_duplicate_edges_use_the_stronger_measurement(tree):
    rng = np.random.default_rng(8)
    truth = synthetic.trajectory(rng, 5)
    edge_from, edge_to = np.array([0, 1, 2, 3, 3]), np.array([1, 2, 3, 4, 4])
    information = synthetic.information_matrices(rng, 5, 10.0, 100.0)
    information[3] *= 1e-3  # edge 3 is weak: its measurement is garbage
    graph = synthetic.build_graph(truth, edge_from, edge_to, information, rng=rng)
    measurements = graph.measurements.copy()
    measurements[3] = measurements[3] @ se3.exp(np.full(6, 0.5))
    graph = PoseGraph(graph.ids, graph.poses, edge_from, edge_to, measurements, information, graph.fixed)
    _, parent_edge = spanning_tree(graph, tree)
    assert parent_edge[4] == 4
    np.testing.assert_allclose(odometry_initialization(graph, tree), synthetic.expected_poses(graph, truth), atol=1e-12)


def test_long_chain_matches_sequential_composition():
    # Depth 1500 takes ⌈log₂ 1500⌉ = 11 pointer-jumping passes; compare with composing in order.
    rng = np.random.default_rng(9)
    truth = synthetic.trajectory(rng, 1500, step=0.2, turn=0.05)
    edge_from, edge_to = np.arange(1499), np.arange(1, 1500)
    graph = synthetic.build_graph(truth, edge_from, edge_to, synthetic.information_matrices(rng, 1499), rng=rng)
    sequential = np.empty_like(truth)
    sequential[0] = graph.poses[0]
    for k in range(1, 1500):
        sequential[k] = sequential[k - 1] @ graph.measurements[k - 1]
    np.testing.assert_allclose(odometry_initialization(graph), sequential, rtol=0, atol=1e-10)


def test_vertices_without_edges_keep_their_file_pose():
    rng = np.random.default_rng(10)
    poses = synthetic.trajectory(rng, 3)
    graph = PoseGraph(
        ids=np.array([4, 2, 9]),
        poses=poses,
        edge_from=np.zeros(0, dtype=np.int64),
        edge_to=np.zeros(0, dtype=np.int64),
        measurements=np.zeros((0, 4, 4)),
        information=np.zeros((0, 6, 6)),
    )
    for tree in TREES:
        assert np.array_equal(odometry_initialization(graph, tree), poses)
    assert np.array_equal(initialize(graph, "chordal"), poses)


def test_unknown_tree_is_refused():
    graph, _ = synthetic.noise_free_graph(0, n=5, loops=1)
    with pytest.raises(ValueError, match="tree must be one of"):
        odometry_initialization(graph, tree="dfs")


@pytest.mark.parametrize("field", ["measurements", "information"])
def test_non_finite_numbers_name_the_edge(field):
    graph, _ = synthetic.noise_free_graph(0, n=6, loops=1)
    values = getattr(graph, field).copy()
    values[2, 1, 1] = np.nan
    arrays = {f: getattr(graph, f) for f in ("ids", "poses", "edge_from", "edge_to", "measurements", "information")}
    arrays[field] = values
    broken = PoseGraph(**arrays, source="broken.g2o")
    with pytest.raises(GraphError, match=r"broken\.g2o: edge 2 \(2 -> 3\) has a non-finite value"):
        odometry_initialization(broken)
