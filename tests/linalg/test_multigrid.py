"""Multigrid-preconditioned CG (posegraph.linalg.multigrid): the near-null space, solves, failures."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")

from posegraph.linalg import multigrid  # noqa: E402
from posegraph.linalg.cholmod import NotPositiveDefiniteError  # noqa: E402
from posegraph.lie.group import SE2, SE3  # noqa: E402
from posegraph.solve.linearize import linearize  # noqa: E402
from posegraph.solve.sparsity import analyze_pattern, hessian_values, symmetric_block_values, symmetric_blocks  # noqa: E402
from tests.init.synthetic import noise_free_graph  # noqa: E402


@pytest.fixture(autouse=True)
def several_levels(monkeypatch):
    """Coarsen the tests' small systems down to a few dozen unknowns, so that they have coarse levels."""
    monkeypatch.setattr(multigrid, "COARSEST_UNKNOWNS", 24)


def block_matrix(pattern, data):
    """H (both triangles) as a scipy BSR matrix of d×d blocks."""
    layout = symmetric_blocks(pattern)
    values = symmetric_block_values(pattern, layout, data)
    size = pattern.dimension
    return sp.bsr_matrix((values, layout.indices, layout.indptr), shape=(size, size))


def hessian_of(graph, poses, held):
    pattern = analyze_pattern(graph.num_vertices, graph.edge_from, graph.edge_to, held, graph.group.dim)
    return pattern, hessian_values(pattern, linearize(poses, graph).hessian_blocks)


@pytest.mark.parametrize("group", [SE2, SE3], ids=lambda g: g.name)
@pytest.mark.parametrize("seed", range(3))
def test_pose_null_space_is_the_null_space_of_the_unanchored_hessian(group, seed):
    # Left-multiplying every pose by one element leaves every residual unchanged: H·Ad(X⁻¹)ξ = 0.
    graph, truth = noise_free_graph(seed, n=30, loops=15, group=group)
    rng = np.random.default_rng(seed)
    poses = truth @ group.exp(0.3 * rng.normal(size=(truth.shape[0], group.dim)))  # away from the optimum
    pattern, data = hessian_of(graph, poses, np.zeros(graph.num_vertices, dtype=bool))
    hessian = block_matrix(pattern, data).toarray()
    null = multigrid.pose_null_space(group, poses)
    assert null.shape == (pattern.dimension, group.dim)
    assert np.abs(hessian @ null).max() <= 1e-9 * np.abs(hessian).max() * np.abs(null).max()
    assert np.linalg.matrix_rank(null) == group.dim
    # identity blocks are not: a uniform tangent step is no global motion on a curved trajectory
    uniform = np.tile(np.eye(group.dim), (graph.num_vertices, 1))
    assert np.abs(hessian @ uniform).max() > 1e-3 * np.abs(hessian).max()


def anchored_system(seed, group=SE3, n=60):
    graph, truth = noise_free_graph(seed, n=n, loops=n // 2, group=group)
    held = np.zeros(graph.num_vertices, dtype=bool)
    held[0] = True
    pattern, data = hessian_of(graph, truth, held)
    rhs = np.random.default_rng(seed).normal(size=pattern.dimension)
    return pattern, data, truth[~held], rhs


@pytest.mark.parametrize("seed", range(3))
def test_solves_to_the_relative_residual_asked(seed):
    pattern, data, poses, rhs = anchored_system(seed)
    matrix = block_matrix(pattern, data)
    for tolerance in (1e-4, 1e-10):
        solver = multigrid.MultigridCG(tolerance)
        solver.factorize(matrix, multigrid.pose_null_space(SE3, poses))
        x = solver.solve(rhs)
        assert np.linalg.norm(matrix @ x - rhs) <= tolerance * np.linalg.norm(rhs)
    exact = np.linalg.solve(matrix.toarray(), rhs)
    np.testing.assert_allclose(x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())


def test_several_right_hand_sides_are_solved_column_by_column():
    pattern, data, poses, rhs = anchored_system(4)
    matrix = block_matrix(pattern, data)
    solver = multigrid.MultigridCG(1e-12)
    solver.factorize(matrix, multigrid.pose_null_space(SE3, poses))
    columns = np.stack([rhs, 2 * rhs + 1, np.zeros_like(rhs)], axis=1)
    x = solver.solve(columns)
    assert x.shape == columns.shape
    np.testing.assert_allclose(matrix @ x, columns, atol=1e-9 * np.abs(columns).max())
    assert solver.iterations[-1] == 0  # the zero column costs nothing


def test_the_pose_null_space_makes_the_preconditioner_work():
    # The design's reason: global motions as the near-null space, not identity blocks.
    pattern, data, poses, rhs = anchored_system(7, n=200)
    matrix = block_matrix(pattern, data)
    counts = []
    for null in (multigrid.pose_null_space(SE3, poses), np.tile(np.eye(6), (poses.shape[0], 1))):
        solver = multigrid.MultigridCG(1e-8)
        solver.factorize(matrix, null)
        solver.solve(rhs)
        counts.append(solver.iterations[-1])
    assert counts[0] < counts[1]


def test_later_factorisations_reuse_the_aggregates_and_solve_the_new_matrix():
    pattern, data, poses, rhs = anchored_system(2)
    solver = multigrid.MultigridCG(1e-12)
    null = multigrid.pose_null_space(SE3, poses)
    solver.factorize(block_matrix(pattern, data), null)
    aggregates = solver._aggregates
    scaled = block_matrix(pattern, data * 3.0)
    solver.factorize(scaled, null)
    assert solver._aggregates is aggregates
    np.testing.assert_allclose(scaled @ solver.solve(rhs), rhs, atol=1e-9 * np.abs(rhs).max())


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_matrix_is_refused_at_factorisation(bad):
    pattern, data, poses, _ = anchored_system(1)
    data = data.copy()
    data[pattern.diagonal[2]] = bad
    with pytest.raises(NotPositiveDefiniteError, match="non-finite"):
        multigrid.MultigridCG().factorize(block_matrix(pattern, data), multigrid.pose_null_space(SE3, poses))


def test_an_indefinite_matrix_fails_the_solve_or_is_solved():
    pattern, data, poses, rhs = anchored_system(3)
    data = data.copy()
    data[pattern.diagonal[3]] = -1e3 * np.abs(data).max()  # one strongly negative pivot: indefinite
    solver = multigrid.MultigridCG(1e-10, max_iterations=200)
    solver.factorize(block_matrix(pattern, data), multigrid.pose_null_space(SE3, poses))
    try:
        x = solver.solve(rhs)
    except NotPositiveDefiniteError:
        return
    # CG may still converge on an indefinite matrix; then it has solved it
    assert np.linalg.norm(block_matrix(pattern, data) @ x - rhs) <= 1e-10 * np.linalg.norm(rhs)


def test_solve_before_factorize_is_an_error():
    with pytest.raises(RuntimeError, match="factorize"):
        multigrid.MultigridCG().solve(np.ones(6))
