"""The incremental optimiser on landmark graphs: the batch optimum after every update, the gauge through
landmarks, exact first sightings, covariances, bad input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.analysis.covariance import marginal_covariances
from posegraph.errors import GraphError
from posegraph.incremental import IncrementalOptimizer
from posegraph.incremental.replay import cost_excess, replay
from posegraph.lie.group import SE2, SE3, SIM3
from posegraph.model.graph import held_vertices
from posegraph.solve import SolverParams, optimize

TOLERANCE = 1e-6  # relative cost excess over the batch optimum of the prefix, asserted after every update (as for pose graphs)

CASES = {
    "SE2-position": (SE2, ("position",), False),
    "SE2-bearings": (SE2, ("bearing_range", "bearing"), False),
    "SE3-offsets-priors": (SE3, ("position", "prior"), True),
}


def _graph(case, seed=1, poses=24, landmarks=8):
    group, kinds, offsets = CASES[case]
    graph, _, _ = landmark_graph(group, poses, landmarks, kinds, noise=0.02, seed=seed, offsets=offsets)
    return graph


@pytest.mark.parametrize("case", sorted(CASES))
def test_replay_is_at_the_batch_optimum_after_every_update(case):
    graph = _graph(case)
    result = replay(graph, check_every=1)
    excess = np.array([check[3] for check in result.checks])
    assert len(result.checks) == graph.num_vertices
    assert excess.max() <= TOLERANCE, excess.max()
    final = optimize(graph, params=SolverParams(relative_tolerance=1e-12, absolute_tolerance=0.0))
    assert result.optimizer.cost() <= final.final_cost * (1 + TOLERANCE)
    assert sorted(result.optimizer.landmark_ids.tolist()) == sorted(graph.landmarks.ids.tolist())


@pytest.mark.parametrize("case", sorted(CASES))
def test_batches_of_several_poses_reach_the_same_optimum(case):
    graph = _graph(case, seed=4)
    one, five = replay(graph, 1).optimizer, replay(graph, 5).optimizer
    assert five.cost() == pytest.approx(one.cost(), rel=TOLERANCE)
    assert sorted(five.landmark_ids.tolist()) == sorted(graph.landmarks.ids.tolist())


def _two_poses_one_landmark(opt, z=(2.0, 1.0)):
    step = SE2.exp(np.array([[1.0, 0.0, 0.3]]))
    opt.add_vertices([0, 1], np.stack([np.eye(3), step[0]]))
    opt.add_edges([0], [1], step, np.eye(3)[None] * 100)
    opt.add_landmarks([10])
    opt.add_landmark_measurements("position", [1], [10], [z], np.eye(2)[None] * 50)
    return opt.update(), step[0]


def test_a_first_sighting_places_its_landmark_exactly_without_a_solve():
    opt = IncrementalOptimizer(SE2)
    info, pose = _two_poses_one_landmark(opt)
    assert info.kind == "exact" and info.cost < 1e-20
    np.testing.assert_allclose(opt.landmark_positions[0], pose[:2, :2] @ [2.0, 1.0] + pose[:2, 2], atol=1e-12)
    opt.add_landmark_measurements("position", [0], [10], [[0.0, 0.0]], np.eye(2)[None])  # seen again: a solve
    info = opt.update()
    assert info.kind == "whole" and info.cost > 0  # Gauss-Newton on the held analysis, the landmark in it
    assert cost_excess(opt)[3] <= TOLERANCE


def _split_by_landmarks():
    """Two odometry chains (ids 0–5 and 100–105) that share landmarks but no pose edge."""
    graph = _graph("SE2-position", seed=7, poses=12, landmarks=6)
    ids = np.r_[np.arange(6), np.arange(100, 106)]
    keep = ~((graph.edge_from == 5) & (graph.edge_to == 6))
    return replace(graph, ids=ids, edge_from=graph.edge_from[keep], edge_to=graph.edge_to[keep],
                   measurements=graph.measurements[keep], information=graph.information[keep])


def test_landmarks_join_components_so_one_pose_is_held():
    graph = _split_by_landmarks()
    assert held_vertices(graph).sum() == 1  # the batch solver's gauge: one component through the landmarks
    opt = replay(graph).optimizer
    assert opt.held().sum() == 1
    assert cost_excess(opt)[3] <= TOLERANCE


def test_a_fixed_landmark_holds_its_position_and_anchors_its_component():
    opt = IncrementalOptimizer(SE2)
    step = SE2.exp(np.array([[1.0, 0.0, 0.3]]))
    opt.add_vertices([0, 1], np.stack([np.eye(3), step[0]]))
    opt.add_edges([0], [1], step, np.eye(3)[None] * 100)
    opt.add_landmarks([10, 11], [[3.0, 1.0], [0.0, 4.0]], fixed=[True, True])
    opt.add_landmark_measurements("position", [0, 1, 1], [10, 10, 11], [[3.1, 1.0], [1.8, 0.4], [-1.0, 3.3]],
                                  np.eye(2)[None].repeat(3, 0))
    opt.update()
    assert not opt.held().any()  # two FIX landmarks tie the poses: no anchor
    np.testing.assert_array_equal(opt.landmark_positions, [[3.0, 1.0], [0.0, 4.0]])
    assert cost_excess(opt)[3] <= TOLERANCE


def test_removing_a_pose_edge_keeps_the_component_joined_through_landmarks():
    graph = _graph("SE2-position", seed=2, poses=16, landmarks=8)
    opt = replay(graph).optimizer
    middle = int(np.flatnonzero((graph.edge_from == 7) & (graph.edge_to == 8))[0])
    opt.remove_edges(opt.edge_keys[[middle]])
    opt.update()
    reduced = opt.graph()
    assert opt.held().sum() == held_vertices(reduced).sum()
    assert cost_excess(opt)[3] <= TOLERANCE


def test_marginal_covariance_is_the_batch_one_with_the_landmarks():
    graph = _graph("SE2-position", seed=3)
    opt = replay(graph).optimizer
    estimate = replace(opt.graph(), fixed=opt.held())
    expected = marginal_covariances(estimate, estimate.poses, points=estimate.landmarks.positions)
    last = int(opt.ids[-1])
    np.testing.assert_allclose(opt.marginal_covariance(last), expected[-1], rtol=1e-9, atol=1e-15)
    joint = opt.joint_covariance([int(opt.ids[3]), last])
    np.testing.assert_allclose(joint[3:, 3:], expected[-1], rtol=1e-9, atol=1e-15)


def _state(opt):
    return opt.num_vertices, opt.landmark_ids.tolist(), opt.landmark_positions.tolist(), opt.cost()


@pytest.mark.parametrize("bad, message", [
    (lambda o: o.add_landmark_measurements("position", [1], [99], [[1.0, 0.0]], np.eye(2)[None]), "landmark id 99"),
    (lambda o: o.add_landmark_measurements("position", [7], [10], [[1.0, 0.0]], np.eye(2)[None]), "vertex id 7"),
    (lambda o: o.add_landmark_measurements("range", [1], [10], [[1.0]], np.eye(1)[None]), "unknown kind"),
    (lambda o: o.add_landmark_measurements("position", [1], [10], [[1.0, 0.0]], -np.eye(2)[None]), "positive definite"),
    (lambda o: o.add_landmark_measurements("position", [1], [10], [[np.nan, 0.0]], np.eye(2)[None]), "not finite"),
    (lambda o: o.add_landmark_measurements("bearing", [1], [10], [[0.1]], np.eye(1)[None], offsets=np.eye(3)[None]),
     "sensor offsets"),
    (lambda o: o.add_landmarks([1]), "already in the graph"),
    (lambda o: o.add_landmarks([10]), "already in the graph"),
    (lambda o: o.add_landmarks([20, 20]), "given twice"),
    (lambda o: o.add_landmarks([20], [[np.inf, 0.0]]), "not finite"),
    (lambda o: o.add_landmarks([20], fixed=[True]), "FIX landmark needs its position"),
    (lambda o: o.add_vertices([10], np.eye(3)[None]), "already in the graph"),
])
def test_bad_landmark_input_names_the_item_and_changes_nothing(bad, message):
    opt = IncrementalOptimizer(SE2)
    _two_poses_one_landmark(opt)
    before = _state(opt)
    with pytest.raises(GraphError, match=message):
        bad(opt)
    assert opt.update().kind == "none" and _state(opt) == before


def test_a_landmark_without_position_or_measurement_is_refused_at_update():
    opt = IncrementalOptimizer(SE2)
    _two_poses_one_landmark(opt)
    before = _state(opt)
    opt.add_landmarks([20])
    with pytest.raises(GraphError, match="landmark id 20: no position given and no measurement"):
        opt.update()
    assert _state(opt) == before
    opt.discard()
    assert opt.update().kind == "none"


def test_sim3_has_no_landmarks():
    with pytest.raises(GraphError, match="Sim"):
        IncrementalOptimizer(SIM3).add_landmarks([0], [[0.0, 0.0, 0.0]])


def _with_wrong_association(case="SE2-position", seed=5):
    """A replayed graph, then one more measurement of landmark 0 from the last pose, far from where it is."""
    graph = _graph(case, seed=seed, poses=20, landmarks=6)
    opt = replay(graph).optimizer
    clean = opt.cost()
    keys = opt.add_landmark_measurements("position", [int(opt.ids[-1])], [int(opt.landmark_ids[0])], [[4.0, -3.0]],
                                         np.eye(2)[None] * 400)
    opt.update()
    return graph, opt, keys, clean


def test_removing_a_wrong_association_returns_to_the_optimum_without_it():
    graph, opt, keys, clean = _with_wrong_association()
    assert opt.cost() > clean + 1.0  # the wrong measurement pulled the estimate
    opt.remove_landmark_measurements(keys)
    info = opt.update()
    assert info.kind == "whole" and opt.cost() == pytest.approx(clean, rel=TOLERANCE)
    assert opt.graph().landmarks.num_measurements == graph.landmarks.num_measurements
    assert cost_excess(opt)[3] <= TOLERANCE


def test_removing_the_only_sightings_that_join_two_components_splits_the_gauge():
    graph = _split_by_landmarks()
    opt = IncrementalOptimizer(SE2)
    replay(graph, optimizer=opt)
    assert opt.held().sum() == 1
    model = opt.graph().landmarks
    pose, landmark = np.concatenate([f.pose for f in model.observations]), np.concatenate([f.landmark for f in model.observations])
    first_chain = pose < 6
    shared = np.intersect1d(landmark[first_chain], landmark[~first_chain])
    (family,) = opt._landmarks.families.values()
    keys = family.keys.view[np.isin(family.landmark.view, shared) & (family.pose.view < 6)]  # the first observers
    opt.remove_landmark_measurements(keys)
    opt.update()
    assert opt.held().sum() == 2 == held_vertices(opt.graph()).sum()
    assert cost_excess(opt)[3] <= TOLERANCE


def test_an_unknown_or_repeated_measurement_key_changes_nothing():
    graph, opt, keys, _ = _with_wrong_association()
    before = _state(opt)
    with pytest.raises(GraphError, match="no measurement with key 999"):
        opt.remove_landmark_measurements([999])
    with pytest.raises(GraphError, match="given twice"):
        opt.remove_landmark_measurements([keys[0], keys[0]])
    assert opt.update().kind == "none" and _state(opt) == before


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_cost_after_every_update_is_the_cost_of_the_graph_so_far(case):
    from posegraph.solve.residuals import cost

    graph = _graph(case, seed=6)
    checked = []

    def check(result, number):
        opt = result.optimizer
        so_far = opt.graph()
        checked.append(abs(opt.cost() - cost(so_far, so_far.poses, so_far.landmarks.positions if so_far.landmarks else None)))

    replay(graph, progress=check)
    assert len(checked) == graph.num_vertices and max(checked) <= 1e-9
