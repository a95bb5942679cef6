"""The speed setting: a looser ``tolerance`` defers solves, the excess over the optimum still within it."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.incremental import IncrementalOptimizer
from posegraph.incremental.replay import cost_excess
from posegraph.lie.group import SE2, SE3

from .test_incremental import _information, _noisy, _truth


def _feed_short_loops(opt, rng, group, truth, v):
    """Vertex ``v`` with odometry from v−1 and, from v = 4, a loop closure to v−2, v−3 or v−4: each adds a
    few χ² to a cost that grows with the graph, so later ones fit a loose tolerance's budget."""
    opt.add_vertices([v], truth[v:v + 1])
    if v == 0:
        return
    i = np.array([v - 1] + ([v - int(rng.integers(2, 5))] if v >= 4 else []))
    j = np.full(i.shape, v)
    opt.add_edges(i, j, _noisy(rng, group, group.between(truth[i], truth[j])), _information(group, i.shape[0]))


@pytest.mark.parametrize("group", [SE2, SE3], ids=["SE2", "SE3"])
@pytest.mark.parametrize("tolerance", [0.1, 0.3])
def test_deferred_updates_keep_the_excess_within_the_tolerance(group, tolerance):
    """Loop-closure updates left unsolved (``bounded``) while the excess bound allows, after every update:
    relative excess over the batch optimum ≤ tolerance; a bound that forgets the deferred terms lets it grow past."""
    rng = np.random.default_rng(23)
    n = 70
    truth = _truth(rng, group, n)
    opt = IncrementalOptimizer(group, tolerance=tolerance)
    kinds = []
    for v in range(n):
        _feed_short_loops(opt, rng, group, truth, v)
        kinds.append(opt.update().kind)
        if v >= 2:
            _, ours, best, excess = cost_excess(opt)
            assert excess <= tolerance, (v, kinds[-1], excess)
    assert kinds.count("bounded") >= 5 and kinds.count("whole") >= 3, kinds


def test_a_removal_forgets_the_bound():
    group, rng = SE2, np.random.default_rng(4)
    truth = _truth(rng, group, 30)
    opt = IncrementalOptimizer(group, tolerance=0.05)
    for v in range(30):
        _feed_short_loops(opt, rng, group, truth, v)
        opt.update()
    keys = opt.add_edges([3], [25], group.between(truth[3:4], truth[25:26]), np.eye(3)[None])
    opt.update()
    opt.remove_edges(keys)
    assert opt.update().kind == "whole"  # solved, not deferred: the optimum may have dropped
    assert cost_excess(opt)[3] <= 0.05


@pytest.mark.parametrize("group", [SE2, SE3], ids=["SE2", "SE3"])
def test_a_loose_tolerance_stops_after_a_step_the_model_predicted(group):
    """At tolerance 1e-3 a loop-closure update stops after one step when the cost fell by its Newton
    decrement to within the tolerance (no check step: ``iterations == 1``); after every update the relative
    excess over the batch optimum is still ≤ 1e-3. At the default tolerance every solved update checks."""
    excesses, iterations = {}, {}
    for tolerance in (1e-3, None):
        rng = np.random.default_rng(5)
        n = 60
        truth = _truth(rng, group, n)
        opt = IncrementalOptimizer(group) if tolerance is None else IncrementalOptimizer(group, tolerance=tolerance)
        excesses[tolerance], iterations[tolerance] = [], []
        for v in range(n):
            opt.add_vertices([v], truth[v:v + 1])
            if v:
                i = np.array([v - 1] + ([int(rng.integers(0, v - 8))] if v >= 12 and v % 3 == 0 else []))
                j = np.full(i.shape, v)
                opt.add_edges(i, j, _noisy(rng, group, group.between(truth[i], truth[j])), _information(group, i.shape[0]))
            info = opt.update()
            if info.kind == "whole":
                iterations[tolerance].append(info.iterations)
            if v >= 2:
                excesses[tolerance].append(cost_excess(opt)[3])
    assert max(excesses[1e-3]) <= 1e-3
    assert iterations[1e-3].count(1) >= 3, iterations[1e-3]
    assert min(iterations[None]) >= 2
