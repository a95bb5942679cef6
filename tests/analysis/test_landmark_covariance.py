"""Covariances of landmark graphs: the padded H against the solver's, poses' and landmarks' marginals
against dense inversion and gtsam.Marginals (2D and 3D), FIX landmarks and held poses at zero."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.analysis import covariance as cv
from posegraph.lie.group import SE2, SE3
from posegraph.model.graph import held_vertices
from posegraph.solve import optimize
from posegraph.solve.landmark_terms import point_variables
from posegraph.solve.sparsity import analyze_pattern

SIGMA = 1e-9
"""σ of gtsam's priors standing for our held vertices and FIX landmarks: they add σ² of variance there,
which moves the others by ~σ²/variance relative (σ² scaling: ``tests/analysis/test_covariance.py``),
1e-14 here against the 1e-8 asked; at 1e-6 the gap was 1e-8–1e-7."""

CASES = [
    (SE2, ("position", "bearing_range"), False),
    (SE2, ("position", "bearing", "bearing_range", "prior"), True),  # point priors: no pose anchor at all
    (SE3, ("position",), True),
]


def solved(group, kinds, offsets, fixed_landmark=False):
    graph, _, _ = landmark_graph(group, 12, 8, kinds, noise=0.05, seed=3, offsets=offsets)
    if fixed_landmark:
        fixed = np.zeros(graph.landmarks.count, dtype=bool)
        fixed[2] = True
        # a FIX landmark anchors its component (posegraph.model.landmarks), but one point leaves the
        # rotation free: FIX pose 5 too (then no anchor is chosen and pose 0 is free)
        pose_fixed = np.zeros(graph.num_vertices, dtype=bool)
        pose_fixed[5] = True
        graph = replace(graph, fixed=pose_fixed, landmarks=replace(graph.landmarks, fixed=fixed))
    result = optimize(graph, initial="file")
    return graph, result.poses, result.points


def dense_mixed_inverse(graph, poses, points):
    """``(H⁻¹, pattern)`` of the solver's own mixed-block H (poses ``d``, landmarks ``s``) by dense inversion."""
    pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held_vertices(graph), graph.group.dim,
                              point_variables(graph))  # fmt: skip
    data = cv._solver_hessian(graph, pattern, poses, points)
    size = pattern.dimension
    lower = np.zeros((size, size))
    lower[pattern.indices, np.repeat(np.arange(size), np.diff(pattern.indptr))] = data
    return np.linalg.inv(lower + np.tril(lower, -1).T), pattern


def dense_marginals(graph, poses, points):
    """``(pose blocks (n, d, d), landmark blocks (L, s, s))`` of the mixed H's dense inverse, zero where held."""
    inverse, pattern = dense_mixed_inverse(graph, poses, points)
    d, s = graph.group.dim, graph.landmarks.space_dim
    P = np.zeros((graph.num_vertices, d, d))
    for k, c in enumerate(pattern.variable_of):
        if c >= 0:
            P[k] = inverse[d * c : d * c + d, d * c : d * c + d]
    L = np.zeros((graph.landmarks.count, s, s))
    for l, c in enumerate(pattern.point_variable_of):
        if c >= 0:
            row = pattern.pose_dimension + s * (c - pattern.num_pose_variables)
            L[l] = inverse[row : row + s, row : row + s]
    return P, L


def gtsam_marginals(graph, poses, points, sigma=SIGMA):
    """gtsam's marginals of :func:`gtsam_landmark_graph` with σ priors on our held vertices and FIX landmarks."""
    gtsam = pytest.importorskip("gtsam")
    from posegraph.crosscheck.gtsam_bridge import _element, _factor_class
    from posegraph.crosscheck.gtsam_landmarks import gtsam_landmark_graph, landmark_key

    factors, values = gtsam_landmark_graph(graph, poses, points)
    prior = _factor_class(gtsam, graph, "Prior")
    noise = gtsam.noiseModel.Isotropic.Sigma(graph.group.dim, sigma)
    for k in np.flatnonzero(held_vertices(graph)).tolist():
        factors.add(prior(int(graph.ids[k]), _element(gtsam, poses[k], graph.group), noise))
    s = graph.landmarks.space_dim
    point_prior = gtsam.PriorFactorPoint2 if s == 2 else gtsam.PriorFactorPoint3
    for l in np.flatnonzero(graph.landmarks.fixed).tolist():
        factors.add(point_prior(landmark_key(l), points[l].copy(), gtsam.noiseModel.Isotropic.Sigma(s, sigma)))
    marginals = gtsam.Marginals(factors, values)
    P = np.stack([marginals.marginalCovariance(int(key)) for key in graph.ids])
    L = np.stack([marginals.marginalCovariance(landmark_key(l)) for l in range(graph.landmarks.count)])
    return P, L


def relative_block_error(ours, theirs) -> np.ndarray:
    return np.linalg.norm(ours - theirs, axis=(1, 2)) / np.linalg.norm(theirs, axis=(1, 2))


@pytest.mark.parametrize("group, kinds, offsets", CASES)
def test_padded_hessian_inverts_to_the_solvers(group, kinds, offsets):
    graph, poses, points = solved(group, kinds, offsets, fixed_landmark=True)
    pattern, data = cv.hessian_at(graph, poses, points)
    d, n = graph.group.dim, graph.num_vertices
    assert pattern.block_size == d and pattern.num_vertices == n + graph.landmarks.count
    assert pattern.variable_of[n + 2] == -1  # the FIX landmark has no variable
    P, L = dense_marginals(graph, poses, points)
    ours_p = cv.marginal_covariances(graph, poses, points=points)
    ours_l = cv.landmark_covariances(graph, poses, points)
    free_p, free_l = ~held_vertices(graph), ~graph.landmarks.fixed
    assert relative_block_error(ours_p[free_p], P[free_p]).max() < 1e-10
    assert relative_block_error(ours_l[free_l], L[free_l]).max() < 1e-10
    assert np.all(ours_p[~free_p] == 0.0) and np.all(ours_l[~free_l] == 0.0)


@pytest.mark.parametrize("group, kinds, offsets", CASES)
@pytest.mark.parametrize("fixed_landmark", [False, True])
def test_marginals_match_gtsam(group, kinds, offsets, fixed_landmark):
    graph, poses, points = solved(group, kinds, offsets, fixed_landmark)
    ours_p = cv.marginal_covariances(graph, poses, points=points)
    ours_l = cv.landmark_covariances(graph, poses, points)
    s = graph.landmarks.space_dim
    assert ours_p.shape == (graph.num_vertices, graph.group.dim, graph.group.dim)
    assert ours_l.shape == (graph.landmarks.count, s, s)
    theirs_p, theirs_l = gtsam_marginals(graph, poses, points)
    free_p, free_l = ~held_vertices(graph), ~graph.landmarks.fixed
    assert relative_block_error(ours_p[free_p], theirs_p[free_p]).max() < 1e-8
    assert relative_block_error(ours_l[free_l], theirs_l[free_l]).max() < 1e-8
    assert np.all(ours_p[~free_p] == 0.0) and np.all(ours_l[~free_l] == 0.0)


def test_landmarks_change_the_poses_covariances():
    """The poses' marginals account for the landmarks: tighter than the odometry chain's alone."""
    graph, poses, points = solved(SE2, ("position", "bearing_range"), False)
    with_landmarks = cv.marginal_covariances(graph, poses, points=points)
    chain = cv.marginal_covariances(replace(graph, landmarks=None), poses)
    last = graph.num_vertices - 1
    assert np.trace(with_landmarks[last]) < 0.5 * np.trace(chain[last])


def test_subsets_joint_and_bad_indices():
    graph, poses, points = solved(SE3, ("position",), True)
    every = cv.landmark_covariances(graph, poses, points)
    some = cv.landmark_covariances(graph, poses, points, np.array([5, 1]))
    np.testing.assert_allclose(some, every[[5, 1]], rtol=1e-12, atol=0)
    assert cv.landmark_covariances(graph, poses, points, np.zeros(0, dtype=int)).shape == (0, 3, 3)
    vertices = np.array([0, 11, 4])
    joint = cv.joint_covariance(graph, poses, vertices, points=points)
    inverse, pattern = dense_mixed_inverse(graph, poses, points)
    d = graph.group.dim
    rows = [np.arange(d * c, d * c + d) if c >= 0 else None for c in pattern.variable_of[vertices]]
    for a, ra in enumerate(rows):
        for b, rb in enumerate(rows):
            block = joint[d * a : d * a + d, d * b : d * b + d]
            reference = np.zeros((d, d)) if ra is None or rb is None else inverse[np.ix_(ra, rb)]
            np.testing.assert_allclose(block, reference, rtol=0, atol=1e-10 * np.abs(inverse).max())
    with pytest.raises(IndexError, match="landmark indices"):
        cv.landmark_covariances(graph, poses, points, [graph.landmarks.count])
    with pytest.raises(ValueError, match="no landmarks"):
        cv.landmark_covariances(replace(graph, landmarks=None), poses)


def test_a_landmark_graph_needs_its_points_or_the_result():
    """Poses without points would linearise at the file's positions (other covariances, silently): refused;
    the result itself gives both."""
    graph, _, _ = landmark_graph(SE2, 12, 8, ("position", "bearing_range"), noise=0.05, seed=3)
    result = optimize(graph)
    for call in (lambda: cv.landmark_covariances(graph, result.poses),
                 lambda: cv.marginal_covariances(graph, result.poses),
                 lambda: cv.joint_covariance(graph, result.poses, [1, 2])):
        with pytest.raises(ValueError, match=r"solved points .* pass the result"):
            call()
    np.testing.assert_array_equal(cv.landmark_covariances(graph, result), cv.landmark_covariances(graph, result.poses, result.points))
    np.testing.assert_array_equal(cv.marginal_covariances(graph, result), cv.marginal_covariances(graph, result.poses, points=result.points))
    np.testing.assert_array_equal(cv.joint_covariance(graph, result, [1, 2]),
                                  cv.joint_covariance(graph, result.poses, [1, 2], points=result.points))
    at_file = cv.landmark_covariances(graph, result.poses, graph.landmarks.positions)  # asked for explicitly
    assert relative_block_error(at_file, cv.landmark_covariances(graph, result)).max() > 1e-3
