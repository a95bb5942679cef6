"""Λ and S against dense computations; the proven bound and the eigenvalue of Q − Λ against eigvalsh;
the test's verdict under scaled information and other units."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from posegraph.certification.certificate import poses_to_blocks
from posegraph.certification.local import refine_poses
from posegraph.certification.problem import objective, sync_problem
from posegraph.certification.verify import SHIFT_FLOOR, certificate_matrix, data_scale, lambda_blocks, verify
from posegraph.lie.group import SE2, SE3
from tests.certification.dense import interleave, reduced_data_matrix, sesync_data_matrix, sesync_lambda
from tests.certification.graphs import loop_graph

GROUPS = pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])


def _critical_point(group, seed=10, rotation_noise=0.05):
    graph, _ = loop_graph(seed, n=12, loops=8, rotation_noise=rotation_noise, translation_noise=0.1, group=group)
    problem = sync_problem(graph)
    u, _, _ = refine_poses(problem, poses_to_blocks(graph.poses), anchor=0)
    return problem, u


def _block_diagonal(blocks: np.ndarray) -> np.ndarray:
    n, d = blocks.shape[0], blocks.shape[1]
    out = np.zeros((n * d, n * d))
    for k in range(n):
        out[d * k: d * (k + 1), d * k: d * (k + 1)] = blocks[k]
    return out


def _dense_q_minus_lambda(problem, lambdas) -> np.ndarray:
    return reduced_data_matrix(problem) - _block_diagonal(lambdas)


def _verify(problem, u, budget=0.0):
    lambdas = lambda_blocks(problem, u)
    return lambdas, verify(certificate_matrix(problem, lambdas), u, lambdas, budget, data_scale(problem))


@GROUPS
def test_lambda_and_certificate_match_dense(group):
    """Λ_i = Sym((Q Yᵀ)_i Y_i) with the dense Q, and S = M − diag(0, Λ) entry by entry."""
    problem, u = _critical_point(group)
    lambdas = lambda_blocks(problem, u)
    np.testing.assert_allclose(lambdas, sesync_lambda(problem, u[:, :, 1:]), atol=1e-8 * np.abs(lambdas).max())
    n = problem.num_poses
    dense = sesync_data_matrix(problem)
    dense[n:, n:] -= _block_diagonal(lambdas)
    perm = interleave(n, problem.d)
    matrix = certificate_matrix(problem, lambdas)
    np.testing.assert_allclose(matrix.dense(), dense[np.ix_(perm, perm)], atol=1e-10 * np.abs(dense).max())
    x = np.random.default_rng(0).normal(size=matrix.pattern.dimension)
    np.testing.assert_allclose(matrix.matvec(x), matrix.dense() @ x, atol=1e-10 * np.abs(dense).max())


@GROUPS
def test_optimum_is_proven_psd_with_q_minus_lambda_kernel(group):
    """At the optimum of a low-noise graph Q − Λ ⪰ 0 with the rows of Y in its kernel: λ_min ≈ 0, the proven
    shift is at round-off and the lower bound is F to ~1e-12."""
    problem, u = _critical_point(group)
    lambdas, result = _verify(problem, u)
    exact = np.linalg.eigvalsh(_dense_q_minus_lambda(problem, lambdas))
    scale = data_scale(problem)
    assert result.positive_semidefinite
    assert abs(exact[0]) < 1e-10 * scale and abs(result.min_eigenvalue - exact[0]) <= result.residual + 1e-12 * scale
    assert -result.proven_shift <= exact[0]
    assert exact[problem.d] > 1e-3  # the kernel is Y's d rows, nothing more
    value = objective(problem, u)
    assert result.lower_bound <= value and value - result.lower_bound < 1e-10 * scale


@GROUPS
@pytest.mark.parametrize("seed", range(4))
def test_eigenvalue_and_bound_against_a_dense_eigensolver(group, seed):
    """Points moved off the optimum by up to 1 rad: the reported λ_min equals eigvalsh's of the dense Q − Λ
    to its residual, the proven −σ is below it, and the eigenvector is a Ritz vector of Q − Λ."""
    problem, u = _critical_point(group, seed=20 + seed, rotation_noise=0.1)
    rng = np.random.default_rng(seed)
    moved = u.copy()
    turn = rng.uniform(0.0, 1.0, size=(3, len(group.rotation_axes)))
    moved[[2, 5, 7], :, 1:] = moved[[2, 5, 7], :, 1:] @ group.rotations.exp(turn)
    lambdas, result = _verify(problem, moved)
    q_minus_lambda = _dense_q_minus_lambda(problem, lambdas)
    exact = np.linalg.eigvalsh(q_minus_lambda)
    assert exact[0] < 0 and not result.positive_semidefinite
    assert result.min_eigenvalue == pytest.approx(exact[0], rel=1e-8)
    assert abs(result.min_eigenvalue - exact[0]) <= result.residual + 1e-12 * abs(exact[0])
    assert -result.proven_shift <= exact[0] and -result.proven_shift >= 1.5 * exact[0]  # tight to 50 %
    d, dn = problem.d, exact.size
    trace = np.trace(lambdas, axis1=1, axis2=2).sum()
    assert result.lower_bound == pytest.approx(trace - dn * result.proven_shift)
    rotation = result.eigenvector.reshape(problem.num_poses, d + 1)[:, 1:].ravel()
    assert np.linalg.norm(rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(q_minus_lambda @ rotation, result.min_eigenvalue * rotation, atol=result.residual * 2)


def _scaled(graph, information_scale=1.0, unit=1.0):
    """The graph with every information × ``information_scale`` and lengths in units 1/``unit`` (metres → mm: 1000)."""
    measurements = graph.measurements.copy()
    d = graph.group.space_dim
    measurements[:, :d, d] *= unit
    information = graph.information * information_scale
    tra = np.array(graph.group.translation_axes)
    information[:, tra[:, None], tra] /= unit**2
    information[:, tra[:, None], np.array(graph.group.rotation_axes)] /= unit
    information[:, np.array(graph.group.rotation_axes)[:, None], tra] /= unit
    poses = graph.poses.copy()
    poses[:, :d, d] *= unit
    return dataclasses.replace(graph, measurements=measurements, information=information, poses=poses)


@GROUPS
@pytest.mark.parametrize("information_scale, unit", [(1e-6, 1.0), (1e-4, 1.0), (1e4, 1.0), (1e6, 1.0), (1.0, 1e3),
                                                     (1e-4, 1e3)])  # fmt: skip
def test_verdict_and_shift_do_not_depend_on_scale_or_units(group, information_scale, unit):
    """A local minimum (0.8 rad of noise, moved 0.6 rad): scaling every information by c multiplies Q − Λ by c;
    metres as millimetres leaves it as it is. The verdict and the relative proven shift stay."""
    problem, u = _critical_point(group, seed=3, rotation_noise=0.3)
    moved = u.copy()
    moved[4, :, 1:] = moved[4, :, 1:] @ group.rotations.exp(np.full(len(group.rotation_axes), 0.6))
    graph, _ = loop_graph(3, n=12, loops=8, rotation_noise=0.3, translation_noise=0.1, group=group)
    _, base = _verify(problem, moved, budget=1e-6)
    other = sync_problem(_scaled(graph, information_scale, unit))
    scaled_u = moved.copy()
    scaled_u[:, :, 0] *= unit
    _, result = _verify(other, scaled_u, budget=1e-6 * information_scale)
    assert result.positive_semidefinite == base.positive_semidefinite
    assert result.min_eigenvalue == pytest.approx(information_scale * base.min_eigenvalue, rel=1e-6)
    assert result.proven_shift == pytest.approx(information_scale * base.proven_shift, rel=1e-6)
    assert result.lower_bound == pytest.approx(information_scale * base.lower_bound, rel=1e-6)


def test_products_by_bincount_and_by_scipy_agree(monkeypatch):
    """S x for a vector and a block: scipy's product (once scipy.sparse is loaded) and the bincount one (the
    scipy-free rank-d path) both equal the dense product."""
    import sys

    import scipy.sparse  # noqa: F401 (loaded: the scipy branch)

    problem, u = _critical_point(SE3)
    matrix = certificate_matrix(problem, lambda_blocks(problem, u))
    rng = np.random.default_rng(1)
    vector, block = rng.normal(size=matrix.pattern.dimension), rng.normal(size=(matrix.pattern.dimension, 5))
    dense = matrix.dense()
    with_scipy = matrix.matvec(vector), matrix.matvec(block)
    monkeypatch.delitem(sys.modules, "scipy.sparse")
    without = matrix.matvec(vector), matrix.matvec(block)
    for got in (*with_scipy, *without):
        expected = dense @ (vector if got.ndim == 1 else block)
        np.testing.assert_allclose(got, expected, atol=1e-10 * np.abs(dense).max())


@GROUPS
def test_psd_verdict_decided_by_the_budget_around_a_small_negative_eigenvalue(group):
    """A point turned 0.02 rad off the optimum: Q − Λ has a small θ < 0 (dense eigvalsh). With the budget
    2|θ| the shift proves Q − Λ + σI ≻ 0 within it (positive semidefinite within the tolerance); with
    |θ|/2 no shift inside the budget can, and the verdict is no — the proven −σ staying below θ either way."""
    problem, u = _critical_point(group)
    moved = u.copy()
    moved[5, :, 1:] = moved[5, :, 1:] @ group.rotations.exp(np.full(len(group.rotation_axes), 0.02))
    lambdas = lambda_blocks(problem, moved)
    theta = np.linalg.eigvalsh(_dense_q_minus_lambda(problem, lambdas))[0]
    dn = lambdas.shape[0] * lambdas.shape[1]
    assert -1e-2 * data_scale(problem) / dn < theta < -1e4 * SHIFT_FLOOR * data_scale(problem) / dn  # small, far above the floor
    matrix, scale = certificate_matrix(problem, lambdas), data_scale(problem)
    within = verify(matrix, moved, lambdas, 2 * abs(theta), scale)
    outside = verify(matrix, moved, lambdas, abs(theta) / 2, scale)
    assert within.positive_semidefinite and abs(theta) <= within.proven_shift <= 2 * abs(theta)
    assert not outside.positive_semidefinite and outside.proven_shift >= abs(theta)
    for result in (within, outside):
        assert result.min_eigenvalue == pytest.approx(theta, rel=1e-6)
        assert -result.proven_shift <= theta
