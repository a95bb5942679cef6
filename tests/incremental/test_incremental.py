"""The incremental optimiser against batch solves of the same graph, after every update."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.errors import GraphError
from posegraph.incremental import IncrementalOptimizer
from posegraph.incremental.replay import cost_excess
from posegraph.lie.group import SE2, SE3, SIM3

GROUPS = {"SE2": SE2, "SE3": SE3, "SIM3": SIM3}
TOLERANCE = 1e-6  # relative cost excess over the batch optimum asserted after every update


def _random_steps(rng, group, count, scale=1.0):
    xi = rng.normal(scale=0.1, size=(count, group.dim))
    xi[:, list(group.translation_axes)] = rng.normal(scale=scale, size=(count, len(group.translation_axes)))
    return group.exp(xi)


def _noisy(rng, group, z, sigma=0.02):
    return z @ group.exp(rng.normal(scale=sigma, size=(z.shape[0], group.dim)))


def _information(group, count):
    base = np.diag(np.linspace(50.0, 200.0, group.dim))
    base[0, 1] = base[1, 0] = 5.0
    return np.broadcast_to(base, (count, group.dim, group.dim)).copy()


def _truth(rng, group, n):
    poses = [np.eye(group.matrix_size)]
    for step in _random_steps(rng, group, n - 1):
        poses.append(poses[-1] @ step)
    return np.array(poses)


def _feed(opt, rng, group, truth, v, loops=2, fixed=False):
    """Add vertex ``v`` (with odometry from v−1 and up to ``loops`` random loop closures)."""
    guess = truth[v] @ group.exp(rng.normal(scale=0.05, size=(1, group.dim)))
    opt.add_vertices([v], guess, [fixed])
    if v == 0:
        return
    others = rng.choice(v, size=min(v, rng.integers(0, loops + 1)), replace=False) if v > 2 else np.zeros(0, int)
    i = np.r_[v - 1, others].astype(np.int64)
    j = np.full(i.shape, v, dtype=np.int64)
    z = _noisy(rng, group, group.between(truth[i], truth[j]))
    opt.add_edges(i, j, z, _information(group, i.shape[0]))


@pytest.mark.parametrize("name", sorted(GROUPS))
def test_estimate_is_the_batch_optimum_after_every_update(name):
    group, rng = GROUPS[name], np.random.default_rng(3)
    truth = _truth(rng, group, 40)
    opt = IncrementalOptimizer(group)
    for v in range(40):
        _feed(opt, rng, group, truth, v, loops=1 if v % 3 else 0)
        if v == 20:  # a prior on a pose in the middle: the component is then anchored by it
            opt.add_pose_priors([10], truth[10:11], 100.0 * np.eye(group.dim)[None])
        opt.update()
        if v >= 2:
            _, ours, best, excess = cost_excess(opt)
            assert excess <= TOLERANCE or ours - best <= 1e-12, (v, ours, best)
    assert not opt.held().any()  # the prior anchors the graph: no vertex held


def test_fixed_vertices_stay_and_batches_of_many():
    group, rng = SE2, np.random.default_rng(5)
    truth = _truth(rng, group, 60)
    opt = IncrementalOptimizer(group)
    for start in range(0, 60, 7):
        for v in range(start, min(start + 7, 60)):
            _feed(opt, rng, group, truth, v, fixed=(v == 30))
        opt.update()
        _, ours, best, excess = cost_excess(opt)
        assert excess <= TOLERANCE or ours - best <= 1e-12
    held = opt.held()
    assert held[opt.ids == 30].all() and held.sum() == 1  # FIX replaces the anchor
    assert np.allclose(opt.pose(30), opt.graph().poses[30])


def test_position_priors_and_a_second_component():
    group, rng = SE3, np.random.default_rng(9)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group)
    for v in range(15):
        _feed(opt, rng, group, truth, v)
        opt.update()
    opt.add_vertices([100, 101], truth[[3, 4]])  # a new component of its own
    opt.add_edges([100], [101], group.between(truth[3:4], truth[4:5]), _information(group, 1))
    opt.update()
    assert opt.held()[opt.ids == 100].all()
    opt.add_edges([14], [100], _noisy(rng, group, group.between(truth[14:15], truth[3:4])), _information(group, 1))
    opt.update()  # joins the components: vertex 100 is no longer an anchor
    assert not opt.held()[opt.ids == 100].any()
    opt.add_position_priors([5, 12], truth[[5, 12], :3, 3] + 0.1, np.tile(np.eye(3), (2, 1, 1)))
    opt.update()
    _, ours, best, excess = cost_excess(opt)
    assert excess <= TOLERANCE or ours - best <= 1e-12


def test_remove_edges_round_trip():
    group, rng = SE2, np.random.default_rng(1)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group)
    for v in range(30):
        _feed(opt, rng, group, truth, v, loops=0)
        opt.update()
    before = opt.poses
    keys = opt.add_edges([2], [27], _noisy(rng, group, group.between(truth[2:3], truth[27:28]), 0.3),
                         _information(group, 1))
    opt.update()
    assert not np.allclose(opt.poses, before)
    opt.remove_edges(keys)
    opt.update()
    assert opt.num_edges == 29
    assert np.allclose(opt.poses, before, atol=1e-6)  # back at the odometry-only optimum
    _, ours, best, excess = cost_excess(opt)
    assert ours - best <= 1e-10


def test_covariances_equal_the_batch_ones():
    from posegraph.analysis.covariance import joint_covariance, marginal_covariances

    group, rng = SE3, np.random.default_rng(2)
    truth = _truth(rng, group, 25)
    opt = IncrementalOptimizer(group)
    for v in range(25):
        _feed(opt, rng, group, truth, v)
        opt.update()
    graph = opt.graph()
    batch = marginal_covariances(graph, graph.poses)
    assert np.allclose(opt.marginal_covariance(24), batch[24], rtol=1e-9, atol=1e-15)
    joint = opt.joint_covariance([3, 24])
    assert np.allclose(joint, joint_covariance(graph, graph.poses, np.array([3, 24])), rtol=1e-9, atol=1e-15)


def test_graph_round_trips_through_g2o(tmp_path):
    from posegraph.io.g2o import read_g2o, write_g2o

    group, rng = SE2, np.random.default_rng(4)
    truth = _truth(rng, group, 12)
    opt = IncrementalOptimizer(group)
    for v in range(12):
        _feed(opt, rng, group, truth, v)
    opt.update()
    write_g2o(tmp_path / "out.g2o", opt.graph())
    back = read_g2o(tmp_path / "out.g2o")
    assert back.num_vertices == 12 and back.num_edges == opt.num_edges
    assert np.allclose(back.poses, opt.poses, atol=1e-6)


def _state(opt):
    return (opt.poses, opt.ids, opt.edge_keys, opt.num_edges)


@pytest.mark.parametrize("bad", ["unknown vertex", "duplicate id", "duplicate in batch", "bad information",
                                 "indefinite information", "nan pose", "self loop", "unknown key", "shape"])
def test_bad_inputs_raise_naming_the_item_and_change_nothing(bad):
    group, rng = SE2, np.random.default_rng(0)
    truth = _truth(rng, group, 5)
    opt = IncrementalOptimizer(group)
    for v in range(5):
        _feed(opt, rng, group, truth, v)
    keys = opt.add_edges([0], [4], group.between(truth[:1], truth[4:5]), _information(group, 1))
    opt.update()
    state = _state(opt)
    z, w = group.between(truth[:2], truth[1:3]), _information(group, 2)
    calls = {
        "unknown vertex": (lambda: opt.add_edges([0, 1], [1, 77], z, w), "77"),
        "duplicate id": (lambda: opt.add_vertices([3], truth[:1]), "3"),
        "duplicate in batch": (lambda: opt.add_vertices([8, 8], truth[:2]), "8"),
        "bad information": (lambda: opt.add_edges([0, 1], [1, 2], z, np.r_[w[:1], np.full((1, 3, 3), np.nan)]), "#1"),
        "indefinite information": (lambda: opt.add_edges([0, 1], [1, 2], z, np.r_[w[:1], -w[1:]]), "#1"),
        "nan pose": (lambda: opt.add_vertices([9], np.full((1, 3, 3), np.nan)), "#0"),
        "self loop": (lambda: opt.add_edges([2], [2], z[:1], w[:1]), "itself"),
        "unknown key": (lambda: opt.remove_edges([keys[0] + 100]), str(keys[0] + 100)),
        "shape": (lambda: opt.add_edges([0, 1], [1], z, w), "edges"),
    }
    call, named = calls[bad]
    with pytest.raises(GraphError, match=named):
        call()
    info = opt.update()
    assert info.kind == "none"
    after = _state(opt)
    assert all(np.array_equal(a, b) for a, b in zip(state, after))


def test_robust_loss_applies():
    from posegraph.robust.losses import make_loss
    from posegraph.solve import SolverParams

    group, rng = SE2, np.random.default_rng(6)
    truth = _truth(rng, group, 30)
    params = SolverParams(loss=make_loss("cauchy", dimension=3))
    opt = IncrementalOptimizer(group, params=params)
    for v in range(30):
        _feed(opt, rng, group, truth, v)
        if v == 20:  # an outlier
            opt.add_edges([2], [20], truth[:1], _information(group, 1))
        opt.update()
    _, ours, best, excess = cost_excess(opt)
    assert excess <= TOLERANCE or ours - best <= 1e-10
    assert abs(opt.cost() - ours) <= 1e-9 * max(ours, 1.0)


def test_verify_mode_is_exact():
    group, rng = SE3, np.random.default_rng(8)
    truth = _truth(rng, group, 20)
    opt = IncrementalOptimizer(group, verify=True)
    for v in range(20):
        _feed(opt, rng, group, truth, v)
        opt.update()
    _, ours, best, excess = cost_excess(opt)
    assert ours - best <= 1e-9 * max(best, 1.0)


def test_an_edge_between_two_held_vertices_counts_in_the_cost_without_a_solve():
    from posegraph.solve.residuals import cost

    opt = IncrementalOptimizer(SE2)
    opt.add_vertices([0, 1], np.stack([np.eye(3), SE2.exp(np.array([1.0, 0.0, 0.0]))]), [True, True])
    opt.add_edges([0], [1], SE2.exp(np.array([[0.5, 0.0, 0.0]])), np.eye(3)[None])
    assert opt.update().kind == "exact"
    assert opt.cost() == pytest.approx(cost(opt.graph()), rel=1e-12) and opt.cost() > 0.1


def test_a_whole_graph_in_one_update_predicts_blocks_for_its_last_loop_closures_only():
    from posegraph.incremental.whole import PREDICT, PREDICTED_LOOPS

    group, rng = SE2, np.random.default_rng(5)
    n = 400
    truth = _truth(rng, group, n)
    i = np.r_[np.arange(n - 1), rng.integers(0, n - 50, 300)]
    j = np.r_[np.arange(1, n), rng.integers(n - 40, n, 300)]
    opt = IncrementalOptimizer(group)
    opt.add_vertices(np.arange(n), truth)
    opt.add_edges(i, j, _noisy(rng, group, group.between(truth[i], truth[j])), _information(group, i.shape[0]))
    opt.update()
    pattern = opt._whole.pattern
    blocks = pattern.block_indptr[-1] - pattern.num_variables  # stored off-diagonal blocks
    cone = sum(4 * s + 5 for s in range(1, PREDICT + 1))
    assert blocks <= i.shape[0] + pattern.num_vertices + PREDICTED_LOOPS * cone
    assert cost_excess(opt)[3] <= TOLERANCE


def _drifting_route(n=300, seed=9):
    """An SE(2) odometry route with rotational drift, as an optimiser, and a loop closure first → last (true)."""
    group, rng = SE2, np.random.default_rng(seed)
    truth = _truth(rng, group, n)
    opt = IncrementalOptimizer(group)
    opt.add_vertices(np.arange(n), truth)
    z = _noisy(rng, group, group.between(truth[:-1], truth[1:]), sigma=0.05)
    opt.add_edges(np.arange(n - 1), np.arange(1, n), z, _information(group, n - 1))
    opt.update()
    return opt, group.between(truth[:1], truth[-1:])


def test_gauss_newton_that_runs_out_of_steps_says_so_and_keeps_its_progress():
    from posegraph.incremental.commit import commit_batch
    from posegraph.solve.residuals import cost

    opt, z = _drifting_route()
    opt.add_edges([0], [opt.num_vertices - 1], z, _information(SE2, 1))
    batch, opt._batch = opt._batch, None
    commit_batch(opt, batch)  # the loop closure in the graph, no solve yet
    start = cost(opt.graph())
    ok, iterations, _ = opt._whole.solve(opt.held(), 1e-12, max_iterations=1)
    assert not ok and iterations == 1 and cost(opt.graph()) < start


def test_a_long_loop_closure_ends_at_the_batch_optimum():
    opt, z = _drifting_route()
    opt.add_edges([0], [opt.num_vertices - 1], z, _information(SE2, 1))
    info = opt.update()
    assert info.kind in ("whole", "full") and cost_excess(opt)[3] <= TOLERANCE
