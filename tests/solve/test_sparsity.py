"""The block pattern and the scatter of per-edge blocks, checked against a dense assembly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posegraph.solve.sparsity import (
    analyze_pattern, gradient_values, hessian_values, lower_csc, lower_matvec, symmetric_block_values, symmetric_blocks,
)  # fmt: skip


def random_graph(rng, n, m):
    """Random edges (with repeated pairs and both directions) between n vertices."""
    edge_from = rng.integers(0, n, m)
    edge_to = (edge_from + rng.integers(1, n, m)) % n
    return edge_from, edge_to


def random_blocks(rng, m):
    """Per-edge [H_ii, H_jj, H_ij] blocks of random 6×12 Jacobians (so H is PSD and symmetric)."""
    jac = rng.normal(size=(m, 6, 12))
    a_i, a_j = jac[..., :6], jac[..., 6:]
    t = lambda x: np.swapaxes(x, -1, -2)  # noqa: E731
    return np.stack([t(a_i) @ a_i, t(a_j) @ a_j, t(a_i) @ a_j], axis=1)


def dense_reference(n, edge_from, edge_to, held, blocks, grads):
    """H and g by a Python loop over edges, held vertices' rows/columns removed."""
    h = np.zeros((6 * n, 6 * n))
    g = np.zeros(6 * n)
    for e, (i, j) in enumerate(zip(edge_from, edge_to)):
        si, sj = slice(6 * i, 6 * i + 6), slice(6 * j, 6 * j + 6)
        h[si, si] += blocks[e, 0]
        h[sj, sj] += blocks[e, 1]
        h[si, sj] += blocks[e, 2]
        h[sj, si] += blocks[e, 2].T
        g[si] += grads[e, 0]
        g[sj] += grads[e, 1]
    keep = np.repeat(~held, 6)
    return h[np.ix_(keep, keep)], g[keep]


@pytest.mark.parametrize("seed", range(6))
def test_scatter_matches_dense_assembly(seed):
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(2, 12)), int(rng.integers(1, 40))
    edge_from, edge_to = random_graph(rng, n, m)
    held = rng.random(n) < 0.3
    pattern = analyze_pattern(n, edge_from, edge_to, held)
    blocks = random_blocks(rng, m)
    grads = rng.normal(size=(m, 2, 6))
    h_ref, g_ref = dense_reference(n, edge_from, edge_to, held, blocks, grads)

    lower = lower_csc(pattern, hessian_values(pattern, blocks)).toarray()
    np.testing.assert_allclose(lower, np.tril(h_ref), rtol=0, atol=1e-12)
    # the three blocks given apart, as linearize returns them, assemble the same
    apart = hessian_values(pattern, tuple(np.ascontiguousarray(blocks[:, k]) for k in range(3)))
    np.testing.assert_array_equal(apart, hessian_values(pattern, blocks))
    # and made slice by slice by a function of the edges' slice, a few edges at a time (the solver's way)
    asked = []

    def by_slice(part):
        asked.append(part)
        return [blocks[part, k] for k in range(3)]

    sliced = lower_csc(pattern, hessian_values(pattern, by_slice, slice_edges=3)).toarray()
    np.testing.assert_allclose(sliced, np.tril(h_ref), rtol=0, atol=1e-12)
    assert [(p.start, p.stop) for p in asked] == [(a, min(a + 3, m)) for a in range(0, m, 3)]
    np.testing.assert_allclose(gradient_values(pattern, grads), g_ref, rtol=0, atol=1e-12)
    assert pattern.dimension == 6 * np.count_nonzero(~held)


@st.composite
def graphs(draw):
    """(n, edge_from, edge_to, held): any multigraph without self-loops, any held subset."""
    n = draw(st.integers(2, 9))
    pairs = draw(
        st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)).filter(lambda p: p[0] != p[1]), min_size=1, max_size=25)
    )
    held = draw(st.lists(st.booleans(), min_size=n, max_size=n))
    return n, np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]), np.array(held)


@settings(max_examples=60, deadline=None)
@given(graphs(), st.integers(0, 2**31 - 1))
def test_scatter_matches_dense_assembly_on_any_graph(graph, seed):
    n, edge_from, edge_to, held = graph
    rng = np.random.default_rng(seed)
    m = edge_from.shape[0]
    pattern = analyze_pattern(n, edge_from, edge_to, held)
    blocks, grads = random_blocks(rng, m), rng.normal(size=(m, 2, 6))
    h_ref, g_ref = dense_reference(n, edge_from, edge_to, held, blocks, grads)
    lower = lower_csc(pattern, hessian_values(pattern, blocks)).toarray()
    np.testing.assert_allclose(lower, np.tril(h_ref), rtol=0, atol=1e-12)
    np.testing.assert_allclose(gradient_values(pattern, grads), g_ref, rtol=0, atol=1e-12)
    # stored entries are exactly the lower triangle of the touched blocks (nothing more)
    touched = np.kron(np.abs(h_ref[::6, ::6]) > 0, np.ones((6, 6), dtype=bool)) | np.kron(np.eye(len(h_ref) // 6, dtype=bool), np.ones((6, 6), dtype=bool))
    assert pattern.nnz == np.count_nonzero(np.tril(touched))


def test_pattern_layout_is_canonical_lower_csc():
    rng = np.random.default_rng(7)
    edge_from, edge_to = random_graph(rng, 9, 30)
    pattern = analyze_pattern(9, edge_from, edge_to, np.eye(9, dtype=bool)[0])
    matrix = lower_csc(pattern, np.ones(pattern.nnz))
    assert matrix.has_canonical_format  # sorted rows, no duplicates
    rows = pattern.indices.astype(np.int64)
    cols = np.repeat(np.arange(pattern.dimension), np.diff(pattern.indptr))
    assert np.all(rows >= cols)  # lower triangle only
    np.testing.assert_array_equal(rows[pattern.diagonal], np.arange(pattern.dimension))
    assert pattern.indptr.dtype == np.int32 and pattern.indices.dtype == np.int32


def test_pattern_is_exactly_the_blocks_touched_by_edges():
    # path 0-1-2-3 plus a chord 0-3; vertex 1 held: blocks (0,0),(2,2),(3,3),(3,2),(3,0) remain.
    edge_from, edge_to = np.array([0, 1, 2, 3]), np.array([1, 2, 3, 0])
    held = np.array([False, True, False, False])
    pattern = analyze_pattern(4, edge_from, edge_to, held)
    block = lower_csc(pattern, np.ones(pattern.nnz)).toarray()[::6, ::6] != 0
    expected = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 1]], dtype=bool)  # variables: vertices 0, 2, 3
    np.testing.assert_array_equal(block, expected)
    np.testing.assert_array_equal(pattern.variable_of, [0, -1, 1, 2])
    assert pattern.nnz == 3 * 21 + 2 * 36


def test_expand_puts_zero_steps_on_held_vertices():
    pattern = analyze_pattern(3, np.array([0, 1]), np.array([1, 2]), np.array([False, True, False]))
    steps = pattern.expand(np.arange(12.0))
    np.testing.assert_array_equal(steps[1], 0)
    np.testing.assert_array_equal(steps[[0, 2]].ravel(), np.arange(12.0))


def test_self_loop_is_refused():
    with pytest.raises(ValueError, match="itself"):
        analyze_pattern(2, np.array([0, 1]), np.array([1, 1]), np.zeros(2, dtype=bool))


def test_scatter_has_no_python_loop_cost_per_edge():
    # One bincount per assembly: the scatter maps are flat position arrays sized by the edges.
    rng = np.random.default_rng(3)
    edge_from, edge_to = random_graph(rng, 50, 400)
    held = np.eye(50, dtype=bool)[0]
    pattern = analyze_pattern(50, edge_from, edge_to, held)
    assert pattern.hessian_positions.shape == (3, 400 * 36)
    assert pattern.gradient_positions.shape == (400 * 12,)
    # every stored entry receives at least one contribution
    received = np.bincount(pattern.hessian_positions.ravel(), minlength=pattern.nnz + 1)
    assert np.all(received[: pattern.nnz] > 0)
    # dropped (slot nnz): the 15 upper entries of a free end's diagonal block, all 36 of a held
    # end's, and the whole H_ij block when either end is held
    at_held = held[edge_from].astype(int) + held[edge_to]
    expected_dropped = np.sum(15 * (2 - at_held) + 36 * at_held + 36 * (at_held > 0))
    assert received[pattern.nnz] == expected_dropped
    assert np.count_nonzero(pattern.gradient_positions == pattern.dimension) == 6 * at_held.sum()


@pytest.mark.parametrize("seed", range(3))
def test_lower_matvec_is_the_stored_lower_triangle_times_a_vector(seed):
    rng = np.random.default_rng(seed)
    n, m = 30, 90
    edge_from, edge_to = random_graph(rng, n, m)
    held = rng.random(n) < 0.2
    pattern = analyze_pattern(n, edge_from, edge_to, held)
    data = hessian_values(pattern, random_blocks(rng, m))
    x = rng.normal(size=pattern.dimension)
    expected = lower_csc(pattern, data).toarray() @ x
    np.testing.assert_allclose(lower_matvec(pattern, data, x), expected, rtol=1e-12, atol=1e-12)
    for chunk in (1, 7, 100):  # a few entries at a time: the same product
        np.testing.assert_allclose(lower_matvec(pattern, data, x, chunk=chunk), expected, rtol=1e-12, atol=1e-12)


def test_entry_columns_are_the_csc_columns():
    rng = np.random.default_rng(3)
    edge_from, edge_to = random_graph(rng, 12, 30)
    pattern = analyze_pattern(12, edge_from, edge_to, np.arange(12) == 4)
    lower = lower_csc(pattern, np.arange(1.0, pattern.nnz + 1)).tocoo()
    order = np.argsort(lower.data)
    np.testing.assert_array_equal(pattern.entry_columns, lower.col[order])


@pytest.mark.parametrize("block", [3, 6])
@pytest.mark.parametrize("seed", range(3))
def test_symmetric_blocks_hold_the_whole_matrix(block, seed):
    """The block-CSR values read from the lower triangle are H itself, both triangles, for any chunk size."""
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    n, m = 25, 70
    edge_from, edge_to = random_graph(rng, n, m)
    held = rng.random(n) < 0.2
    pattern = analyze_pattern(n, edge_from, edge_to, held, block)
    data = rng.normal(size=pattern.nnz)
    lower = lower_csc(pattern, data).toarray()
    full = lower + np.tril(lower, -1).T
    layout = symmetric_blocks(pattern)
    assert np.all(np.diff(layout.indptr) >= 1) and layout.indices.size == 2 * pattern.block_indices.size - pattern.num_variables
    for chunk in (1, 5, 1 << 16):
        values = symmetric_block_values(pattern, layout, data, chunk=chunk)
        matrix = sp.bsr_matrix((values, layout.indices, layout.indptr), shape=full.shape)
        np.testing.assert_array_equal(matrix.toarray(), full)
    np.testing.assert_array_equal(layout.indices[layout.diagonal_blocks], np.arange(pattern.num_variables))


def test_scatter_maps_are_int32_and_assemble_as_int64_ones_do():
    """The 32-bit maps (half the memory) give bit for bit the values of 64-bit ones, and a system too
    large for them keeps 64 bits."""
    from dataclasses import replace

    from posegraph.solve.sparsity import _narrowest

    rng = np.random.default_rng(11)
    edge_from, edge_to = random_graph(rng, 10, 30)
    pattern = analyze_pattern(10, edge_from, edge_to, np.arange(10) == 0)
    assert pattern.hessian_positions.dtype == np.int32 and pattern.gradient_positions.dtype == np.int32
    wide = replace(pattern, hessian_positions=pattern.hessian_positions.astype(np.int64),
                   gradient_positions=pattern.gradient_positions.astype(np.int64))
    blocks, grads = random_blocks(rng, 30), rng.normal(size=(30, 2, 6))
    np.testing.assert_array_equal(hessian_values(pattern, blocks), hessian_values(wide, blocks))
    np.testing.assert_array_equal(gradient_values(pattern, grads), gradient_values(wide, grads))
    assert _narrowest(np.arange(3), 2**31).dtype == np.arange(3).dtype
