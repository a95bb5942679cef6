"""``SolverParams.estimate_callback``: each iteration's record with the poses it ends at, never changed afterwards."""

from __future__ import annotations

import numpy as np
import pytest

from datasets.synthetic import grid
from posegraph.solve import SolverParams, optimize


def test_the_callback_sees_every_iteration_and_its_poses():
    graph = grid(3, 3, 2, seed=2).graph
    seen = []
    result = optimize(graph, params=SolverParams(estimate_callback=lambda record, poses, points: seen.append(
        (record, poses, poses.copy(), points))))
    assert [record.iteration for record, *_ in seen] == list(range(1, result.iterations + 1))
    assert [record.cost for record, *_ in seen] == [record.cost for record in result.records]
    np.testing.assert_array_equal(seen[-1][1], result.poses)
    for record, poses, copy, points in seen:
        np.testing.assert_array_equal(poses, copy)  # the solver never wrote into an array it handed out
        assert points is None
    assert not np.array_equal(seen[0][1], result.poses)  # the first iteration's estimate, not the result


def test_a_callback_that_is_not_callable_is_refused():
    with pytest.raises(ValueError, match="estimate_callback"):
        SolverParams(estimate_callback=3)
