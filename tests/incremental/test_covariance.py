"""The incremental optimiser's covariances (posegraph.incremental.covariance) against the batch ones of the same graph."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from posegraph.analysis.covariance import joint_covariance, marginal_covariances
from posegraph.incremental import IncrementalOptimizer
from posegraph.lie.group import SE2, SE3, SIM3
from tests.incremental.test_incremental import _feed, _information, _noisy, _truth

GROUPS = {"SE2": SE2, "SE3": SE3, "SIM3": SIM3}


def _assert_batch(opt, ids, pair=None):
    """Marginals of ``ids`` and the joint of ``pair`` equal the batch ones (graph with its held set), rtol 1e-9."""
    graph = replace(opt.graph(), fixed=opt.held())
    index = np.array([int(np.flatnonzero(opt.ids == v)[0]) for v in ids])
    batch = marginal_covariances(graph, graph.poses, index)
    for v, expected in zip(ids, batch):
        np.testing.assert_allclose(opt.marginal_covariance(v), expected, rtol=1e-9, atol=1e-9 * np.abs(batch).max())
    if pair is not None:
        where = [int(np.flatnonzero(opt.ids == v)[0]) for v in pair]
        expected = joint_covariance(graph, graph.poses, np.array(where))
        np.testing.assert_allclose(opt.joint_covariance(pair), expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def _odometry(opt, rng, group, truth, v):
    """Vertex ``v`` from ``v − 1`` by one noisy edge: an exact update."""
    opt.add_vertices([v], truth[v : v + 1])
    opt.add_edges([v - 1], [v], _noisy(rng, group, group.between(truth[v - 1 : v], truth[v : v + 1])), _information(group, 1))
    assert opt.update().kind == "exact"


@pytest.mark.parametrize("name", sorted(GROUPS))
def test_odometry_updates_propagate_the_latest_covariance_exactly(name):
    group, rng = GROUPS[name], np.random.default_rng(11)
    truth = _truth(rng, group, 45)
    opt = IncrementalOptimizer(group)
    for v in range(25):
        _feed(opt, rng, group, truth, v)
    opt.update()  # loop closures: a solved state
    _assert_batch(opt, [24, 7])
    made = opt._covariances.factorizations
    assert made == 1
    for v in range(25, 45):
        _odometry(opt, rng, group, truth, v)
        _assert_batch(opt, [v], pair=(v, 7))  # the latest pose's, and a pair's, every update
    _assert_batch(opt, [24, 30, 7, 0], pair=(40, 31))
    assert opt._covariances.factorizations == made  # the odometry poses were propagated, not solved for


@pytest.mark.parametrize("name", sorted(GROUPS))
def test_a_loop_closure_drops_the_cache_and_the_new_values_are_the_batch_ones(name):
    group, rng = GROUPS[name], np.random.default_rng(12)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group)
    for v in range(29):
        _feed(opt, rng, group, truth, v, loops=1 if v % 5 == 0 else 0)
        opt.update()
        if v > 20:
            opt.marginal_covariance(v)
    before, made = opt.marginal_covariance(28), opt._covariances.factorizations
    assert np.array_equal(opt.marginal_covariance(28), before) and opt._covariances.factorizations == made  # cached
    opt.add_edges([3], [28], _noisy(rng, group, group.between(truth[3:4], truth[28:29])), _information(group, 1))
    assert opt.update().kind != "exact"
    assert opt._whole.current is not None  # covariances were asked: the solve ended on a factor at its poses
    after = opt.marginal_covariance(28)
    assert opt._covariances.factorizations == made and np.abs(after - before).max() > 1e-3 * np.abs(before).max()
    _assert_batch(opt, [28, 3, 15], pair=(28, 3))
    _odometry(opt, rng, group, truth, 29)  # and odometry after it
    _assert_batch(opt, [29], pair=(29, 28))
    opt.add_edges([6], [29], _noisy(rng, group, group.between(truth[6:7], truth[29:30])), _information(group, 1))
    assert opt.update().kind != "exact" and opt._whole.current is not None  # asked after the last solve
    opt.add_edges([9], [29], _noisy(rng, group, group.between(truth[9:10], truth[29:30])), _information(group, 1))
    assert opt.update().kind != "exact" and opt._whole.current is None  # not asked since: no extra factorisation
    _assert_batch(opt, [29])


def test_a_batch_of_new_poses_forming_a_tree_in_one_update():
    """New poses placed from each other (ids not in placement order, edges both ways, a branch): leaves of
    leaves, their marginals and cross-covariances through a common new ancestor."""
    group, rng = SE3, np.random.default_rng(13)
    truth = _truth(rng, group, 20)
    opt = IncrementalOptimizer(group)
    for v in range(12):
        _feed(opt, rng, group, truth, v)
    opt.update()
    opt.marginal_covariance(11)
    ids = np.array([105, 101, 104, 102, 103])  # 101 from 11; 102, 103 from 101; 105 from 103; 104 ← 102 reversed
    poses = truth[[16, 12, 15, 13, 14]]
    opt.add_vertices(ids, poses)
    truth_of = dict(zip(ids.tolist(), poses)) | {11: truth[11]}
    edges = [(11, 101), (101, 102), (101, 103), (103, 105), (104, 102)]
    i, j = np.array(edges).T
    z = _noisy(rng, group, group.between(np.array([truth_of[a] for a in i]), np.array([truth_of[b] for b in j])))
    opt.add_edges(i, j, z, _information(group, len(edges)))
    assert opt.update().kind == "exact"
    made = opt._covariances.factorizations
    _assert_batch(opt, [105, 104, 101, 102, 103, 11, 4], pair=(105, 104))
    _assert_batch(opt, [], pair=(102, 3))
    assert opt._covariances.factorizations == made


@pytest.mark.parametrize("name", sorted(GROUPS))
def test_priors(name):
    """A prior anchors the graph (nothing held); odometry after it propagates; a new prior drops the cache."""
    group, rng = GROUPS[name], np.random.default_rng(14)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group)
    for v in range(20):
        _feed(opt, rng, group, truth, v)
    opt.add_pose_priors([5], truth[5:6], 100.0 * np.eye(group.dim)[None])
    opt.update()
    assert not opt.held().any()
    _assert_batch(opt, [19, 0, 5], pair=(19, 0))
    for v in range(20, 24):
        _odometry(opt, rng, group, truth, v)
    _assert_batch(opt, [23], pair=(23, 0))
    before = opt.marginal_covariance(23)
    opt.add_position_priors([22], truth[22:23, : group.space_dim, group.space_dim], np.eye(group.space_dim)[None] * 50.0)
    opt.update()  # a prior on the latest poses' neighbour: not an exact leaf any more
    assert np.abs(opt.marginal_covariance(23) - before).max() > 1e-3 * np.abs(before).max()
    _assert_batch(opt, [23, 22], pair=(23, 0))


def test_fix_vertices_new_components_and_held_parents():
    """FIX and anchors are zero; a leaf of a held vertex has Σ = N; a new component's leaves propagate from
    its anchor; a batch of a FIX vertex and its leaves."""
    group, rng = SE2, np.random.default_rng(15)
    truth = _truth(rng, group, 40)
    opt = IncrementalOptimizer(group)
    for v in range(15):
        _feed(opt, rng, group, truth, v, fixed=(v == 6))
    opt.update()
    assert opt.held()[opt.ids == 6].all() and opt.held().sum() == 1
    _assert_batch(opt, [14, 7, 5], pair=(14, 7))
    assert not opt.marginal_covariance(6).any()
    opt.add_vertices([200, 201, 202], truth[[30, 31, 32]], [False, False, False])  # a new component
    opt.add_edges([200, 201], [201, 202], group.between(truth[[30, 31]], truth[[31, 32]]), _information(group, 2))
    opt.add_vertices([300, 301], truth[[35, 36]], [True, False])  # a FIX vertex and its leaf
    opt.add_edges([300], [301], group.between(truth[35:36], truth[36:37]), _information(group, 1))
    assert opt.update().kind == "exact"
    made = opt._covariances.factorizations
    assert not opt.marginal_covariance(200).any() and not opt.marginal_covariance(300).any()
    _assert_batch(opt, [201, 202, 301, 14], pair=(202, 301))
    _assert_batch(opt, [], pair=(202, 14))
    assert opt._covariances.factorizations == made


def test_a_robust_loss_is_not_in_the_covariance():
    from posegraph.robust.losses import make_loss
    from posegraph.solve import SolverParams

    group, rng = SE2, np.random.default_rng(16)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group, params=SolverParams(loss=make_loss("cauchy", dimension=3)))
    for v in range(25):
        _feed(opt, rng, group, truth, v)
        if v == 20:  # an outlier: its weight is far from 1
            opt.add_edges([2], [20], truth[:1], _information(group, 1))
        opt.update()
    _assert_batch(opt, [24, 20, 2], pair=(20, 2))
    for v in range(25, 28):
        _odometry(opt, rng, group, truth, v)
    _assert_batch(opt, [27], pair=(27, 20))
    opt.add_edges([5], [27], _noisy(rng, group, group.between(truth[5:6], truth[27:28])), _information(group, 1))
    assert opt.update().kind == "whole"
    assert opt._whole.current is None  # the solve's H carries IRLS weights: not the covariances' H
    _assert_batch(opt, [27, 5])


def test_remove_edges():
    group, rng = SE3, np.random.default_rng(17)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group)
    for v in range(25):
        _feed(opt, rng, group, truth, v, loops=1 if v % 4 == 0 else 0)
        opt.update()
    keys = opt.add_edges([1], [24], _noisy(rng, group, group.between(truth[1:2], truth[24:25])), _information(group, 1))
    opt.update()
    closed = opt.marginal_covariance(24)
    opt.remove_edges(keys)
    opt.update()
    assert np.abs(opt.marginal_covariance(24) - closed).max() > 1e-3 * np.abs(closed).max()
    _assert_batch(opt, [24, 1], pair=(24, 1))


def test_left_out_edges_are_in_the_covariance():
    """Loop closures outside the held pattern (the Woodbury correction) are in H."""
    group, rng = SE2, np.random.default_rng(21)
    truth = _truth(rng, group, 45)
    opt = IncrementalOptimizer(group)
    opt._whole.max_left_out = 4
    for v in range(45):
        _feed(opt, rng, group, truth, v, loops=1 if v % 4 else 0)
        opt.update()
        if opt._whole.left_out.shape[0]:
            _assert_batch(opt, [v, 0], pair=(v, 3))
            assert opt._whole.left_out.shape[0] > 0
            break
    else:
        pytest.fail("no update left an edge out")


def test_optimize_drops_the_cache_and_a_long_chain_is_solved_for():
    from posegraph.incremental import covariance

    group, rng = SE2, np.random.default_rng(18)
    truth = _truth(rng, group, 40)
    opt = IncrementalOptimizer(group)
    for v in range(20):
        _feed(opt, rng, group, truth, v)
    opt.update()
    opt.marginal_covariance(19)
    for v in range(20, 40):
        _odometry(opt, rng, group, truth, v)
    made = opt._covariances.factorizations
    old = covariance.MAX_CHAIN
    covariance.MAX_CHAIN = 5
    try:
        _assert_batch(opt, [39], pair=(39, 2))
    finally:
        covariance.MAX_CHAIN = old
    assert opt._covariances.factorizations == made + 1
    opt.optimize()
    _assert_batch(opt, [39], pair=(39, 2))
    assert opt._covariances.factorizations == made + 2
