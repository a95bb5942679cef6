"""The Riemannian staircase: from a local minimum to the certified global one; SE-Sync's rounding."""

from __future__ import annotations

import numpy as np

from posegraph.certification.certificate import certify
from posegraph.certification.local import refine_poses, translations_given_rotations
from posegraph.certification.problem import objective, sync_problem
from posegraph.certification.staircase import riemannian_staircase, round_solution
from posegraph.certification.verify import Budget, data_scale, verify_point
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
    rank-3 test rejects; the staircase escapes it, and its rounding, refined, is the certified optimum."""
    graph, _ = loop_graph(3, n=40, loops=40, rotation_noise=0.2, translation_noise=0.3, group=SE3)
    optimum = certify(graph)
    assert optimum.certified
    problem = sync_problem(graph)
    u, value = _local_minimum(problem, optimum.sesync_objective, np.random.default_rng(3))
    budget = Budget(1e-6, data_scale(problem))
    check = verify_point(problem, u, value, budget)
    assert not check.positive_semidefinite and check.min_eigenvalue < 0
    assert check.lower_bound < optimum.sesync_objective  # a valid, if weak, bound even at a local minimum
    found = riemannian_staircase(problem, u, check, budget)
    assert found.rank > 3 and found.best_value < value
    assert abs(found.best_value - optimum.sesync_objective) <= 1e-6 * optimum.sesync_objective
    assert found.best_value - found.lower_bound <= budget.allowed(found.best_value)
    assert found.lower_bound <= optimum.sesync_objective


def test_staircase_never_returns_worse_than_its_start():
    """2 rad of rotation noise on 10 poses (the relaxation is not tight): whatever the levels' roundings
    give, the estimate returned is at most the start's F, and the bound below it."""
    graph, _ = loop_graph(1, n=10, loops=10, rotation_noise=2.0, translation_noise=0.5, group=SE3)
    problem = sync_problem(graph)
    start, value, _ = refine_poses(problem, np.concatenate([graph.poses[:, :3, 3:], graph.poses[:, :3, :3]], axis=2))
    budget = Budget(1e-6, data_scale(problem))
    check = verify_point(problem, start, value, budget)
    found = riemannian_staircase(problem, start, check, budget)
    assert found.best_value <= value
    assert found.lower_bound <= found.best_value
    assert all(level[3] <= found.lower_bound for level in found.levels)


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
    assert abs(objective(problem, rounded) - value) <= 1e-9 * value
