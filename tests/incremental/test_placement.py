"""New vertices placed by composition, along an edge and against it (``X_from = X_to · Z⁻¹``)."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.incremental import IncrementalOptimizer
from posegraph.incremental.replay import cost_excess
from posegraph.lie.group import SE2, SE3

from .test_incremental import TOLERANCE, _information, _noisy, _truth


@pytest.mark.parametrize("group", [SE2, SE3], ids=["SE2", "SE3"])
def test_a_vertex_at_the_from_end_of_its_first_edge_is_placed_by_the_inverse(group):
    """Vertex v arrives only as the ``from`` of its edge ``v → v−1``: it must be put at ``X_{v−1} Z⁻¹``
    (zero residual, the update exact and at the optimum); placing it at ``X_{v−1} Z`` fails both."""
    rng = np.random.default_rng(17)
    n = 24
    truth = _truth(rng, group, n)
    opt = IncrementalOptimizer(group)
    far = group.exp(np.full((1, group.dim), 3.0))  # a given pose far from the right one: only placement fixes it
    for v in range(n):
        opt.add_vertices([v], truth[v:v + 1] if v == 0 else far)
        if v:
            z = _noisy(rng, group, group.between(truth[v:v + 1], truth[v - 1:v]))
            opt.add_edges([v], [v - 1], z, _information(group, 1))
            if v % 5 == 0:  # a loop closure, the new vertex again its from end
                z_loop = _noisy(rng, group, group.between(truth[v:v + 1], truth[v - 4:v - 3]))
                opt.add_edges([v], [v - 4], z_loop, _information(group, 1))
        info = opt.update()
        if v and v % 5:
            assert info.kind == "exact"
            placed = opt.pose(v - 1) @ group.inverse(z[0])
            assert np.allclose(opt.pose(v), placed, atol=1e-12)
        if v >= 2:
            _, ours, best, excess = cost_excess(opt)
            assert excess <= TOLERANCE or ours - best <= 1e-12, (v, ours, best)
