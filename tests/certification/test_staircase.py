"""The Riemannian staircase: from a local minimum to the certified global one; SE-Sync's rounding."""

from __future__ import annotations

import numpy as np

from posegraph.certification.certificate import certify
from posegraph.certification.local import refine_poses, translations_given_rotations
from posegraph.certification.problem import objective, sync_problem
from posegraph.certification.staircase import riemannian_staircase, round_solution
from posegraph.certification.verify import DEFAULT_ETA, certificate_matrix, lambda_blocks, verify
from posegraph.lie.group import SE3
from tests.certification.graphs import loop_graph
from tests.init.synthetic import random_rotations


def _local_minimum(problem, global_value, rng, attempts=10):
    """A rank-3 critical point from random rotations whose F is above the global minimum."""
    n = problem.num_poses
    for _ in range(attempts):
        rotations = random_rotations(rng, n)
        u = np.concatenate([translations_given_rotations(problem, rotations)[:, :, None], rotations], axis=2)
        u, value, _ = refine_poses(problem, u)
        if value > global_value * (1 + 1e-6):
            return u, value
    raise AssertionError("no local minimum found")


def test_staircase_climbs_from_a_local_minimum_to_the_certified_optimum():
    """0.2 rad noise, 40 poses: a random start ends in a local minimum (F 34 % too high) that the
    rank-3 test rejects; the staircase escapes it and certifies the global optimum at rank > 3."""
    graph, _ = loop_graph(3, n=40, loops=40, rotation_noise=0.2, translation_noise=0.3, group=SE3)
    optimum = certify(graph)
    assert optimum.certified
    problem = sync_problem(graph)
    u, value = _local_minimum(problem, optimum.sesync_objective, np.random.default_rng(3))
    check = verify(certificate_matrix(problem, lambda_blocks(problem, u)), u, DEFAULT_ETA)
    assert not check.positive_semidefinite and check.min_eigenvalue < -DEFAULT_ETA
    found = riemannian_staircase(problem, u, check, DEFAULT_ETA)
    assert found.verification.positive_semidefinite and found.rank > 3
    assert found.objective < value
    assert abs(found.objective - optimum.sesync_objective) <= 1e-6 * optimum.sesync_objective
    dual = np.trace(found.lambdas, axis1=1, axis2=2).sum()
    assert abs(found.objective - dual) <= 1e-6 * found.objective


def test_rounding_of_a_rank_d_point_is_the_point():
    """Rounding a rank-d Y = R (rotated by any orthogonal matrix, one block a reflection away) gives R back
    up to a global rotation, with the same F."""
    graph, _ = loop_graph(5, n=8, loops=6, rotation_noise=0.1, translation_noise=0.1, group=SE3)
    problem = sync_problem(graph)
    u, value, _ = refine_poses(problem, np.concatenate([graph.poses[:, :3, 3:], graph.poses[:, :3, :3]], axis=2))
    lifted = np.concatenate([u, np.zeros((8, 2, 4))], axis=1)
    mixing, _ = np.linalg.qr(np.random.default_rng(0).normal(size=(5, 5)))
    rounded = round_solution(problem, mixing @ lifted)
    assert np.allclose(np.linalg.det(rounded[:, :, 1:]), 1.0)
    assert objective(problem, rounded) == np.float64(objective(problem, rounded))
    assert abs(objective(problem, rounded) - value) <= 1e-9 * value
