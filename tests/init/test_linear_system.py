"""RelativeLeastSquares.restricted: the analysed problem serves a sub-problem (fewer edges counted,
more vertices held) with the solution of that sub-problem analysed on its own."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.init.linear_system import RelativeLeastSquares


def _random_problem(rng, n=30, m=80, r=3, k=2):
    """A connected random graph (chain + random edges) with SPD weights, rotations as transfers, offsets."""
    chain = np.arange(n - 1)
    extra_from, extra_to = rng.integers(0, n, (2, m - (n - 1)))
    keep = extra_from != extra_to
    edge_from = np.concatenate([chain, extra_from[keep]])
    edge_to = np.concatenate([chain + 1, extra_to[keep]])
    count = edge_from.size
    transfer = np.linalg.qr(rng.normal(size=(count, r, r)))[0]
    roots = rng.normal(size=(count, r, r))
    weight = roots @ roots.transpose(0, 2, 1) + 0.1 * np.eye(r)
    offset = weight @ rng.normal(size=(count, r, k))
    values = rng.normal(size=(n, r, k))
    return edge_from, edge_to, transfer, weight, offset, values


def _anchored(held, edge_from, edge_to):
    """``held`` plus the smallest vertex of every component of the edges that holds none."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = held.size
    _, labels = connected_components(coo_matrix((np.ones(edge_from.size), (edge_from, edge_to)), shape=(n, n)))
    out = held.copy()
    for label in np.unique(labels):
        members = np.flatnonzero(labels == label)
        if not held[members].any():
            out[members[0]] = True
    return out


@pytest.mark.parametrize("linear_solver", ["auto", "scipy", "pcg"])
def test_restricted_solve_equals_the_problem_of_the_counted_edges(linear_solver):
    if linear_solver == "pcg":
        pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")
    tolerance = 1e-6 if linear_solver == "pcg" else 1e-10  # CG's relative residual 1e-8
    rng = np.random.default_rng(3)
    edge_from, edge_to, transfer, weight, offset, values = _random_problem(rng)
    n, m = values.shape[0], edge_from.size
    held = np.zeros(n, bool)
    held[0] = True
    counted = rng.uniform(size=m) < 0.7
    counted[: n - 1] = True
    counted[(edge_from == 10) | (edge_to == 10)] = False  # vertex 10 has no counted edge
    counted[(edge_from >= 20) != (edge_to >= 20)] = False  # vertices 20.. are a piece without a held vertex
    sub_held = _anchored(held, edge_from[counted], edge_to[counted])
    assert sub_held[10] and np.count_nonzero(sub_held) >= 3  # vertex 10 and another piece's anchor
    full = RelativeLeastSquares(held, edge_from, edge_to, linear_solver=linear_solver)
    weight_big = np.where(counted[:, None, None], weight, 1e6 * weight)  # uncounted edges would dominate
    restricted = full.restricted(counted, sub_held).solve(values, transfer, weight_big, offset)
    alone = RelativeLeastSquares(sub_held, edge_from[counted], edge_to[counted], linear_solver=linear_solver)
    expected = alone.solve(values, transfer[counted], weight[counted], offset[counted])
    np.testing.assert_allclose(restricted, expected, rtol=0, atol=tolerance)
    np.testing.assert_array_equal(restricted[sub_held], values[sub_held])
    assert not np.allclose(restricted[~sub_held], values[~sub_held])
    # the view shares the analysis and leaves the analysed problem as it was
    np.testing.assert_allclose(
        full.solve(values, transfer, weight, offset),
        RelativeLeastSquares(held, edge_from, edge_to, linear_solver=linear_solver).solve(values, transfer, weight, offset),
        rtol=0, atol=tolerance,
    )  # fmt: skip


def test_every_ordering_gives_the_same_solution_and_a_bad_name_is_refused():
    from posegraph.linalg import cholmod

    rng = np.random.default_rng(4)
    edge_from, edge_to, transfer, weight, offset, values = _random_problem(rng)
    held = np.zeros(values.shape[0], bool)
    held[0] = True
    solutions = [
        RelativeLeastSquares(held, edge_from, edge_to, ordering=ordering).solve(values, transfer, weight, offset)
        for ordering in ("auto", "amd", "nesdis", "natural")
    ]
    for solution in solutions[1:]:
        np.testing.assert_allclose(solution, solutions[0], rtol=0, atol=1e-10)
    with pytest.raises(ValueError, match="ordering"):
        RelativeLeastSquares(held, edge_from, edge_to, ordering="colamd")
    if cholmod.load() is not None:
        problem = RelativeLeastSquares(held, edge_from, edge_to, ordering="nesdis")
        problem.solve(values, transfer, weight, offset)
        assert problem._cholesky.ordering == "nesdis"


def test_a_cholmod_failure_is_raised_when_cholmod_was_asked_for_and_falls_back_only_under_auto(monkeypatch):
    """CHOLMOD's factorisation forced to fail (as at round-off level when weights span many decades):
    ``"cholmod"`` named explicitly raises it; ``"auto"`` turns to SuperLU and gives its solution."""
    from posegraph.linalg import cholmod
    from posegraph.init.linear_system import NotPositiveDefiniteError

    if cholmod.load() is None:
        pytest.skip(f"CHOLMOD is not available: {cholmod.unavailable_reason()}")
    rng = np.random.default_rng(5)
    edge_from, edge_to, transfer, weight, offset, values = _random_problem(rng)
    held = np.zeros(values.shape[0], bool)
    held[0] = True
    calls = []

    def failing(data):
        calls.append(len(data))
        raise NotPositiveDefiniteError("CHOLMOD: matrix not positive definite (forced by the test)")

    solutions = {}
    for linear_solver in ("cholmod", "auto"):
        problem = RelativeLeastSquares(held, edge_from, edge_to, linear_solver=linear_solver)
        monkeypatch.setattr(problem._analysed(), "factorize", failing)
        if linear_solver == "cholmod":
            with pytest.raises(NotPositiveDefiniteError, match="forced by the test"):
                problem.solve(values, transfer, weight, offset)
        else:
            solutions[linear_solver] = problem.solve(values, transfer, weight, offset)
    assert len(calls) == 2  # CHOLMOD was tried both times
    superlu = RelativeLeastSquares(held, edge_from, edge_to, linear_solver="scipy").solve(values, transfer, weight, offset)
    np.testing.assert_array_equal(solutions["auto"], superlu)
