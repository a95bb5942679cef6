"""The gtsam bridge: conversions keyed by vertex id, the factor graph's cost, a timed reference run."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

gtsam = pytest.importorskip("gtsam", reason="the bridge needs gtsam (pip install 'posegraph[gtsam]')")

from posegraph.gtsam_bridge import graph_to_gtsam, poses_to_values, run_gtsam, values_to_poses  # noqa: E402


def test_values_round_trip_by_id_in_any_order():
    rng = np.random.default_rng(0)
    n = 7
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    poses[:, :3, 3] = rng.normal(size=(n, 3))
    ids = np.array([40, 3, 17, 5, 99, 0, 12])
    values = poses_to_values(ids, poses)
    np.testing.assert_allclose(values.atPose3(17).matrix(), poses[2], atol=1e-15)
    perm = rng.permutation(n)
    np.testing.assert_allclose(values_to_poses(values, ids[perm]), poses[perm], atol=1e-15)
    with pytest.raises(KeyError):
        values_to_poses(values, np.array([3, 4]))


def test_factor_graph_cost_is_ours_and_readg2os(shared_dataset):
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.residuals import cost

    path = shared_dataset("smallGrid3D")
    graph = read_g2o(path)
    theirs, values = gtsam.readG2o(str(path), True)
    mine = graph_to_gtsam(graph)
    assert mine.size() == graph.num_edges
    assert mine.error(values) == pytest.approx(theirs.error(values), rel=1e-12)
    assert mine.error(values) == pytest.approx(cost(graph), rel=1e-12)


def test_run_gtsam_reaches_the_reference_cost(shared_dataset):
    from posegraph.io.g2o import read_g2o

    path = shared_dataset("tinyGrid3D")
    graph = read_g2o(path)
    result = run_gtsam(path, graph=graph, init="chordal", relative_tolerance=1e-10, absolute_tolerance=1e-12)
    assert result.final_cost == pytest.approx(9.313909433544, rel=1e-9)
    assert result.converged and 0 < result.iterations == len(result.costs) == len(result.seconds_iterations)
    assert result.costs[-1] == pytest.approx(result.final_cost, rel=1e-9)
    # The anchor (smallest id, no FIX in this file) stays where it started.
    k = int(np.argmin(graph.ids))
    np.testing.assert_allclose(result.poses[k], result.initial_poses[k], atol=1e-9)
    # Starting from given poses and from an in-memory graph gives the same optimum.
    again = run_gtsam(graph, initial=result.initial_poses, method="gn", relative_tolerance=1e-10,
                      absolute_tolerance=1e-12)
    assert again.init == "given" and again.initial_cost == pytest.approx(result.initial_cost, rel=1e-12)
    assert again.final_cost == pytest.approx(result.final_cost, rel=1e-9)
    np.testing.assert_allclose(again.poses, result.poses, atol=1e-6)
