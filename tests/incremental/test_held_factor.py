"""Loop-closure updates on the held factor with exact low-rank terms (:mod:`posegraph.incremental.held_factor`)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from posegraph.incremental import IncrementalOptimizer
from posegraph.incremental.replay import cost_excess
from posegraph.lie.group import SE2, SE3
from posegraph.robust.losses import make_loss
from posegraph.solve import SolverParams

from .test_incremental import _feed, _truth

CASES = {"SE2": (SE2, None), "SE3": (SE3, None), "SE2-cauchy": (SE2, "cauchy"), "SE3-huber": (SE3, "huber")}


def _optimizer(group, loss):
    params = SolverParams(loss=make_loss(loss, dimension=group.dim)) if loss else None
    return IncrementalOptimizer(group) if params is None else IncrementalOptimizer(group, params=params)


def _held_system(opt):
    """``(H̃⁻¹ g, H⁻¹ g)`` at the current poses: the held factor with its low-rank terms made there, and
    a dense solve of H assembled there from scratch (every edge re-linearised, the left-out ones added
    densely)."""
    whole, held = opt._whole, opt.held()
    n = whole.store.num_vertices
    objective = whole._objective(held)
    poses = whole.store.poses.view
    blocks = objective.linearize(poses, objective.evaluate(poses))
    data, g = whole._system(blocks, n, True)
    pattern = whole.pattern
    lower = sp.csc_matrix((data, pattern.indices, pattern.indptr), shape=(pattern.dimension,) * 2).toarray()
    hessian = lower + np.tril(lower, -1).T
    d, store = pattern.block_size, whole.store
    for e, h_ii, h_jj, h_ij in zip(whole.left_out, *blocks.hessian_slice(whole.left_out)):  # not in the pattern
        ci, cj = pattern.variable_of[[store.edge_from.view[e], store.edge_to.view[e]]]
        i, j = d * ci + np.arange(d), d * cj + np.arange(d)
        if ci >= 0:
            hessian[np.ix_(i, i)] += h_ii
        if cj >= 0:
            hessian[np.ix_(j, j)] += h_jj
        if ci >= 0 and cj >= 0:
            hessian[np.ix_(i, j)] += h_ij
            hessian[np.ix_(j, i)] += h_ij.T
    terms = whole._low_rank(blocks, n)
    return whole.held_factor.solve(g, terms), np.linalg.solve(hessian, g)


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_update_on_the_held_factor_is_at_the_batch_optimum(case, monkeypatch):
    """Random graphs with loop closures, a prior and a FIX vertex: after every update the estimate is
    the batch optimum to 1e-6, the held factor served most loop-closure updates (fewer factorisations
    than such updates, held steps taken), and its terms re-linearised at every step make ``H̃`` equal
    H at the current point when every drifted old edge is re-linearised (``H̃⁻¹g = H⁻¹g``): dropped,
    stale (not re-linearised) or kept-across-a-factorisation terms break that equality."""
    group, loss = CASES[case]
    rng = np.random.default_rng(17)
    truth = _truth(rng, group, 48)
    opt = _optimizer(group, loss)
    opt._whole.relinearise = 10**6  # every old edge whose residual moved: H̃ is then H
    monkeypatch.setattr("posegraph.incremental.whole.DRIFT", 0.0)
    monkeypatch.setattr("posegraph.incremental.whole.BREAK_EVEN", np.inf)  # small graphs: factorising is cheaper
    solves = 0
    for v in range(48):
        _feed(opt, rng, group, truth, v, loops=1 if v % 3 else 0, fixed=v == 0)
        if v == 24:
            opt.add_pose_priors([12], truth[12:13], 50.0 * np.eye(group.dim)[None])
        info = opt.update()
        solves += info.kind == "whole"
        if v >= 2:
            _, cost, best, excess = cost_excess(opt)
            assert excess <= 1e-6 or cost - best <= 1e-12, (v, cost, best)
        if info.kind == "whole" and opt._whole.held_factor is not None:
            ours, dense = _held_system(opt)
            assert np.abs(ours - dense).max() <= 1e-7 * max(np.abs(dense).max(), 1e-12), v
    whole = opt._whole
    assert solves >= 10 and whole.held_steps > 0
    assert whole.factorizations < solves


def test_without_relinearising_old_edges_the_held_system_differs_from_h(monkeypatch):
    """The re-linearised old edges matter: with none (``relinearise = 0``), ``H̃`` keeps the old edges'
    blocks from the factorisation's point and ``H̃⁻¹g`` differs from ``H⁻¹g`` after a loop closure moved
    the poses (the estimate is still the optimum: the gradient is exact)."""
    group, rng = SE2, np.random.default_rng(17)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group)
    opt._whole.relinearise = 0
    monkeypatch.setattr("posegraph.incremental.whole.BREAK_EVEN", np.inf)
    differs = 0
    for v in range(30):
        _feed(opt, rng, group, truth, v, loops=1 if v % 3 else 0)
        info = opt.update()
        if info.kind == "whole" and opt._whole.held_factor is not None:
            ours, dense = _held_system(opt)
            differs += np.abs(ours - dense).max() > 1e-6 * np.abs(dense).max()
    _, cost, best, excess = cost_excess(opt)
    assert differs > 0 and (excess <= 1e-6 or cost - best <= 1e-12)


def test_edge_terms_are_the_blocks_summed_with_held_ends_left_out():
    """``edge_terms`` equals a dense sum of the parts' blocks over the free block columns (an end at −1,
    held, adds nothing), minus the unit diagonal of ``unit``; on the columns it names and nowhere else."""
    from posegraph.incremental.held_factor import edge_terms

    rng, d, p = np.random.default_rng(5), 3, 7
    parts, dense = [], np.zeros((p * d, p * d))
    for count in (5, 4):
        ci, cj = rng.integers(-1, p, count), rng.integers(-1, p, count)
        ci[0], cj[1] = -1, -1  # one edge held at each end
        h_ii, h_jj, h_ij = (rng.normal(size=(count, d, d)) for _ in range(3))
        parts.append((h_ii, h_jj, h_ij, ci, cj))
        for k in range(count):
            i, j = slice(d * ci[k], d * ci[k] + d), slice(d * cj[k], d * cj[k] + d)
            if ci[k] >= 0:
                dense[i, i] += h_ii[k]
            if cj[k] >= 0:
                dense[j, j] += h_jj[k]
            if ci[k] >= 0 and cj[k] >= 0:
                dense[i, j] += h_ij[k]
                dense[j, i] += h_ij[k].T
    unit = np.array([p - 1])
    dense[d * (p - 1) :, d * (p - 1) :] -= np.eye(d)
    terms = edge_terms(parts, d, unit)
    expected = np.zeros_like(dense)
    expected[np.ix_(terms.columns, terms.columns)] = terms.matrix
    np.testing.assert_allclose(expected, dense, atol=1e-12)
