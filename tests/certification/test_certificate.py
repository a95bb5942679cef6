"""``certify``: exact graphs certify with bound ~0, wrong poses and non-tight relaxations never do."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import posegraph
from posegraph.certification.certificate import certify
from posegraph.certification.local import refine_poses, translations_given_rotations
from posegraph.certification.problem import sync_problem
from posegraph.certification.verify import data_scale
from posegraph.lie.group import SE2, SE3
from tests.certification.graphs import loop_graph
from tests.init.synthetic import expected_poses, random_rotations

GROUPS = pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])


@GROUPS
def test_exact_graph_certifies_with_zero_bound(group):
    graph, truth = loop_graph(11, n=20, loops=12, group=group)
    certificate = posegraph.certify(graph)
    assert certificate.certified and certificate.status == "certified"
    assert certificate.rank == group.space_dim
    scale = data_scale(sync_problem(graph))  # F's size: the bound is round-off of it
    assert abs(certificate.sesync_objective) < 1e-25 * scale and 0 <= certificate.suboptimality_bound <= 1e-12 * scale
    np.testing.assert_allclose(certificate.poses, expected_poses(graph, truth), atol=1e-7)
    assert set(certificate.seconds) == {"candidate", "refine", "verify"}


@GROUPS
def test_low_noise_graph_certifies_at_rank_d(group):
    graph, _ = loop_graph(12, n=30, loops=20, rotation_noise=0.05, translation_noise=0.1, group=group)
    certificate = certify(graph)
    assert certificate.certified and certificate.rank == group.space_dim
    assert certificate.sesync_objective > 0.1
    assert abs(certificate.suboptimality_bound) <= 1e-9 * certificate.sesync_objective
    assert abs(certificate.min_eigenvalue) < 1e-8
    again = certify(graph, poses=certificate.poses)  # the returned poses certify as given
    assert again.certified
    assert again.sesync_objective == pytest.approx(certificate.sesync_objective, rel=1e-9)


@GROUPS
def test_perturbed_estimate_is_not_certified(group):
    graph, _ = loop_graph(12, n=30, loops=20, rotation_noise=0.05, translation_noise=0.1, group=group)
    optimum = certify(graph)
    moved = optimum.poses.copy()
    moved[7] = moved[7] @ group.exp(np.r_[np.full(group.dim - 1, 0.0), 0.2] if group is SE2 else np.r_[0.2, 0, 0, 0, 0, 0])
    certificate = certify(graph, poses=moved)
    assert not certificate.certified
    assert certificate.min_eigenvalue < 0 and certificate.proven_min_eigenvalue < certificate.min_eigenvalue
    assert certificate.sesync_objective > optimum.sesync_objective
    assert certificate.lower_bound <= optimum.sesync_objective  # a proven bound, wherever it is read
    assert certificate.status.startswith("not certified: Q − Λ has a negative eigenvalue")


@pytest.mark.parametrize("group, seed", [(SE2, 0), (SE3, 1)], ids=["SE2", "SE3"])
def test_relaxation_not_tight_is_not_certified(group, seed):
    """2 rad of rotation noise on 10 poses: the staircase reaches a PSD certificate at rank > d, whose
    rounding loses — reported as not certified, with the (positive) bound."""
    graph, _ = loop_graph(seed, n=10, loops=10, rotation_noise=2.0, translation_noise=0.5, group=group)
    certificate = certify(graph)
    assert not certificate.certified
    assert certificate.rank > group.space_dim
    assert certificate.suboptimality_bound > 1e-3 * certificate.sesync_objective
    assert "not tight" in certificate.status or "negative eigenvalue" in certificate.status
    assert "staircase" in certificate.seconds


def _random_start_minimum(problem, rng, group):
    """A local minimiser of F from uniformly random rotations."""
    n = problem.num_poses
    rotations = random_rotations(rng, n) if group is SE3 else SE2.rotations.exp(rng.uniform(-np.pi, np.pi, (n, 1)))
    u = np.concatenate([translations_given_rotations(problem, rotations)[:, :, None], rotations], axis=2)
    return refine_poses(problem, u)[1]


@pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])
@pytest.mark.parametrize("seed", range(3))
def test_never_a_false_yes(group, seed):
    """Whenever a noisy graph is certified, no local minimum from 15 random starts is lower."""
    graph, _ = loop_graph(seed, n=10, loops=10, rotation_noise=1.0, translation_noise=0.5, group=group)
    certificate = certify(graph)
    if not certificate.certified:
        assert certificate.suboptimality_bound > certificate.eta * certificate.sesync_objective
        return
    problem, rng = sync_problem(graph), np.random.default_rng(seed)
    lowest = min(_random_start_minimum(problem, rng, group) for _ in range(15))
    assert lowest >= certificate.sesync_objective * (1 - 1e-9)


def test_output_gauge_keeps_the_first_fixed_vertex():
    """FIX plays no part in SE-Sync's problem; the estimate is moved rigidly to keep the first FIX pose."""
    import dataclasses

    graph, truth = loop_graph(13, n=15, loops=8, group=SE3)
    fixed = np.zeros(15, dtype=bool)
    fixed[[5, 9]] = True
    certificate = certify(dataclasses.replace(graph, fixed=fixed))
    assert certificate.certified
    np.testing.assert_allclose(certificate.poses[5], graph.poses[5], atol=1e-12)
    relative = np.linalg.inv(certificate.poses[5]) @ certificate.poses
    np.testing.assert_allclose(relative, np.linalg.inv(truth[5]) @ truth, atol=1e-7)


@GROUPS
def test_anisotropic_optimum_certifies_only_after_refinement(group):
    """With anisotropic information LM's optimum of the g2o cost is not a critical point of F: as given
    it does not certify; refined from it, it does, to the same F as the default candidate. (With
    isotropic information it can: it is then within η and 10⁻⁶ F of F's optimum.)"""
    import dataclasses

    from tests.init.synthetic import information_matrices

    graph, _ = loop_graph(14, n=30, loops=20, rotation_noise=0.05, translation_noise=0.1, group=group)
    information = information_matrices(np.random.default_rng(14), graph.num_edges, 1.0, 1e3, size=group.dim)
    graph = dataclasses.replace(graph, information=information)
    lm = posegraph.optimize(graph).poses
    assert not certify(graph, poses=lm).certified
    refined = certify(graph, poses=lm, refine=True)
    assert refined.certified and "candidate" not in refined.seconds
    assert refined.sesync_objective == pytest.approx(certify(graph).sesync_objective, rel=1e-9)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), rotation_noise=st.floats(0.0, 0.1), two_d=st.booleans())
def test_certified_objective_never_exceeds_the_truths(seed, rotation_noise, two_d):
    """Property: the truth is a feasible point, so a certified global minimum is at most F(truth), and
    the bound holds: F(truth) ≥ tr Λ."""
    from posegraph.certification.certificate import poses_to_blocks
    from posegraph.certification.problem import objective

    group = SE2 if two_d else SE3
    graph, truth = loop_graph(seed, n=12, loops=8, rotation_noise=rotation_noise, translation_noise=0.05, group=group)
    certificate = certify(graph)
    assert certificate.certified
    at_truth = objective(sync_problem(graph), poses_to_blocks(truth))
    assert certificate.sesync_objective <= at_truth * (1 + 1e-9) + 1e-12
    assert certificate.dual_bound <= at_truth * (1 + 1e-9) + 1e-12
