"""Linear-solver backends: same solutions, positive-definiteness errors, selection rules."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from posegraph.solve import linear
from posegraph.solve.linear import (
    NotPositiveDefiniteError,
    cholmod_available,
    elimination_tree,
    make_linear_solver,
    tree_postorder,
    vertex_ordering,
)
from posegraph.solve.sparsity import analyze_pattern, hessian_values, lower_csc
from tests.solve.test_sparsity import random_blocks, random_graph



def spd_system(seed, n=30, m=80):
    rng = np.random.default_rng(seed)
    edge_from, edge_to = random_graph(rng, n, m)
    held = np.zeros(n, dtype=bool)
    held[0] = True
    pattern = analyze_pattern(n, edge_from, edge_to, held)
    data = hessian_values(pattern, random_blocks(rng, m))
    data[pattern.diagonal] += 1e-2  # strictly positive definite
    lower = lower_csc(pattern, data)
    full = (lower + sp.tril(lower, k=-1).T).toarray()
    return pattern, data, full, rng.normal(size=pattern.dimension)


def check_solution_matches_dense_solve(kind, seed):
    pattern, data, full, rhs = spd_system(seed)
    solver = make_linear_solver(kind, pattern)
    solver.factorize(data)
    np.testing.assert_allclose(solver.solve(rhs), np.linalg.solve(full, rhs), rtol=1e-9, atol=1e-9)
    # numeric refactorisation with new values on the same pattern
    data2 = data * 2.0
    solver.factorize(data2)
    np.testing.assert_allclose(solver.solve(rhs), np.linalg.solve(2.0 * full, rhs), rtol=1e-9, atol=1e-9)
    return solver


@pytest.mark.parametrize("seed", range(3))
def test_scipy_solution_matches_dense_solve(seed):
    check_solution_matches_dense_solve("scipy", seed)


@pytest.mark.parametrize("seed", range(3))
def test_cholmod_solution_matches_dense_solve(seed, cholmod_backend):
    solver = check_solution_matches_dense_solve("cholmod", seed)
    assert solver.name.endswith(f"via {cholmod_backend}")


@pytest.mark.parametrize("kind", ["scipy", "cholmod"])
def test_factor_and_permutation_reproduce_the_matrix(kind, cholmod_backend):
    pattern, data, full, _ = spd_system(5)
    solver = make_linear_solver(kind, pattern)
    solver.factorize(data)
    indptr, indices, values, permutation = solver.factor()
    lower = sp.csc_matrix((values, indices, indptr), shape=full.shape).toarray()
    assert np.array_equal(lower, np.tril(lower))
    np.testing.assert_allclose(lower @ lower.T, full[np.ix_(permutation, permutation)], rtol=0, atol=1e-9)


def test_backends_agree_on_the_same_matrix(cholmod_backend):
    pattern, data, _, rhs = spd_system(6, n=60, m=200)
    solutions = []
    for kind in ("scipy", "cholmod"):
        solver = make_linear_solver(kind, pattern)
        solver.factorize(data)
        solutions.append(solver.solve(rhs))
    np.testing.assert_allclose(solutions[0], solutions[1], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["scipy", "cholmod"])
@pytest.mark.parametrize("bad_value", [-1e3, np.nan, np.inf])
def test_indefinite_or_non_finite_matrices_are_reported(kind, bad_value, cholmod_backend):
    pattern, data, full, rhs = spd_system(0)
    solver = make_linear_solver(kind, pattern)
    bad = data.copy()
    bad[pattern.diagonal[3]] = bad_value
    with pytest.raises(NotPositiveDefiniteError):
        solver.factorize(bad)
    solver.factorize(data)  # recovers on the next good matrix
    np.testing.assert_allclose(solver.solve(rhs), np.linalg.solve(full, rhs), rtol=1e-9, atol=1e-9)


def test_scipy_reports_exactly_singular_matrix():
    pattern, data, _, _ = spd_system(1)
    solver = make_linear_solver("scipy", pattern)
    with pytest.raises(NotPositiveDefiniteError):
        solver.factorize(np.zeros_like(data))


def test_auto_picks_cholmod_when_available_else_scipy(monkeypatch):
    pattern = spd_system(0)[0]
    expected = "cholmod" if cholmod_available() else "scipy"
    assert make_linear_solver("auto", pattern).name.startswith(expected)
    monkeypatch.setattr(linear, "cholmod_available", lambda: False)
    assert make_linear_solver("auto", pattern).name.startswith("scipy")
    with pytest.raises(ImportError, match="cvxopt"):
        make_linear_solver("cholmod", pattern)
    with pytest.raises(ValueError, match="unknown linear solver"):
        make_linear_solver("mumps", pattern)


@pytest.fixture
def multigrid_available():
    pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")


@pytest.mark.parametrize("seed", range(3))
def test_pcg_solution_matches_dense_solve(seed, multigrid_available):
    pattern, data, full, rhs = spd_system(seed)
    solver = make_linear_solver("pcg", pattern, tolerance=1e-13)
    assert not solver.holds_factorization
    for scale in (1.0, 2.0):  # refactorised with new values on the same pattern
        solver.factorize(data * scale)
        np.testing.assert_allclose(solver.solve(rhs), np.linalg.solve(scale * full, rhs), rtol=1e-8, atol=1e-9)
    assert solver.name.startswith("pcg") and "1e-13" in solver.name
    with pytest.raises(NotImplementedError, match="covariances"):
        solver.factor()
    solver.release()
    with pytest.raises(RuntimeError, match="factorize"):
        solver.solve(rhs)


@pytest.mark.parametrize("kind", ["scipy", "cholmod", "pcg"])
def test_shift_is_added_to_the_diagonal_and_data_left_unchanged(kind):
    if kind == "pcg":
        pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")
    if kind == "cholmod" and not cholmod_available():
        pytest.skip("CHOLMOD (cvxopt) is not installed")
    pattern, data, full, rhs = spd_system(8)
    shift = np.random.default_rng(8).uniform(0.1, 3.0, size=pattern.dimension)
    kept = data.copy()
    solver = make_linear_solver(kind, pattern, tolerance=1e-13)
    solver.factorize(data, shift)
    np.testing.assert_array_equal(data, kept)
    np.testing.assert_allclose(solver.solve(rhs), np.linalg.solve(full + np.diag(shift), rhs), rtol=1e-8, atol=1e-9)


def test_pcg_without_pyamg_says_what_to_install(monkeypatch):
    from posegraph.linalg import multigrid

    monkeypatch.setattr(multigrid, "available", lambda: False)
    with pytest.raises(ImportError, match=r"posegraph\[large\]"):
        make_linear_solver("pcg", spd_system(0)[0])


def test_elimination_tree_of_a_path_and_an_arrow():
    # path 0-1-2-3: parent k -> k+1
    path = sp.csc_matrix(np.eye(4) + np.eye(4, k=1) + np.eye(4, k=-1))
    np.testing.assert_array_equal(elimination_tree(path), [1, 2, 3, -1])
    # arrow: every node joined to the last only
    arrow = np.eye(4)
    arrow[3, :] = arrow[:, 3] = 1
    np.testing.assert_array_equal(elimination_tree(sp.csc_matrix(arrow)), [3, 3, 3, -1])


def test_elimination_tree_matches_dense_cholesky_fill():
    # parent(i) = first off-diagonal nonzero row of column i of the Cholesky factor
    rng = np.random.default_rng(5)
    a = (rng.random((25, 25)) < 0.12).astype(float)
    a = a + a.T + 25 * np.eye(25)
    chol = np.linalg.cholesky(a)
    expected = [int(np.flatnonzero(np.abs(chol[i + 1 :, i]) > 1e-14)[0] + i + 1) if np.any(np.abs(chol[i + 1 :, i]) > 1e-14) else -1 for i in range(25)]
    np.testing.assert_array_equal(elimination_tree(sp.csc_matrix(a)), expected)


def test_postorder_puts_children_before_parents_and_keeps_subtrees_contiguous():
    parent = np.array([2, 2, 5, 4, 5, -1, -1])
    order = tree_postorder(parent)
    assert sorted(order.tolist()) == list(range(7))
    position = np.argsort(order)
    for child, par in enumerate(parent):
        if par >= 0:
            assert position[child] < position[par]
    # subtree of 2 = {0, 1, 2} occupies consecutive positions
    assert sorted(position[[0, 1, 2]].tolist()) == list(range(position[[0, 1, 2]].min(), position[[0, 1, 2]].min() + 3))


def test_vertex_ordering_is_a_permutation_of_free_vertices():
    pattern = spd_system(2, n=40, m=120)[0]
    order = vertex_ordering(pattern)
    assert sorted(order.tolist()) == list(range(pattern.num_variables))


def test_auto_ordering_is_amd_for_small_systems_and_nested_dissection_from_the_threshold(monkeypatch, cholmod_backend):
    from posegraph.linalg import cholmod

    pattern, data, full, rhs = spd_system(4)
    assert pattern.num_variables < cholmod.NESTED_DISSECTION_VERTICES
    assert "(supernodal, amd" in make_linear_solver("cholmod", pattern).name
    monkeypatch.setattr(cholmod, "NESTED_DISSECTION_VERTICES", pattern.num_variables)
    solver = make_linear_solver("cholmod", pattern)
    assert "(supernodal, nesdis" in solver.name
    solver.factorize(data)
    np.testing.assert_allclose(solver.solve(rhs), np.linalg.solve(full, rhs), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kind", ["scipy", "cholmod"])
def test_one_free_vertex_is_one_block(kind, cholmod_backend):
    held = np.array([True, False])
    pattern = analyze_pattern(2, np.array([0]), np.array([1]), held)
    assert pattern.num_variables == 1 and pattern.dimension == 6
    rng = np.random.default_rng(3)
    a = rng.normal(size=(6, 6))
    block = a @ a.T + 6 * np.eye(6)
    data = block[pattern.indices, np.repeat(np.arange(6), np.diff(pattern.indptr))]
    solver = make_linear_solver(kind, pattern)
    solver.factorize(data)
    np.testing.assert_allclose(solver.solve(np.ones(6)), np.linalg.solve(block, np.ones(6)), rtol=1e-12)


def test_lm_raises_lambda_when_cholmod_reports_not_positive_definite(monkeypatch, shared_dataset, cholmod_backend):
    """The first factorisation gets an indefinite matrix (its diagonal negated) from a wrapped CHOLMOD
    solver: CHOLMOD's own failure must reach LM as NotPositiveDefiniteError, LM must raise λ and
    retry, and the optimum must be the one reached without the failure."""
    from posegraph import SolverParams, optimize, read_g2o
    from posegraph.solve import optimizer

    graph = read_g2o(shared_dataset("smallGrid3D"))
    params = SolverParams(linear_solver="cholmod")
    clean = optimize(graph, params=params)

    class FirstFactorizationIndefinite(linear.LinearSolver):
        def __init__(self, solver):
            self.solver, self.name, self.failed = solver, solver.name, False

        def factorize(self, data, shift=None):
            if not self.failed:
                self.failed = True
                self.solver.factorize(-data, shift)  # raises: CHOLMOD's ArithmeticError, translated
            self.solver.factorize(data, shift)

        def solve(self, rhs):
            return self.solver.solve(rhs)

    made = []

    def wrapped(*args, **kwargs):
        made.append(FirstFactorizationIndefinite(make_linear_solver(*args, **kwargs)))
        return made[-1]

    monkeypatch.setattr(optimizer, "make_linear_solver", wrapped)
    result = optimize(graph, params=params)
    assert made and made[0].failed
    first = result.records[0]
    assert first.attempts >= 2 and first.lambda_ > params.initial_lambda
    assert result.converged and result.final_cost == pytest.approx(clean.final_cost, rel=1e-9)


def test_pcg_tightens_its_tolerance_as_the_gradient_falls(multigrid_available, monkeypatch):
    """Eisenstat–Walker forcing: 1e-2 at the first solve, γ(‖b‖/‖b_prev‖)² after, never below the floor."""
    from posegraph.linalg import multigrid

    monkeypatch.setattr(multigrid, "COARSEST_UNKNOWNS", 12)  # coarse levels, so that CG iterates
    pattern, data, full, rhs = spd_system(9, n=60, m=200)
    solver = make_linear_solver("pcg", pattern, tolerance=1e-10)
    solver.factorize(data)
    asked = []
    for scale in (1.0, 1e-3, 1e-3, 1e-9):
        b = scale * rhs
        x = solver.solve(b)
        asked.append(solver._cg.tolerance)
        assert np.linalg.norm(b - full @ x) <= asked[-1] * np.linalg.norm(b) * (1 + 1e-9)
    assert asked[0] == linear.FORCING_MAX
    assert asked[1] == pytest.approx(linear.FORCING_GAMMA * 1e-6)
    assert asked[2] == asked[1]  # the same gradient again (LM's retry with another λ)
    assert asked[3] == 1e-10  # the floor


def test_pcg_confirms_convergence_only_after_a_tight_enough_solve(multigrid_available, monkeypatch):
    from posegraph.linalg import multigrid

    monkeypatch.setattr(multigrid, "COARSEST_UNKNOWNS", 12)
    pattern, data, _, rhs = spd_system(10, n=60, m=200)
    solver = make_linear_solver("pcg", pattern, tolerance=1e-10)
    solver.factorize(data)
    solver.solve(rhs)  # the first solve: the forcing's 1e-2
    assert solver.confirm_convergence() is False  # … so LM's decrease test does not stop on it
    solver.solve(rhs)
    assert solver._cg.tolerance == 1e-10 and solver.confirm_convergence() is True
    solver.solve(1e-3 * rhs)  # 0.9e-6 ≤ linear.CONVERGENCE_TOLERANCE: trusted as it is
    assert solver.confirm_convergence() is True
    assert make_linear_solver("scipy", pattern).confirm_convergence() is True


def test_auto_solves_by_pcg_when_the_factor_would_not_fit_and_a_factor_is_not_needed(monkeypatch, multigrid_available):
    from posegraph.linalg import heap
    from posegraph.errors import PosegraphWarning

    if not cholmod_available():
        pytest.skip("CHOLMOD (cvxopt) is not installed")
    pattern, data, full, rhs = spd_system(2)
    from posegraph.linalg import cholmod

    foreseen = cholmod.block_factor_bytes(pattern.block_indptr, pattern.block_indices, pattern.num_variables, pattern.block_size)
    monkeypatch.setattr(heap, "available_bytes", lambda: int(foreseen / heap.FACTOR_MEMORY_SHARE) - 1)
    assert make_linear_solver("auto", pattern).name.startswith("cholmod")  # covariances need the factor
    with pytest.warns(PosegraphWarning, match=r"Cholesky factor of this graph would take [\d.]+ kiB, more than 75% of the [\d.]+ kiB .* 'pcg'"):
        solver = make_linear_solver("auto", pattern, factor_needed=False, tolerance=1e-13)
    assert solver.name.startswith("pcg")
    solver.factorize(data)
    np.testing.assert_allclose(solver.solve(rhs), np.linalg.solve(full, rhs), rtol=1e-8, atol=1e-9)
    for available in (int(foreseen / heap.FACTOR_MEMORY_SHARE) + 1, None):  # fits, or unknown
        monkeypatch.setattr(heap, "available_bytes", lambda: available)
        assert make_linear_solver("auto", pattern, factor_needed=False).name.startswith("cholmod")


def test_auto_without_pyamg_says_how_large_the_factor_would_be_and_what_to_install(monkeypatch):
    from posegraph.linalg import heap, multigrid

    if not cholmod_available():
        pytest.skip("CHOLMOD (cvxopt) is not installed")
    monkeypatch.setattr(heap, "available_bytes", lambda: 1000)
    monkeypatch.setattr(multigrid, "available", lambda: False)
    with pytest.raises(ImportError, match=r"would take .*iB.*pip install \"posegraph\[large\]\".*'cholmod'"):
        make_linear_solver("auto", spd_system(0)[0], factor_needed=False)
    assert make_linear_solver("cholmod", spd_system(0)[0], factor_needed=False).name.startswith("cholmod")  # asked by name


@pytest.mark.parametrize("ordering", ["auto", "amd", "nesdis", "natural", "default"])
def test_the_factor_foreseen_from_the_vertex_pattern_bounds_the_scalar_analysis(ordering):
    from posegraph.linalg import cholmod

    if not cholmod_available():
        pytest.skip("CHOLMOD (cvxopt) is not installed")
    if ordering == "nesdis":
        pytest.importorskip("pymetis", reason="nested dissection needs pymetis")
    rng = np.random.default_rng(5)
    edge_from, edge_to = random_graph(rng, 400, 1600)
    held = np.zeros(400, dtype=bool)
    held[0] = True
    for block in (3, 6):
        pattern = analyze_pattern(400, edge_from, edge_to, held, block)
        scalar = cholmod.block_cholesky(pattern.indptr, pattern.indices, pattern.block_indptr, pattern.block_indices,
                                        pattern.num_variables, block, ordering).factor_bytes  # fmt: skip
        foreseen = cholmod.block_factor_bytes(pattern.block_indptr, pattern.block_indices, pattern.num_variables, block, ordering)
        # from above, and close: the vertex analysis amalgamates what the scalar one amalgamates at block size
        assert scalar <= foreseen <= 1.6 * scalar, (block, scalar, foreseen)
