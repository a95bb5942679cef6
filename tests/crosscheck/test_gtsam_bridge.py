"""The gtsam bridge: conversions keyed by vertex id, the factor graph's cost, a timed reference run."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

gtsam = pytest.importorskip("gtsam", reason="the bridge needs gtsam (pip install 'posegraph[gtsam]')")

from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam, poses_to_values, run_gtsam, values_to_poses  # noqa: E402


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


def test_planar_values_round_trip_by_id():
    from posegraph.lie import se2

    rng = np.random.default_rng(1)
    poses = se2.from_xytheta(np.column_stack([rng.normal(size=(6, 2)), rng.uniform(-np.pi, np.pi, 6)]))
    ids = np.array([8, 2, 30, 4, 1, 0])
    values = poses_to_values(ids, poses)
    assert values.atPose2(30).theta() == pytest.approx(se2.to_xytheta(poses[2])[2], abs=1e-15)
    perm = rng.permutation(6)
    np.testing.assert_allclose(values_to_poses(values, ids[perm]), poses[perm], atol=1e-15)


def test_planar_factor_graph_cost_is_ours_with_full_and_diagonal_noise():
    """BetweenFactorPose2 with Ω as given equals our cost; the diagonal copy (for LAGO) keeps the marginal sigmas."""
    from datasets.synthetic import generate
    from posegraph.solve.residuals import cost

    graph = generate("manhattan", 200, seed=3).graph
    coupled = graph.information.copy()
    coupled[:, 0, 1] = coupled[:, 1, 0] = 50.0  # x-y coupling, as manhattan.g2o has
    graph = type(graph)(graph.ids, graph.poses, graph.edge_from, graph.edge_to, graph.measurements, coupled,
                        group=graph.group)
    values = poses_to_values(graph.ids, graph.poses)
    assert graph_to_gtsam(graph).error(values) == pytest.approx(cost(graph), rel=1e-12)
    diagonal = graph_to_gtsam(graph, diagonal=True)
    sigmas = np.sqrt(np.diagonal(np.linalg.inv(coupled[0])))
    np.testing.assert_allclose(diagonal.at(0).noiseModel().sigmas(), sigmas, rtol=1e-12)


def test_run_gtsam_on_a_planar_graph_from_lago_and_from_the_file():
    from datasets.synthetic import generate
    from posegraph.solve import optimize

    graph = generate("manhattan", 300, seed=5).graph
    ours = optimize(graph).final_cost
    for init in ("chordal", "file"):
        result = run_gtsam(graph, init=init)
        assert result.poses.shape == (graph.num_vertices, 3, 3)
        assert result.final_cost == pytest.approx(ours, rel=1e-6)


@pytest.mark.parametrize("kind", ["priors", "toro"])
def test_run_gtsam_on_files_gtsam_reads_otherwise(tmp_path, kind):
    """Prior lines (which ``readG2o`` skips) get their factors; a TORO-order EDGE2 file with EQUIV lines
    (which ``readG2o`` refuses) is given as we read it: gtsam then reaches our cost."""
    from posegraph.solve import SolverParams, optimize
    from tests.io.test_g2o_priors import CHAIN_2D, PRIORS_2D
    from tests.io.test_g2o_toro import TORO_ENTRIES, toro_file

    text = CHAIN_2D + "\n" + PRIORS_2D + "\n" if kind == "priors" else toro_file(TORO_ENTRIES, "EQUIV 3 1")
    path = tmp_path / "in.g2o"
    path.write_text(text)
    from tests.io.helpers import read_with_warnings

    graph = read_with_warnings(path)[0]  # (the EQUIV merge's warning)
    ours = optimize(graph, "chordal", SolverParams(relative_tolerance=1e-14, absolute_tolerance=1e-14))
    theirs = run_gtsam(str(path), graph=graph, initial=ours.poses, relative_tolerance=1e-12, absolute_tolerance=1e-12)
    assert theirs.initial_cost == pytest.approx(ours.final_cost, rel=1e-12)
    assert theirs.final_cost == pytest.approx(ours.final_cost, rel=1e-9, abs=1e-12)
