"""Λ and S against dense computations; the PSD test and the eigenvalue estimate against eigvalsh."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.certification.certificate import poses_to_blocks
from posegraph.certification.local import refine_poses
from posegraph.certification.problem import sync_problem
from posegraph.certification.verify import certificate_matrix, lambda_blocks, verify
from posegraph.lie.group import SE2, SE3
from tests.certification.dense import interleave, sesync_data_matrix, sesync_lambda
from tests.certification.graphs import loop_graph

GROUPS = pytest.mark.parametrize("group", [SE3, SE2], ids=["SE3", "SE2"])


def _critical_point(group, seed=10, rotation_noise=0.05):
    graph, _ = loop_graph(seed, n=12, loops=8, rotation_noise=rotation_noise, translation_noise=0.1, group=group)
    problem = sync_problem(graph)
    u, _, _ = refine_poses(problem, poses_to_blocks(graph.poses), anchor=0)
    return problem, u


@GROUPS
def test_lambda_and_certificate_match_dense(group):
    """Λ_i = Sym((Q Yᵀ)_i Y_i) with the dense Q, and S = M − diag(0, Λ) entry by entry."""
    problem, u = _critical_point(group)
    lambdas = lambda_blocks(problem, u)
    np.testing.assert_allclose(lambdas, sesync_lambda(problem, u[:, :, 1:]), atol=1e-8 * np.abs(lambdas).max())
    n, d = problem.num_poses, problem.d
    dense = sesync_data_matrix(problem)
    dense[n:, n:] -= _block_diagonal(lambdas)
    perm = interleave(n, d)
    matrix = certificate_matrix(problem, lambdas)
    np.testing.assert_allclose(matrix.dense(), dense[np.ix_(perm, perm)], atol=1e-10 * np.abs(dense).max())
    x = np.random.default_rng(0).normal(size=matrix.pattern.dimension)
    np.testing.assert_allclose(matrix.matvec(x), matrix.dense() @ x, atol=1e-10 * np.abs(dense).max())


def _block_diagonal(blocks: np.ndarray) -> np.ndarray:
    n, d = blocks.shape[0], blocks.shape[1]
    out = np.zeros((n * d, n * d))
    for k in range(n):
        out[d * k: d * (k + 1), d * k: d * (k + 1)] = blocks[k]
    return out


@GROUPS
def test_psd_certificate_and_eigenvalue_estimate(group):
    """At the optimum of a low-noise graph S ⪰ 0 with the rows of X in its kernel: λ_min ≈ 0."""
    problem, u = _critical_point(group)
    matrix = certificate_matrix(problem, lambda_blocks(problem, u))
    result = verify(matrix, u)
    exact = np.linalg.eigvalsh(matrix.dense())
    assert result.positive_semidefinite and exact[0] > -1e-3
    assert result.min_eigenvalue == pytest.approx(exact[0], abs=1e-9)
    # the kernel: the d rows of X and the common translation (M's Laplacian block, Ṽᵀ1 = 0)
    assert abs(exact[problem.d]) < 1e-9 and exact[problem.d + 1] > 1e-3
    np.testing.assert_allclose(matrix.dense() @ np.swapaxes(u, 0, 1).reshape(problem.d, -1).T, 0.0, atol=1e-8)


@GROUPS
def test_perturbed_point_is_not_psd_and_its_eigenpair_is_accurate(group):
    """Away from a critical point S has a clearly negative eigenvalue; the estimate finds it."""
    problem, u = _critical_point(group)
    moved = u.copy()
    moved[3, :, 1:] = moved[3, :, 1:] @ group.rotations.exp(np.full(len(group.rotation_axes), 0.3))
    matrix = certificate_matrix(problem, lambda_blocks(problem, moved))
    result = verify(matrix, moved)
    exact = np.linalg.eigvalsh(matrix.dense())
    assert exact[0] < -1e-3 and not result.positive_semidefinite
    assert result.min_eigenvalue == pytest.approx(exact[0], rel=1e-6)
    vector = result.eigenvector
    assert vector @ matrix.matvec(vector) == pytest.approx(exact[0], rel=1e-6)
