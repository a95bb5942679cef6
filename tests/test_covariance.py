"""Marginal and joint covariances: against dense inversion of H, against gtsam.Marginals, and the
selected inversion itself on random block matrices, orderings and both factor routes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import posegraph
from datasets.synthetic import sphere
from posegraph import covariance as cv
from posegraph.graph import PoseGraph, held_vertices

D = 6


def two_components() -> PoseGraph:
    """Two disjoint spheres; the first holds two FIX vertices, the second is anchored at its first vertex."""
    a = sphere(rings=4, nodes_per_ring=6, seed=3).graph
    b = sphere(rings=3, nodes_per_ring=5, seed=4).graph
    n = a.num_vertices
    fixed = np.zeros(n + b.num_vertices, dtype=bool)
    fixed[[3, 10]] = True
    return PoseGraph(
        ids=np.concatenate((a.ids, b.ids + 1000)),
        poses=np.concatenate((a.poses, b.poses)),
        edge_from=np.concatenate((a.edge_from, b.edge_from + n)),
        edge_to=np.concatenate((a.edge_to, b.edge_to + n)),
        measurements=np.concatenate((a.measurements, b.measurements)),
        information=np.concatenate((a.information, b.information)),
        fixed=fixed,
    )


def dense_covariance(graph, poses) -> np.ndarray:
    """``(n·6, n·6)`` ``H⁻¹`` by dense inversion, zero rows and columns for held vertices."""
    pattern, data = cv.hessian_at(graph, poses)
    size = pattern.dimension
    lower = np.zeros((size, size))
    columns = np.repeat(np.arange(size), np.diff(pattern.indptr))
    lower[pattern.indices, columns] = data
    H = lower + np.tril(lower, -1).T
    free = np.flatnonzero(pattern.variable_of >= 0)
    scalar = (D * free[:, None] + np.arange(D)).ravel()
    variables = (D * pattern.variable_of[free][:, None] + np.arange(D)).ravel()
    full = np.zeros((graph.num_vertices * D,) * 2)
    full[np.ix_(scalar, scalar)] = np.linalg.inv(H)[np.ix_(variables, variables)]
    return full


def diagonal_blocks(full: np.ndarray) -> np.ndarray:
    n = full.shape[0] // D
    return full.reshape(n, D, n, D)[np.arange(n), :, np.arange(n), :]


def relative_block_error(ours: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per block ``max|ours − ref| / max|ref|``."""
    return np.abs(ours - reference).max(axis=(-2, -1)) / np.abs(reference).max(axis=(-2, -1))


@pytest.fixture(params=["tinyGrid3D", "smallGrid3D"])
def small_graph(request, shared_dataset):
    return posegraph.read_g2o(shared_dataset(request.param))


def test_marginals_match_dense_inverse(small_graph):
    poses = posegraph.optimize(small_graph).poses
    covariances = cv.marginal_covariances(small_graph, poses)
    reference = diagonal_blocks(dense_covariance(small_graph, poses))
    held = held_vertices(small_graph)
    assert covariances.shape == (small_graph.num_vertices, D, D)
    assert np.all(covariances[held] == 0.0)
    assert relative_block_error(covariances[~held], reference[~held]).max() < 1e-10
    assert np.allclose(covariances, np.swapaxes(covariances, -1, -2), rtol=0, atol=0)
    assert np.all(np.linalg.eigvalsh(covariances[~held]) > 0)


def test_fixed_vertices_and_two_components_match_dense_inverse():
    graph = two_components()
    held = held_vertices(graph)
    assert held.sum() == 3  # two FIX in the first sphere, the anchor of the second
    covariances = cv.marginal_covariances(graph, graph.poses)
    reference = diagonal_blocks(dense_covariance(graph, graph.poses))
    assert np.all(covariances[held] == 0.0)
    assert relative_block_error(covariances[~held], reference[~held]).max() < 1e-10


def test_subset_of_vertices_equals_the_full_run():
    graph = two_components()
    everything = cv.marginal_covariances(graph, graph.poses)
    chosen = np.array([30, 0, 3, 7, 7])  # out of order, a repeat, a FIX vertex
    np.testing.assert_allclose(cv.marginal_covariances(graph, graph.poses, chosen), everything[chosen], rtol=1e-12, atol=0)
    assert cv.marginal_covariances(graph, graph.poses, np.zeros(0, dtype=int)).shape == (0, D, D)


def test_bad_vertex_indices_raise():
    graph = two_components()
    with pytest.raises(IndexError, match="vertex indices"):
        cv.marginal_covariances(graph, graph.poses, [0, graph.num_vertices])
    with pytest.raises(ValueError, match="vertex indices"):
        cv.marginal_covariances(graph, graph.poses, [0.5])


def gtsam_marginals(graph, poses, sigma: float = 1e-6) -> np.ndarray:
    """gtsam's marginals with a ``PriorFactorPose3`` of σ = ``sigma`` on each held vertex."""
    gtsam = pytest.importorskip("gtsam")
    from posegraph.gtsam_bridge import graph_to_gtsam, poses_to_values

    factors = graph_to_gtsam(graph)
    noise = gtsam.noiseModel.Isotropic.Sigma(D, sigma)
    for k in np.flatnonzero(held_vertices(graph)).tolist():
        factors.add(gtsam.PriorFactorPose3(int(graph.ids[k]), gtsam.Pose3(poses[k]), noise))
    marginals = gtsam.Marginals(factors, poses_to_values(graph.ids, poses))
    return np.stack([marginals.marginalCovariance(int(key)) for key in graph.ids])


@pytest.mark.parametrize("name", ["tinyGrid3D", "smallGrid3D", "parking-garage"])
def test_marginals_match_gtsam(name, shared_dataset):
    graph = posegraph.read_g2o(shared_dataset(name))
    poses = posegraph.optimize(graph).poses
    ours = cv.marginal_covariances(graph, poses)
    theirs = gtsam_marginals(graph, poses)
    held = held_vertices(graph)
    assert relative_block_error(ours[~held], theirs[~held]).max() < 1e-6
    # gtsam's held vertices carry the prior's σ² = 1e-12; ours are exactly zero
    assert np.all(ours[held] == 0.0) and np.abs(theirs[held]).max() < 1.1e-12


def test_fixed_vertices_and_two_components_match_gtsam_as_the_prior_tightens():
    """Next to the FIX vertices the poses' variances are ~1e-7, so a σ = 1e-6 prior (variance 1e-12)
    still moves them by ~1e-5 relative; the difference shrinks as σ², the limit being ours."""
    graph = two_components()
    poses = posegraph.optimize(graph).poses
    ours = cv.marginal_covariances(graph, poses)
    held = held_vertices(graph)
    loose = relative_block_error(ours[~held], gtsam_marginals(graph, poses, 1e-6)[~held]).max()
    tight = relative_block_error(ours[~held], gtsam_marginals(graph, poses, 1e-8)[~held]).max()
    assert tight < 1e-6
    assert loose / tight > 1e3  # σ² scaling: the gap is the prior's, not ours


def joint_reference(full: np.ndarray, vertices) -> np.ndarray:
    scalar = (D * np.asarray(vertices)[:, None] + np.arange(D)).ravel()
    return full[np.ix_(scalar, scalar)]


def test_joint_covariance_by_solves_matches_dense_inverse():
    graph = two_components()
    vertices = np.array([5, 30, 3, 35, 5])  # both components, a FIX vertex, a repeat
    joint = cv.joint_covariance(graph, graph.poses, vertices)
    reference = joint_reference(dense_covariance(graph, graph.poses), vertices)
    assert joint.shape == (5 * D, 5 * D)
    np.testing.assert_allclose(joint, reference, rtol=0, atol=1e-10 * np.abs(reference).max())
    assert np.all(joint[2 * D : 3 * D] == 0.0) and np.all(joint[:, 2 * D : 3 * D] == 0.0)
    # the two components are independent
    assert np.all(np.abs(joint[:D, 3 * D : 4 * D]) < 1e-12 * np.abs(reference).max())


def test_joint_covariance_within_the_pattern_uses_the_selected_inverse(monkeypatch):
    graph = two_components()
    setup = cv._factorise(graph, graph.poses)
    parent = setup.factor.parents()
    column = int(np.flatnonzero(parent >= 0)[0])
    by_position = np.full(setup.position.max() + 1, -1)
    free = setup.position >= 0
    by_position[setup.position[free]] = np.flatnonzero(free)
    vertices = np.array([by_position[parent[column]], by_position[column]])
    monkeypatch.setattr(cv, "_solve_columns", lambda *args: pytest.fail("solved although the blocks are in the pattern"))
    joint = cv.joint_covariance(graph, graph.poses, vertices)
    reference = joint_reference(dense_covariance(graph, graph.poses), vertices)
    np.testing.assert_allclose(joint, reference, rtol=0, atol=1e-10 * np.abs(reference).max())


def random_block_matrix(rng, p: int, d: int, edges: int):
    """Lower CSC ``(indptr, indices, data)`` of an SPD matrix with ``d×d`` blocks on a random vertex graph."""
    dense = np.zeros((p * d, p * d))
    pairs = rng.integers(0, p, size=(edges, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    for i, j in pairs:
        J = rng.standard_normal((d, 2 * d))
        index = np.concatenate((np.arange(i * d, i * d + d), np.arange(j * d, j * d + d)))
        dense[np.ix_(index, index)] += J.T @ J
    dense += np.eye(p * d) * 0.5
    blocks = np.abs(dense.reshape(p, d, p, d)).sum(axis=(1, 3)) > 0
    mask = np.kron(blocks, np.ones((d, d), dtype=bool)) & np.tri(p * d, dtype=bool)
    cols, rows = np.nonzero(mask.T)  # sorted by column, then row
    indptr = np.concatenate(([0], np.cumsum(np.bincount(cols, minlength=p * d))))
    return (indptr, rows, dense[rows, cols]), dense


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), p=st.integers(1, 24), d=st.sampled_from([3, 6]), route=st.sampled_from(["cvxopt", "superlu"]))
def test_selected_inverse_on_random_patterns_and_orderings(seed, p, d, route):
    rng = np.random.default_rng(seed)
    lower, dense = random_block_matrix(rng, p, d, edges=int(rng.integers(0, 3 * p + 1)))
    order = rng.permutation(p)
    permutation = (d * order[:, None] + np.arange(d)).ravel()
    if route == "cvxopt":
        pytest.importorskip("cvxopt")
        L, _ = cv.cholesky_factor(lower, permutation)
    else:
        L = cv._superlu_cholesky(lower, permutation)
    factor = cv.block_factor(L, d)
    sigma = cv.selected_inverse(factor)
    inverse = np.linalg.inv(dense[np.ix_(permutation, permutation)]).reshape(p, d, p, d)
    reference = inverse[factor.rows, :, factor.columns, :]
    np.testing.assert_allclose(sigma, reference, rtol=0, atol=1e-9 * np.abs(inverse).max())
    # only ancestors of the requested columns: their diagonal blocks are right all the same
    wanted = rng.integers(0, p, size=2)
    partial = cv.selected_inverse(factor, wanted)
    np.testing.assert_allclose(partial[factor.indptr[wanted]], sigma[factor.indptr[wanted]], rtol=0, atol=1e-12 * np.abs(inverse).max())


def test_both_factor_routes_give_the_same_factor(shared_dataset):
    pytest.importorskip("cvxopt")
    graph = posegraph.read_g2o(shared_dataset("smallGrid3D"))
    pattern, data = cv.hessian_at(graph, graph.poses)
    from posegraph.cholmod import block_permutation

    permutation = block_permutation(cv.vertex_elimination_order(pattern), D)
    lower = (pattern.indptr, pattern.indices, data)
    a = cv.block_factor(cv.cholesky_factor(lower, permutation)[0], D)
    b = cv.block_factor(cv._superlu_cholesky(lower, permutation), D)
    in_b = b.find(a.rows, a.columns)
    assert np.all(np.abs(a.values[in_b < 0]) == 0)  # blocks only CHOLMOD stores are explicit zeros
    np.testing.assert_allclose(a.values[in_b >= 0], b.values[in_b[in_b >= 0]], rtol=0, atol=1e-9 * np.abs(b.values).max())


def test_not_positive_definite_raises():
    from posegraph.cholmod import NotPositiveDefiniteError

    indptr, indices, data = np.array([0, 2, 3]), np.array([0, 1, 1]), np.array([1.0, 2.0, 1.0])
    for factorise in (cv.cholesky_factor, cv._superlu_cholesky):
        with pytest.raises(NotPositiveDefiniteError):
            factorise((indptr, indices, data), np.array([0, 1]))


def test_poses_of_the_wrong_shape_raise():
    graph = two_components()
    with pytest.raises(ValueError, match="poses must have shape"):
        cv.marginal_covariances(graph, graph.poses[:-1])
