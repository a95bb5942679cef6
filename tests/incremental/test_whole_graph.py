"""The whole-graph solver's shortcuts against the direct computations they stand for."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.incremental import IncrementalOptimizer
from posegraph.incremental.replay import cost_excess
from posegraph.lie.group import SE2, SE3
from posegraph.model.graph import PoseGraph
from posegraph.robust.losses import make_loss
from posegraph.solve.objective import Objective

from .test_incremental import _feed, _information, _noisy, _truth


def _random_graph(rng, group, n, m):
    truth = _truth(rng, group, n)
    i = rng.integers(0, n, size=m)
    j = (i + rng.integers(1, n, size=m)) % n
    z = _noisy(rng, group, group.between(truth[i], truth[j]), 0.2)
    poses = truth @ group.exp(rng.normal(scale=0.1, size=(n, group.dim)))
    return PoseGraph(ids=np.arange(n), poses=poses, edge_from=i, edge_to=j, measurements=z,
                     information=_information(group, m), fixed=np.zeros(n, dtype=bool), group=group)


def _dense_hessian(graph, blocks, d):
    h_ii, h_jj, h_ij = blocks.hessian_blocks
    full = np.zeros((graph.num_vertices * d,) * 2)
    for e, (i, j) in enumerate(zip(graph.edge_from, graph.edge_to)):
        a, b = slice(d * i, d * i + d), slice(d * j, d * j + d)
        full[a, a] += h_ii[e]
        full[b, b] += h_jj[e]
        full[a, b] += h_ij[e]
        full[b, a] += h_ij[e].T
    return full


@pytest.mark.parametrize("loss", [None, "cauchy"])
def test_held_factor_with_low_rank_terms_solves_the_full_system(loss):
    """``H̃ = H0 + E_K M E_Kᵀ`` (edges' blocks added, a vertex's unit diagonal taken out) solved by the
    split path solve equals a dense solve of H̃; the decrement from the forward half is ``½ gᵀH̃⁻¹g``; a
    block of ``H̃⁻¹`` from the path columns alone equals the dense one."""
    import scipy.sparse as sp

    from posegraph.incremental.held_factor import HeldFactor, edge_terms
    from posegraph.linalg.cholmod import SparseCholesky

    group, rng = SE3, np.random.default_rng(11)
    graph = _random_graph(rng, group, 9, 14)
    objective = Objective(graph, make_loss(loss, dimension=6) if loss else None)
    blocks = objective.linearize(graph.poses, objective.evaluate(graph.poses))
    d = group.dim
    h0 = _dense_hessian(graph, blocks, d) + 10.0 * np.eye(9 * d)  # a prior on every pose: positive definite
    matrix = sp.csc_matrix(np.where(np.abs(h0) > 0, h0, 0.0))
    factor = SparseCholesky(matrix.indptr, matrix.indices, 9 * d)
    factor.factorize(matrix.data)
    extra, unit = np.array([2, 5, 9, 13]), np.array([4])
    terms = edge_terms([(*blocks.hessian_slice(extra), graph.edge_from[extra], graph.edge_to[extra])], d, unit)
    e = np.zeros((9 * d, terms.columns.shape[0]))
    e[terms.columns, np.arange(terms.columns.shape[0])] = 1.0
    full = h0 + e @ terms.matrix @ e.T
    assert np.linalg.eigvalsh(terms.matrix).min() < 0 < np.linalg.eigvalsh(full).min()  # M indefinite, H̃ not
    held = HeldFactor(factor, 9, graph.num_edges, 0)
    g = rng.normal(size=9 * d)
    half = held.forward(g, terms)
    dense = np.linalg.solve(full, g)
    assert np.abs(held.backward(half) - dense).max() <= 1e-10 * np.abs(dense).max()
    assert half.decrement == pytest.approx(0.5 * g @ dense, rel=1e-10)
    rhs = rng.normal(size=(9 * d, 3))
    assert np.allclose(held.solve(rhs), np.linalg.solve(full, rhs), rtol=0, atol=1e-10 * np.abs(rhs).max())
    columns = np.arange(6 * d, 7 * d)
    inverse = np.linalg.inv(full)[np.ix_(columns, columns)]
    assert np.abs(held.inverse_block(columns) - inverse).max() <= 1e-10 * np.abs(inverse).max()


def _replay(group, seed, max_left_out, count=45):
    rng = np.random.default_rng(seed)
    truth = _truth(rng, group, count)
    opt = IncrementalOptimizer(group)
    opt._whole.max_left_out = max_left_out
    excess = []
    for v in range(count):
        _feed(opt, rng, group, truth, v, loops=1 if v % 4 else 0)
        opt.update()
        _, cost, best, relative = cost_excess(opt)
        excess.append(0.0 if cost - best <= 1e-12 else relative)
    return opt, excess


@pytest.mark.parametrize("group", [SE2, SE3])
def test_left_out_loop_closures_give_the_estimate_of_a_reanalysis(group):
    """Loop closures outside the held pattern, put back as low-rank terms, leave the estimate at the
    batch optimum after every update, as re-analysing for every one of them does."""
    corrected, ours = _replay(group, 21, max_left_out=4)
    analysed, theirs = _replay(group, 21, max_left_out=0)
    assert corrected._whole.corrections > 0 and analysed._whole.corrections == 0
    assert corrected._whole.analyses < analysed._whole.analyses
    assert max(ours) <= 1e-6 and max(theirs) <= 1e-6


@pytest.mark.parametrize("held_steps", [True, False])
def test_a_vertex_joined_only_by_a_left_out_edge_is_solved(held_steps, monkeypatch):
    """A new branch whose only edge is outside the pattern: on the held factor its terms (the edge, the
    vertex's unit diagonal taken out) make H̃ exact there, solved without an analysis; a refactorisation
    finds H without the edge singular: re-analysed, solved."""
    group, rng = SE2, np.random.default_rng(2)
    truth = _truth(rng, group, 31)
    opt = IncrementalOptimizer(group)
    opt._whole.max_columns = opt._whole.max_columns if held_steps else 0
    monkeypatch.setattr("posegraph.incremental.whole.BREAK_EVEN", np.inf)  # a small graph: held steps all the same
    for v in range(30):
        _feed(opt, rng, group, truth, v, loops=0)
        if v == 20:  # a loop closure: the first solve, the first analysis
            opt.add_edges([2], [20], _noisy(rng, group, group.between(truth[2:3], truth[20:21]), 0.1), _information(group, 1))
        opt.update()
    assert opt._whole.pattern is not None
    opt.add_vertices([100], truth[30:31])
    opt.add_edges([3, 5], [100, 25], _noisy(rng, group, group.between(truth[[3, 5]], truth[[30, 25]]), 0.1),
                  _information(group, 2))
    analyses = opt._whole.analyses
    info = opt.update()
    assert info.kind == "whole" and opt._whole.analyses == analyses + (not held_steps)
    _, cost, best, excess = cost_excess(opt)
    assert excess <= 1e-6 or cost - best <= 1e-12


@pytest.mark.parametrize("loss", [None, "huber"])
def test_the_kept_linearisation_extended_equals_a_fresh_one(loss):
    """After odometry-only updates, the last solve's linearisation with the new edges added equals the
    whole graph's evaluated and linearised anew."""
    from posegraph.solve import SolverParams

    group, rng = SE3, np.random.default_rng(4)
    truth = _truth(rng, group, 20)
    params = SolverParams(loss=make_loss(loss, dimension=6) if loss else None)
    opt = IncrementalOptimizer(group, params=params)
    for v in range(15):
        _feed(opt, rng, group, truth, v, loops=1)
        opt.update()
    for v in range(15, 20):
        _feed(opt, rng, group, truth, v, loops=0)
        assert opt.update().kind == "exact"
    whole = opt._whole
    objective, poses = whole._objective(opt.held()), opt._store.poses.view
    kept = whole.last.extended(objective, poses)
    assert kept is not None and kept[0].residuals.shape[0] == opt.num_edges
    evaluation = objective.evaluate(poses)
    blocks = objective.linearize(poses, evaluation)
    assert kept[0].cost == pytest.approx(evaluation.cost, rel=1e-13)
    for name in ("relative", "residuals", "weights"):
        a, b = getattr(kept[0], name), getattr(evaluation, name)
        assert (a is None and b is None) or np.array_equal(a, b)
    for name in ("gradient", "jacobian_inverse", "adjoint"):
        assert np.array_equal(getattr(kept[1], name), getattr(blocks, name))
    poses[3] = poses[3] @ group.exp(np.full((1, 6), 1e-9))[0]  # a kept pose moved: not used
    assert whole.last.extended(objective, poses) is None


def test_chord_steps_are_skipped_while_they_fail_and_probed():
    from posegraph.incremental.whole import CHORD_ODDS, PROBE

    whole = IncrementalOptimizer(SE2)._whole
    assert whole._chord_pays()
    for _ in range(20):
        whole._chord_outcome(False)
    assert whole.chord_odds < CHORD_ODDS
    assert sum(whole._chord_pays() for _ in range(PROBE)) == 1  # one probe in PROBE chances
    for _ in range(20):
        whole._chord_outcome(True)
    assert all(whole._chord_pays() for _ in range(PROBE))


def _drifted_chain_and_closure(group, n, sigma, rng):
    """An optimiser holding an odometry chain of ``n`` poses measured with noise ``sigma`` (it drifts), and
    the loop closure first → last (the true relative pose) staged; returns ``(opt, closure's ½χ² at the
    chain's estimate)``."""
    from posegraph.solve.residuals import cost

    truth = _truth(rng, group, n)
    opt = IncrementalOptimizer(group)
    opt.add_vertices(np.arange(n), truth)
    z = _noisy(rng, group, group.between(truth[:-1], truth[1:]), sigma)
    opt.add_edges(np.arange(n - 1), np.arange(1, n), z, _information(group, n - 1))
    assert opt.update().kind == "exact"
    closure = group.between(truth[:1], truth[-1:])
    opt.add_edges([0], [n - 1], closure, _information(group, 1))
    chain = opt.graph()
    alone = PoseGraph(ids=chain.ids, poses=chain.poses, edge_from=np.array([0]), edge_to=np.array([n - 1]),
                      measurements=closure, information=_information(group, 1), fixed=chain.fixed, group=group)
    return opt, cost(alone, chain.poses)


def test_a_loop_closure_over_a_long_drifted_chain_goes_to_the_batch_solver():
    """Its new term multiplies the cost by orders of magnitude (χ² ≫ DRASTIC_CHI2): the update is the batch
    LM's, at the batch optimum; a loop closure that agrees with the chain (small drift) stays Gauss-Newton's.
    The chain alone is at its optimum (cost ~0), so the ratio DRASTIC alone would call both drastic."""
    from posegraph.incremental.optimizer import DRASTIC_CHI2

    rng = np.random.default_rng(5)
    drifted, added = _drifted_chain_and_closure(SE2, 300, 0.05, rng)
    assert drifted.cost() < 1e-9 and added > DRASTIC_CHI2 * SE2.dim
    assert drifted.update().kind == "full"
    _, _, _, excess = cost_excess(drifted)
    assert excess <= 1e-6
    from posegraph.solve.residuals import cost

    assert drifted.cost() == pytest.approx(cost(drifted.graph()), rel=1e-12)  # terms from the batch's residuals
    calm, added = _drifted_chain_and_closure(SE2, 300, 1e-3, rng)
    assert calm.cost() < 1e-9 and 0 < added < DRASTIC_CHI2 * SE2.dim
    assert calm.update().kind == "whole"
