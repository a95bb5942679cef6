"""gtsam's landmark graph (posegraph.crosscheck.gtsam_landmarks) has our cost; gtsam's LM on it, on
graphs from datasets.synthetic.landmark_graph."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.lie.group import SE2, SE3
from posegraph.solve.landmark_residuals import landmark_cost
from posegraph.solve.residuals import cost

gtsam = pytest.importorskip("gtsam")

from posegraph.crosscheck.gtsam_landmarks import (  # noqa: E402
    gtsam_landmark_cost, gtsam_landmark_graph, landmark_key, run_gtsam_landmarks, values_to_points,
)  # fmt: skip

CASES = [
    (SE2, ("position",)), (SE2, ("bearing",)), (SE2, ("bearing_range",)), (SE2, ("prior",)),
    (SE2, ("position", "bearing", "bearing_range", "prior")), (SE3, ("position",)), (SE3, ("prior",)),
    (SE3, ("position", "prior")),
]  # fmt: skip
IDS = [f"{g.name}-{'+'.join(k)}" for g, k in CASES]


def _full_information(graph, seed):
    """The graph with random full (SPD) Ω on every landmark measurement, so that off-diagonals count."""
    rng = np.random.default_rng(seed)
    families = []
    for family in graph.landmarks.observations:
        q, r = family.information.shape[:2]
        A = rng.normal(size=(q, r, r))
        families.append(replace(family, information=A @ np.swapaxes(A, 1, 2) + 0.5 * np.eye(r)))
    return replace(graph, landmarks=replace(graph.landmarks, observations=tuple(families)))


def ours(graph, poses, points) -> float:
    """Our cost: the pose edges' and priors' terms (``cost`` of the graph without landmarks) plus the landmarks'."""
    return cost(replace(graph, landmarks=None), poses) + landmark_cost(graph.group, poses, points, graph.landmarks)


@pytest.mark.parametrize("offsets", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("group,kinds", CASES, ids=IDS)
def test_gtsam_error_equals_our_cost(group, kinds, seed, offsets):
    graph, _, _ = landmark_graph(group, 7, 5, kinds, noise=0.2, seed=seed, offsets=offsets)
    graph = _full_information(graph, seed)
    points = graph.landmarks.positions
    expected = ours(graph, graph.poses, points)
    assert expected > 1.0
    assert gtsam_landmark_cost(graph) == pytest.approx(expected, rel=1e-9)


def test_keys_and_values():
    graph, truth, points = landmark_graph(SE2, 4, 3, ("bearing_range",), noise=0.0, seed=0)
    factors, values = gtsam_landmark_graph(graph, truth, points)
    assert landmark_key(2) == gtsam.symbol("l", 2) and gtsam.Symbol(landmark_key(2)).string() == "l2"
    np.testing.assert_array_equal(values_to_points(values, graph.landmarks), points)
    assert factors.size() == graph.num_edges + graph.landmarks.num_measurements
    assert factors.error(values) == pytest.approx(0.0, abs=1e-20)


@pytest.mark.parametrize("group,kinds", [(SE2, ("position", "bearing", "bearing_range")), (SE2, ("bearing",)), (SE3, ("position",))], ids=["2d-mixed", "2d-bearing", "3d-position"])
def test_gtsam_lm_lowers_the_cost_and_our_residuals_evaluate_its_solution(group, kinds):
    graph, truth, points = landmark_graph(group, 8, 6, kinds, noise=0.05, seed=3, per_landmark=4, offsets=True)
    result = run_gtsam_landmarks(graph, graph.poses, graph.landmarks.positions)
    assert result.final_cost < result.initial_cost
    assert result.initial_cost == pytest.approx(ours(graph, graph.poses, graph.landmarks.positions), rel=1e-9)
    assert result.final_cost == pytest.approx(ours(graph, result.poses, result.points), rel=1e-9)
    np.testing.assert_allclose(result.poses[0], graph.poses[0], atol=1e-8)  # the gauge anchor held
    assert result.final_cost <= ours(graph, truth, points)  # at or below the truth's cost: an optimum of this cost


def test_fixed_landmarks_are_held_by_gtsam():
    graph, truth, points = landmark_graph(SE2, 6, 4, ("position", "bearing_range"), noise=0.05, seed=5)
    fixed = np.array([True, False, False, True])
    graph = replace(graph, landmarks=replace(graph.landmarks, fixed=fixed))
    result = run_gtsam_landmarks(graph)
    np.testing.assert_allclose(result.points[fixed], graph.landmarks.positions[fixed], atol=1e-8)
    assert result.final_cost < result.initial_cost


def test_the_python_factors_are_named_with_their_count_and_the_variables():
    """Position measurements run as CustomFactors (slow inside gtsam's optimisers: module docstring): the
    note counts them and the values copied per call; a graph of gtsam's own factors gets none."""
    from posegraph.crosscheck.gtsam_landmarks import python_factor_note

    graph, _, _ = landmark_graph(SE2, 7, 5, ("position", "bearing_range"), noise=0.1, seed=0)
    positions = sum(f.count for f in graph.landmarks.observations if f.kind == "position")
    note = python_factor_note(graph)
    assert f"{positions:,} position measurements run as Python CustomFactors" in note
    assert f"{graph.num_vertices + graph.landmarks.count:,} values" in note
    native, _, _ = landmark_graph(SE2, 7, 5, ("bearing", "bearing_range", "prior"), noise=0.1, seed=0)
    assert python_factor_note(native) is None
    assert python_factor_note(replace(native, landmarks=None)) is None
