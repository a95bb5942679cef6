"""CHOLMOD through cvxopt: solutions against dense algebra, the factor, failures, orderings, index types."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from posegraph.linalg import cholmod

pytestmark = pytest.mark.skipif(cholmod.load() is None, reason=f"no CHOLMOD: {cholmod.unavailable_reason()}")


def random_spd(seed: int, n: int = 120, density: float = 0.05):
    """A sparse SPD matrix (dense array) and its CSC lower triangle ``(indptr, indices, data)``."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n)) * (rng.random((n, n)) < density)
    matrix = a @ a.T + np.diag(rng.uniform(0.5, 2.0, n))
    return matrix, *csc(np.tril(matrix))


def csc(dense: np.ndarray):
    columns = [np.flatnonzero(dense[:, j]) for j in range(dense.shape[1])]
    indptr = np.concatenate([[0], np.cumsum([c.size for c in columns])])
    indices = np.concatenate(columns)
    data = np.concatenate([dense[c, j] for j, c in enumerate(columns)])
    return indptr, indices, data


@pytest.mark.parametrize("ordering", list(cholmod.ORDERINGS))
@pytest.mark.parametrize("seed", range(2))
def test_solution_matches_a_dense_solve_for_every_ordering(ordering, seed):
    matrix, indptr, indices, data = random_spd(seed)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0], ordering)
    factor.factorize(data)
    rng = np.random.default_rng(10 + seed)
    for shape in [(matrix.shape[0],), (matrix.shape[0], 1), (matrix.shape[0], 3)]:
        rhs = rng.normal(size=shape)
        x = factor.solve(rhs)
        assert x.shape == rhs.shape
        np.testing.assert_allclose(x, np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)
    # numeric refactorisation on the same pattern
    factor.factorize(3.0 * data)
    np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(3.0 * matrix, rhs), rtol=1e-10, atol=1e-12)


def test_entries_above_the_diagonal_are_ignored():
    matrix, _, _, _ = random_spd(3)
    garbage = matrix + np.triu(np.full_like(matrix, 7.0), k=1) * (matrix != 0)  # wrong upper half
    indptr, indices, data = csc(garbage)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0])
    factor.factorize(data)
    rhs = np.arange(matrix.shape[0], dtype=float)
    np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)


def test_factor_and_permutation_reproduce_the_matrix_and_leave_the_solver_usable():
    matrix, indptr, indices, data = random_spd(4, n=150)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0])
    factor.factorize(data)
    l_indptr, l_indices, l_data, permutation = factor.factor()
    assert l_indices.dtype == np.int64 and sorted(permutation.tolist()) == list(range(matrix.shape[0]))
    lower = np.zeros_like(matrix)
    lower[l_indices, np.repeat(np.arange(matrix.shape[0]), np.diff(l_indptr))] = l_data
    assert np.array_equal(lower, np.tril(lower)) and (np.diag(lower) > 0).all()
    np.testing.assert_allclose(lower @ lower.T, matrix[np.ix_(permutation, permutation)], rtol=0, atol=1e-12)
    assert lower.astype(bool).sum() < 0.5 * matrix.shape[0] ** 2  # a sparse factor: the permutation reduced fill
    rhs = np.arange(matrix.shape[0], dtype=float)
    np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)


def test_released_factor_is_the_same_and_closes_the_solver():
    matrix, indptr, indices, data = random_spd(5, n=150)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0])
    factor.factorize(data)
    kept = factor.factor()
    released = factor.factor(release=True)  # this object's own factor, no second factorisation
    for a, b in zip(kept, released):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(RuntimeError, match="factorize"):
        factor.solve(np.ones(matrix.shape[0]))
    with pytest.raises(RuntimeError, match="closed"):
        factor.factorize(data)


def test_64_bit_and_unsorted_indices_give_the_same_solution():
    matrix, indptr, indices, data = random_spd(9, n=80)
    shuffled_indices, shuffled_data = indices.copy(), data.copy()
    rng = np.random.default_rng(0)
    for j in range(matrix.shape[0]):  # rows in a random order within each column
        cut = slice(indptr[j], indptr[j + 1])
        order = rng.permutation(indptr[j + 1] - indptr[j])
        shuffled_indices[cut], shuffled_data[cut] = indices[cut][order], data[cut][order]
    rhs = np.ones(matrix.shape[0])
    for dtype in (np.int32, np.int64):
        factor = cholmod.SparseCholesky(indptr.astype(dtype), shuffled_indices.astype(dtype), matrix.shape[0])
        factor.factorize(shuffled_data)
        np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)


def test_one_free_vertex_is_a_single_block():
    block = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.5], [0.0, 0.5, 2.0]])
    indptr, indices, data = csc(np.tril(block))
    for ordering in ("auto", "amd", "nesdis"):
        factor = cholmod.block_cholesky(indptr, indices, np.array([0, 1]), np.array([0]), 1, 3, ordering)
        factor.factorize(data)
        np.testing.assert_allclose(factor.solve(np.ones(3)), np.linalg.solve(block, np.ones(3)), rtol=1e-14)


def test_cvxopt_options_are_restored_after_each_call():
    from cvxopt import cholmod as cvxopt_cholmod

    cvxopt_cholmod.options["postorder"] = False  # another user of cvxopt in the same process
    try:
        matrix, indptr, indices, data = random_spd(2, n=30)
        cholmod.SparseCholesky(indptr, indices, 30, "nesdis").factorize(data)
        assert cvxopt_cholmod.options == {"postorder": False}
    finally:
        cvxopt_cholmod.options.clear()


@pytest.mark.parametrize("bad_value", [-1e3, 0.0, np.nan, np.inf])
def test_a_matrix_that_is_not_positive_definite_raises_and_the_next_good_one_works(bad_value):
    matrix, indptr, indices, data = random_spd(5)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0])
    bad = data.copy()
    bad[indptr[7]] = bad_value  # the diagonal entry of column 7 (stored first)
    if bad_value == 0.0:
        bad[indptr[7] : indptr[8]] = 0.0  # a zero column: singular
    with pytest.raises(cholmod.NotPositiveDefiniteError):
        factor.factorize(bad)
    with pytest.raises(RuntimeError, match="factorize"):
        factor.solve(np.ones(matrix.shape[0]))
    with pytest.raises(RuntimeError, match="factorize"):
        factor.factor()
    factor.factorize(data)
    rhs = np.ones(matrix.shape[0])
    np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)


def test_bad_arguments_are_refused():
    matrix, indptr, indices, data = random_spd(6, n=20)
    with pytest.raises(ValueError, match="ordering"):
        cholmod.SparseCholesky(indptr, indices, 20, "rcm")
    with pytest.raises(ValueError, match="indptr"):
        cholmod.SparseCholesky(indptr[:-1], indices, 20)
    factor = cholmod.SparseCholesky(indptr, indices, 20)
    with pytest.raises(ValueError, match="data"):
        factor.factorize(data[:-1])
    factor.factorize(data)
    with pytest.raises(ValueError, match="rhs"):
        factor.solve(np.ones(19))
    factor.close()
    with pytest.raises(RuntimeError):
        factor.solve(np.ones(20))


def test_without_cvxopt_load_returns_none_with_the_reason(monkeypatch):
    monkeypatch.setitem(sys.modules, "cvxopt", None)  # makes the import fail
    monkeypatch.setattr(cholmod, "_loaded", [])
    assert cholmod.load() is None
    assert "cvxopt" in cholmod.unavailable_reason()
    with pytest.raises(ImportError, match="not available"):
        cholmod.SparseCholesky(np.array([0, 1]), np.array([0]), 1)


@pytest.mark.parametrize("method", cholmod.VERTEX_ORDERINGS)
def test_fill_reducing_orders_are_permutations_that_eliminate_an_arrow_hub_last(method):
    n = 60
    arrow = np.eye(n) * 4.0
    arrow[0, :] = arrow[:, 0] = 1.0  # node 0 joined to every other node
    arrow[0, 0] = n
    indptr, indices, _ = csc(np.tril(arrow))
    order = cholmod.fill_reducing_order(indptr, indices, n, method)
    assert sorted(order.tolist()) == list(range(n))
    assert order[-1] == 0  # eliminating the hub first would fill the whole matrix


@pytest.mark.parametrize("method", ["amd", "nesdis"])
def test_an_order_is_remembered_for_the_same_pattern_in_either_storage(method, monkeypatch):
    """The chordal start (both triangles) and the solver (lower) order the same vertex graph once."""
    matrix = random_spd(3, n=80)[0]
    made = []
    compute = {"amd": "_approximate_minimum_degree", "nesdis": "_nested_dissection"}[method]
    original = getattr(cholmod, compute)
    monkeypatch.setattr(cholmod, compute, lambda *args: made.append(1) or original(*args))
    monkeypatch.setattr(cholmod, "_LAST_ORDERS", {})
    first = cholmod.fill_reducing_order(*csc(matrix)[:2], 80, method)
    again = cholmod.fill_reducing_order(*csc(np.tril(matrix))[:2], 80, method)
    np.testing.assert_array_equal(first, again)
    assert len(made) == 1
    again[:] = 0  # the caller's copy: the remembered order is untouched
    np.testing.assert_array_equal(cholmod.fill_reducing_order(*csc(matrix)[:2], 80, method), first)
    other = matrix.copy()
    other[5, 70] = other[70, 5] = 1.0  # one more edge: ordered anew
    cholmod.fill_reducing_order(*csc(other)[:2], 80, method)
    assert len(made) == 2


def test_block_permutation_keeps_each_block_together_in_the_given_order():
    np.testing.assert_array_equal(cholmod.block_permutation([2, 0, 1], 3), [6, 7, 8, 0, 1, 2, 3, 4, 5])
    with pytest.raises(ValueError, match="method"):
        cholmod.fill_reducing_order(np.array([0, 1]), np.array([0]), 1, "colamd")


@pytest.mark.parametrize("method", cholmod.VERTEX_ORDERINGS)
def test_a_given_block_permutation_factorises_to_the_same_solution(method):
    # a 4×4-block matrix on a random vertex graph, ordered on the vertex graph and expanded
    rng = np.random.default_rng(8)
    p, block = 30, 4
    vertex = (rng.random((p, p)) < 0.1).astype(float)
    vertex = np.maximum(vertex, vertex.T) + np.eye(p)
    a = rng.normal(size=(p * block, p * block)) * np.kron(vertex, np.ones((block, block)))
    # a Aᵀ lives on the blocks of the squared vertex graph, which is then the pattern to order
    matrix = (a @ a.T) * np.kron(np.linalg.matrix_power(vertex, 2) > 0, np.ones((block, block)))
    matrix += p * block * np.eye(p * block)  # diagonally dominant: SPD on its own pattern
    indptr, indices, data = csc(np.tril(matrix))
    vertex_pattern = np.linalg.matrix_power(vertex, 2) > 0
    v_indptr, v_indices, _ = csc(np.tril(vertex_pattern.astype(float)))
    order = cholmod.fill_reducing_order(v_indptr, v_indices, p, method)
    factor = cholmod.SparseCholesky(indptr, indices, p * block, permutation=cholmod.block_permutation(order, block))
    assert factor.ordering == "given"
    factor.factorize(data)
    rhs = rng.normal(size=p * block)
    np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="permutation"):
        cholmod.SparseCholesky(indptr, indices, p * block, permutation=order)


@pytest.mark.parametrize("ordering", ["auto", "amd", "nesdis", "natural", "default"])
def test_block_cholesky_orders_vertex_graphs_and_solves_like_a_dense_solve(ordering):
    rng = np.random.default_rng(12)
    p, block = 25, 3
    vertex = (rng.random((p, p)) < 0.15).astype(float)
    vertex = (np.maximum(vertex, vertex.T) + np.eye(p)) > 0
    blocks = np.kron(vertex, np.ones((block, block)))
    a = rng.normal(size=blocks.shape) * blocks
    matrix = (a + a.T) * blocks + 4 * p * block * np.eye(p * block)  # diagonally dominant on the pattern
    indptr, indices, data = csc(np.tril(matrix))
    v_indptr, v_indices, _ = csc(np.tril(vertex.astype(float)))
    factor = cholmod.block_cholesky(indptr, indices, v_indptr, v_indices, p, block, ordering)
    assert factor.ordering == (cholmod.auto_ordering(p) if ordering == "auto" else ordering)
    factor.factorize(data)
    rhs = rng.normal(size=p * block)
    np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("ordering", ["amd", "nesdis", "natural"])
@pytest.mark.parametrize("seed", range(2))
def test_factor_bytes_bound_the_factor_it_foresees(ordering, seed):
    # L from the supernodal factor holds each supernode's lower trapezoid (amalgamation's zeros
    # included); CHOLMOD stores it as full rectangles (xsize), at most twice that, plus structure
    # and one update matrix, each no larger than the values.
    matrix, indptr, indices, data = random_spd(seed, n=300, density=0.02)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0], ordering)
    foreseen = factor.factor_bytes
    factor.factorize(data)
    values = factor.factor(release=True)[2]
    assert 8 * values.size <= foreseen <= 8 * 5 * values.size
    assert factor.factor_bytes is None  # closed


def test_factor_sizes_are_read_only_from_a_factor_of_this_order():
    matrix, indptr, indices, _ = random_spd(0)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0], "amd")
    assert cholmod._supernodal_sizes(factor._symbolic, matrix.shape[0]) is not None
    assert cholmod._supernodal_sizes(factor._symbolic, matrix.shape[0] + 1) is None  # not this factor
    assert cholmod._supernodal_sizes(object(), matrix.shape[0]) is None  # not a capsule


# A 3D grid's Laplacian (a 7-point stencil, 40³ unknowns): its factor, ~0.17 GiB under nested
# dissection, dwarfs the process's other allocations, so the resident peak's growth is the factor's.
FACTOR_GROWTH = """
    import numpy as np, scipy.sparse as sp
    from posegraph.linalg import cholmod

    def peak_mib():
        return int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1]) / 1024

    side = 40
    path = sp.diags([-np.ones(side - 1), 2.1 * np.ones(side), -np.ones(side - 1)], [-1, 0, 1])
    eye = sp.identity(side)
    grid = (sp.kron(sp.kron(path, eye), eye) + sp.kron(sp.kron(eye, path), eye) + sp.kron(sp.kron(eye, eye), path))
    lower = sp.tril(grid).tocsc()
    factor = cholmod.SparseCholesky(lower.indptr, lower.indices, lower.shape[0], "nesdis")
    foreseen = factor.factor_bytes / 2**20
    open("/proc/self/clear_refs", "w").write("5")
    before = peak_mib()
    factor.factorize(lower.data)
    print(foreseen, peak_mib() - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_factor_bytes_foresee_the_resident_growth_of_the_factorisation():
    import subprocess
    import textwrap
    from pathlib import Path

    pytest.importorskip("pymetis", reason="nested dissection needs pymetis")
    child = subprocess.run([sys.executable, "-c", textwrap.dedent(FACTOR_GROWTH)], capture_output=True, text=True,
                           timeout=300, cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert child.returncode == 0, child.stderr
    foreseen, grown = map(float, child.stdout.split())
    assert grown > 100  # MiB: the factor is what grows
    assert foreseen == pytest.approx(grown, rel=0.15)
