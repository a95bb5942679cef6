"""The direct CHOLMOD binding: solutions against dense algebra and scikit-sparse, failures, and its layout check."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest

from posegraph import cholmod

pytestmark = pytest.mark.skipif(
    cholmod.load() is None, reason=f"the system CHOLMOD cannot be used directly: {cholmod.unavailable_reason()}"
)


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


def test_agrees_with_scikit_sparse():
    sksparse = pytest.importorskip("sksparse.cholmod")
    import scipy.sparse as sp

    matrix, indptr, indices, data = random_spd(4, n=300)
    factor = cholmod.SparseCholesky(indptr, indices, matrix.shape[0])
    factor.factorize(data)
    rhs = np.random.default_rng(0).normal(size=(matrix.shape[0], 2))
    theirs = sksparse.cholesky(sp.csc_matrix(matrix), ordering_method="amd", mode="supernodal")(rhs)
    np.testing.assert_allclose(factor.solve(rhs), theirs, rtol=1e-12, atol=1e-14)


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


def test_the_layout_check_reads_cholmod_3_defaults_and_notices_any_difference():
    library = cholmod.load()
    buffer = library.new_common()  # passed the check
    try:
        prefix = cholmod._CommonPrefix.from_buffer(buffer)
        assert cholmod._defaults_match(prefix)
        # the field one place further on, as a shifted layout would read it
        for field, value in [("grow0", 1.25), ("metis_nswitch", 3001), ("postorder", 0)]:
            saved = getattr(prefix, field)
            setattr(prefix, field, value)
            assert not cholmod._defaults_match(prefix), field
            setattr(prefix, field, saved)
        prefix.method[5].nd_small = 200
        assert not cholmod._defaults_match(prefix)
    finally:
        library.finish(buffer)


def test_without_the_library_load_returns_none_with_the_reason(monkeypatch):
    def missing():
        raise OSError("libcholmod.so.3: cannot open shared object file")

    monkeypatch.setattr(cholmod, "_find_library", missing)
    monkeypatch.setattr(cholmod, "_loaded", [])
    assert cholmod.load() is None
    assert "cannot open shared object file" in cholmod.unavailable_reason()
    with pytest.raises(OSError, match="not available"):
        cholmod.SparseCholesky(np.array([0, 1]), np.array([0]), 1)


def test_an_unknown_major_version_is_refused(monkeypatch):
    real, path = cholmod._find_library()

    class Version5:
        def __getattr__(self, name):
            return getattr(real, name)

        @staticmethod
        def cholmod_version(version):
            ctypes.memmove(version, (ctypes.c_int * 3)(5, 2, 0), 3 * ctypes.sizeof(ctypes.c_int))
            return 50200

    monkeypatch.setattr(cholmod, "_find_library", lambda: (Version5(), path))
    monkeypatch.setattr(cholmod, "_loaded", [])
    assert cholmod.load() is None
    assert "CHOLMOD 5.2.0" in cholmod.unavailable_reason()


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


@pytest.mark.parametrize("ordering", ["auto", "amd", "nesdis", "natural"])
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
    # vertex orderings hand CHOLMOD a block permutation; others let it order the scalar pattern
    assert factor.ordering == ("natural" if ordering == "natural" else "given")
    factor.factorize(data)
    rhs = rng.normal(size=p * block)
    np.testing.assert_allclose(factor.solve(rhs), np.linalg.solve(matrix, rhs), rtol=1e-10, atol=1e-12)
