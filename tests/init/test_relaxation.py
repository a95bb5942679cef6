"""The landmark graph's relaxed start (posegraph/init/relaxation.py): exact without noise, better than
the pose edges' chordal start where the landmarks close the loops."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.init import initialize
from posegraph.init.relaxation import relaxation_anchors, relaxed_start, rotation_basis, rotation_coordinates
from posegraph.lie.group import SE2, SE3
from posegraph.model.landmarks import Observations
from posegraph.solve import optimize
from posegraph.solve.residuals import cost


@pytest.mark.parametrize("r", [2, 3])
def test_rotation_coordinates_rebuild_the_rotation(r):
    group = SE2 if r == 2 else SE3
    rotations = group.exp(np.random.default_rng(0).normal(size=(5, group.dim)))[:, :r, :r]
    basis = rotation_basis(r)
    np.testing.assert_allclose(np.einsum("nk,kab->nab", rotation_coordinates(rotations, basis), basis), rotations, atol=1e-14)


@pytest.mark.parametrize("group, kinds, offsets", [
    (SE2, ("position",), False), (SE2, ("bearing_range", "prior"), False), (SE2, ("position", "bearing"), False),
    (SE3, ("position",), True), (SE3, ("position", "prior"), True),
])  # fmt: skip
def test_noise_free_graphs_start_at_their_truth(group, kinds, offsets):
    graph, truth, _ = landmark_graph(group, 15, 9, kinds, noise=0.0, seed=3, offsets=offsets)
    graph = replace(graph, poses=truth @ group.exp(np.random.default_rng(1).normal(size=(15, group.dim)) * 0.3))
    graph = replace(graph, poses=np.concatenate([truth[:1], graph.poses[1:]]))  # the anchor where the truth is
    np.testing.assert_allclose(relaxed_start(graph), truth, atol=1e-9)


def _loop_closed_by_landmarks(seed: int):
    """A noisy odometry chain whose loops only the landmarks close (Victoria Park's shape)."""
    return landmark_graph(SE2, 60, 12, ("position",), noise=0.05, seed=seed, per_landmark=8)[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_relaxation_starts_nearer_than_the_pose_edges_alone(seed):
    graph = _loop_closed_by_landmarks(seed)
    relaxed = relaxed_start(graph)
    edges_only = initialize(replace(graph, landmarks=None), "chordal")
    assert cost(graph, relaxed) < cost(graph, edges_only)
    assert optimize(graph, relaxed).iterations <= optimize(graph, edges_only).iterations
    np.testing.assert_array_equal(initialize(graph, "chordal"), relaxed)  # the default start of a landmark graph


def test_points_fixed_or_unreached_are_held_and_a_singular_system_falls_back():
    graph, _, _ = landmark_graph(SE2, 8, 4, ("position",), noise=0.02, seed=5)
    lone = Observations("bearing", np.array([2]), np.array([4]), np.array([[0.4]]), np.array([[[50.0]]]), tag="EDGE_BEARING_SE2_XY")
    landmarks = replace(graph.landmarks, ids=np.append(graph.landmarks.ids, 999), positions=np.vstack([graph.landmarks.positions, [[1.0, 2.0]]]),
                        fixed=np.append(graph.landmarks.fixed, False), observations=graph.landmarks.observations + (lone,))  # fmt: skip
    graph = replace(graph, landmarks=landmarks)
    poses = relaxed_start(graph)  # the bearing-only landmark is held, not a singular column
    assert np.all(np.isfinite(poses)) and relaxation_anchors(graph).sum() == 1
    no_edges = replace(graph, edge_from=np.zeros(0, int), edge_to=np.zeros(0, int), measurements=np.zeros((0, 3, 3)),
                       information=np.zeros((0, 3, 3)), edge_lines=None)  # fmt: skip
    assert np.all(np.isfinite(initialize(no_edges, "chordal")))  # poses no term fixes: the pose edges' start


DATA = Path(__file__).resolve().parents[3] / "data-landmarks"
VICTORIA = DATA / "victoriaPark-full.g2o.gz"


def _start_cost(graph, poses) -> float:
    """The cost LM starts from: the poses and the landmarks placed from them."""
    from posegraph.init.landmarks import initialize_landmarks
    from posegraph.solve.objective import Objective

    return Objective(graph).evaluate(poses, initialize_landmarks(graph, poses)[0]).cost


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_unit_passes_start_no_worse_than_the_plain_relaxation(seed):
    graph = _loop_closed_by_landmarks(seed)
    plain, unit = relaxed_start(graph, unit_passes=0), relaxed_start(graph)
    assert _start_cost(graph, unit) <= _start_cost(graph, plain)
    assert cost(graph, unit) < cost(graph, plain)  # the pose edges see the rotations the plain relaxation shrank


@pytest.mark.parametrize("name", ["dlr.g2o", "victoriaPark-full.g2o.gz", "world-2000-default.g2o.gz", "world-2000-lownoise-full.g2o.gz"])
def test_the_unit_passes_start_no_worse_on_the_public_files(name):
    from posegraph.io.g2o import read_g2o

    if not (DATA / name).exists():
        pytest.skip(f"{DATA / name} (fetched outside the repository: benchmarks/bench_landmarks.py) is absent")
    graph = read_g2o(DATA / name)
    plain, unit = _start_cost(graph, relaxed_start(graph, unit_passes=0)), _start_cost(graph, relaxed_start(graph))
    assert unit < plain  # DLR: χ² 474,828 → 59,108 (optimum 56,858)


@pytest.mark.skipif(not VICTORIA.exists(), reason=f"{VICTORIA} (g2o_frontend's Victoria Park, fetched outside the repository) is absent")
def test_victoria_park_from_the_relaxation():
    from posegraph.io.g2o import read_g2o

    graph = read_g2o(VICTORIA)
    result = optimize(graph)
    assert result.converged and result.iterations <= 15 and 2 * result.final_cost < 400.0  # g2o's LM: 87,156


def test_the_unit_passes_go_on_until_settled(monkeypatch):
    from posegraph.init import relaxation

    graph = _loop_closed_by_landmarks(0)  # its second pass turns no rotation by more than 0.1°: settled there
    np.testing.assert_array_equal(relaxed_start(graph), relaxed_start(graph, unit_passes=relaxation.UNIT_PASSES))
    monkeypatch.setattr(relaxation, "SETTLED_DEGREES", 0.0)  # never settled: as many passes as allowed
    np.testing.assert_array_equal(relaxed_start(graph), relaxed_start(graph, unit_passes=relaxation.MAX_UNIT_PASSES))
    assert not np.array_equal(relaxed_start(graph), relaxed_start(graph, unit_passes=relaxation.UNIT_PASSES))


@pytest.mark.parametrize("name", ["dlr.g2o", "victoriaPark-full.g2o.gz", "world-2000-lownoise-full.g2o.gz"])
def test_the_settled_start_is_no_worse_than_two_passes_on_the_public_files(name):
    from posegraph.io.g2o import read_g2o

    if not (DATA / name).exists():
        pytest.skip(f"{DATA / name} (fetched outside the repository: benchmarks/bench_landmarks.py) is absent")
    graph = read_g2o(DATA / name)
    two, settled = relaxed_start(graph, unit_passes=2), relaxed_start(graph)
    assert _start_cost(graph, settled) <= _start_cost(graph, two)  # DLR: χ² 59,108 → 58,537 (4 passes)
    assert np.array_equal(settled, two) == (name != "dlr.g2o")  # the others' second pass turns ≤ 1.04°


def test_a_pass_settles_by_the_turn_of_the_map_not_of_one_pose():
    from posegraph.init.relaxation import _turn

    before = SE2.exp(np.random.default_rng(6).normal(size=(200, 3)))[:, :2, :2]
    turns = np.full(200, np.radians(1.0))
    turns[17] = np.radians(90.0)  # one loosely held pose swinging round
    after = before @ SE2.exp(np.stack([np.zeros(200), np.zeros(200), turns], axis=1))[:, :2, :2]
    assert abs(_turn(before, after, SE2) - 1.0) < 1e-9
    assert _turn(before[:0], after[:0], SE2) == 0.0
