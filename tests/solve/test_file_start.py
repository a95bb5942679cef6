"""A landmark graph's file values as its start (posegraph/solve/file_start.py): the rows counted; values
that fit start LM where they are, others from the relaxation; the same optimum; pose graphs and other
starts as the initialisers make them."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.init import initialize
from posegraph.init.relaxation import relaxed_start
from posegraph.solve.file_start import FIT_COST_PER_ROW, file_cost, file_values_fit, start_poses
from posegraph.lie.group import SE2, SE3
from posegraph.solve import optimize
from posegraph.solve.objective import Objective

DATA = Path(__file__).resolve().parents[3] / "data-landmarks"


@pytest.mark.parametrize("group, kinds, offsets", [
    (SE2, ("position",), False), (SE2, ("bearing_range", "prior"), False), (SE2, ("position", "bearing"), False),
    (SE3, ("position", "prior"), True),
])  # fmt: skip
def test_the_file_cost_is_the_solvers_over_every_residual_row(group, kinds, offsets):
    graph = landmark_graph(group, 12, 6, kinds, noise=0.05, seed=4, offsets=offsets)[0]
    total, rows = file_cost(graph)
    expected = Objective(graph).evaluate(graph.poses, graph.landmarks.positions).cost
    assert total == expected
    counted = {"position": group.space_dim, "prior": group.space_dim, "bearing": 1, "bearing_range": 2}
    assert rows == graph.num_edges * group.dim + sum(f.count * counted[f.kind] for f in graph.landmarks.observations)


def _at_truth(seed: int):
    """A noisy graph whose values are its truth (a front end's refined estimate), whose cost per row is ~½."""
    graph, truth, points = landmark_graph(SE2, 40, 10, ("position", "bearing"), noise=0.02, seed=seed, per_landmark=6)
    return replace(graph, poses=truth, landmarks=replace(graph.landmarks, positions=points))


@pytest.mark.parametrize("seed", [0, 1])
def test_values_that_fit_are_the_start_and_reach_the_relaxations_optimum(seed):
    graph = _at_truth(seed)
    total, rows = file_cost(graph)
    assert total <= FIT_COST_PER_ROW * rows and file_values_fit(graph)
    np.testing.assert_array_equal(start_poses(graph, "chordal"), graph.poses)
    np.testing.assert_array_equal(start_poses(graph, "odometry"), initialize(graph, "odometry"))  # only chordal
    from_file, relaxed = optimize(graph), optimize(graph, relaxed_start(graph))
    np.testing.assert_allclose(from_file.final_cost, relaxed.final_cost, rtol=1e-9)


def test_values_that_do_not_fit_start_from_the_relaxation():
    graph = _at_truth(0)
    drifted = graph.poses @ SE2.exp(np.tile([0.0, 0.0, 0.01], (graph.num_vertices, 1)))  # each pose turned 0.01 rad
    graph = replace(graph, poses=np.concatenate([graph.poses[:1], drifted[1:]]))
    assert not file_values_fit(graph)
    np.testing.assert_array_equal(start_poses(graph, "chordal"), relaxed_start(graph))
    non_finite = replace(graph, landmarks=replace(graph.landmarks, positions=np.full_like(graph.landmarks.positions, 1e300)))
    assert not file_values_fit(non_finite)  # an overflowing cost is no fit


@pytest.mark.filterwarnings("ignore:.*skipped")  # the worlds' DATA_FEATURE_POINTXY lines
@pytest.mark.parametrize("name, fits", [
    ("world-2000-lownoise-default.g2o.gz", True), ("world-2000-full.g2o.gz", True), ("dlr.g2o", False),
    ("victoriaPark-full.g2o.gz", False),
])  # fmt: skip
def test_the_public_files(name, fits):
    from posegraph.io.g2o import read_g2o

    if not (DATA / name).exists():
        pytest.skip(f"{DATA / name} (fetched outside the repository: benchmarks/bench_landmarks.py) is absent")
    graph = read_g2o(DATA / name)
    assert file_values_fit(graph) is fits  # the worlds' values: 0.5-0.83 per row; DLR 4,800, Victoria Park 1,500
    if fits:
        from_file, relaxed = optimize(graph), optimize(graph, relaxed_start(graph))
        np.testing.assert_allclose(from_file.final_cost, relaxed.final_cost, rtol=1e-9)

