"""Forward solves on the elimination-tree paths of CHOLMOD's supernodal factor (posegraph.linalg.supernodal)."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.linalg import cholmod
from posegraph.linalg.supernodal import SupernodalPaths

pytestmark = pytest.mark.skipif(cholmod.load() is None, reason=f"no CHOLMOD: {cholmod.unavailable_reason()}")


def _chain_with_loops(n: int, seed: int) -> np.ndarray:
    """A positive definite matrix with the pattern of a chain and random loop closures."""
    rng = np.random.default_rng(seed)
    a = np.zeros((n, n))
    for i in range(n - 1):
        a[i, i + 1] = a[i + 1, i] = -1.0
    for i, j in rng.integers(0, n, size=(n // 3, 2)):
        if i != j:
            a[i, j] = a[j, i] = -0.5
    return a + np.diag(np.abs(a).sum(axis=1) + 0.1)


def _factor(a: np.ndarray):
    lower = np.tril(a)
    columns = [np.flatnonzero(lower[:, c]) for c in range(a.shape[0])]
    indptr = np.concatenate(([0], np.cumsum([c.shape[0] for c in columns])))
    indices = np.concatenate(columns)
    factor = cholmod.SparseCholesky(indptr, indices, a.shape[0])
    factor.factorize(lower.T[np.nonzero(lower.T)])  # column by column, rows ascending
    return factor


@pytest.mark.parametrize("columns", [[5], [7, 200, 299], [0, 1, 2], [299]])
def test_unit_forward_gives_the_blocks_of_the_inverse_on_the_paths_only(columns):
    a = _chain_with_loops(300, 0)
    factor = _factor(a)
    y = factor.unit_forward(columns)
    expected = np.linalg.inv(a)[np.ix_(columns, columns)]
    assert np.abs(y.T @ y - expected).max() <= 1e-12 * np.abs(expected).max()
    assert isinstance(factor._paths, SupernodalPaths)  # the factor was read, not the dense fallback
    assert y.shape[0] < a.shape[0]  # only the rows of the elimination-tree paths
    factor._paths = False  # the dense fallback (cvxopt's sys=7, sys=4) gives the same
    dense = factor.unit_forward(columns)
    assert dense.shape[0] == a.shape[0] and np.abs(dense.T @ dense - expected).max() <= 1e-12 * np.abs(expected).max()


def test_a_new_factorisation_is_read_again_and_other_layouts_are_refused():
    a = _chain_with_loops(120, 1)
    factor = _factor(a)
    factor.unit_forward([3])
    factor.factorize(np.tril(2 * a).T[np.nonzero(np.tril(a).T)])
    assert factor._paths is None  # dropped: its views were of the factor CHOLMOD overwrote
    y = factor.unit_forward([3, 50])
    expected = np.linalg.inv(2 * a)[np.ix_([3, 50], [3, 50])]
    assert np.abs(y.T @ y - expected).max() <= 1e-12 * np.abs(expected).max()
    assert SupernodalPaths.read(factor._symbolic, 121) is None  # not this factor's size
    assert SupernodalPaths.read(object(), 120) is None


def test_the_rows_of_a_path_solve_and_the_two_halves_of_a_solve():
    """``unit_forward(…, with_rows=True)`` names the rows of ``L⁻¹ P E`` it returns (the dense forward
    half is zero elsewhere); ``backward(forward(b)) = A⁻¹ b``; ``factor_flops`` is positive and at most
    the dense Cholesky's ``n³/3``."""
    a = _chain_with_loops(300, 1)
    factor = _factor(a)
    columns = [3, 150, 299]
    rows, y = factor.unit_forward(columns, with_rows=True)
    unit = np.zeros((300, 3))
    unit[columns, np.arange(3)] = 1.0
    dense = factor.forward(unit)
    assert np.all(np.diff(rows) > 0) and rows.shape[0] < 300
    assert np.abs(dense[rows] - y).max() <= 1e-13 and np.abs(np.delete(dense, rows, axis=0)).max() == 0.0
    b = np.random.default_rng(1).normal(size=300)
    assert np.abs(factor.backward(factor.forward(b)) - np.linalg.solve(a, b)).max() <= 1e-12 * np.abs(b).max()
    assert 0 < factor.factor_flops <= 300**3 / 3
