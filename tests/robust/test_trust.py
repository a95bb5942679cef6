"""Which edges GNC trusts: parallel edges between consecutive vertices are not taken on faith, and
a trusted edge that fails the inlier test at the result is released (or, strict, named)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import grid, inject_outliers, random_relative_poses
from posegraph.model.graph import PoseGraph
from posegraph.robust.pipeline import optimize_robust
from posegraph.robust.trust import (
    contradicted_odometry,
    best_edges_of_unkept_pairs,
    known_chi2_per_dof,
    known_inliers_above,
    parallel_odometry_mask,
)
from posegraph.solve import optimize
from posegraph.solve.residuals import cost


def _chain(ids, pairs):
    n, m = len(ids), len(pairs)
    index = {v: k for k, v in enumerate(ids)}
    return PoseGraph(
        ids=np.asarray(ids, dtype=np.int64), poses=np.tile(np.eye(4), (n, 1, 1)),
        edge_from=np.array([index[a] for a, _ in pairs], dtype=np.int64),
        edge_to=np.array([index[b] for _, b in pairs], dtype=np.int64),
        measurements=np.tile(np.eye(4), (m, 1, 1)), information=np.tile(np.eye(6), (m, 1, 1)),
    )  # fmt: skip


def test_parallel_edges_between_neighbours_are_ambiguous_whichever_way_round():
    graph = _chain([0, 1, 2, 3], [(0, 1), (1, 2), (2, 1), (2, 3), (0, 2), (0, 2), (3, 2)])
    assert parallel_odometry_mask(graph).tolist() == [False, True, True, True, False, False, True]
    # the odometry of each pair is its first edge; the parallel loop closures 0-2 are not neighbours
    assert graph.odometry_mask().tolist() == [True, True, False, True, False, False, False]


def test_an_ambiguous_pair_falls_back_to_its_best_fitting_edge_only_when_none_of_its_edges_was_kept():
    graph = _chain([0, 1, 2, 3], [(0, 1), (1, 2), (2, 1), (2, 3), (3, 2), (2, 3)])
    parallel = parallel_odometry_mask(graph)
    kept = np.array([True, False, True, False, False, False])  # pair 1-2 kept its second edge; pair 2-3 none
    s = np.array([0.0, 9.0, 1.0, 5.0, 2.0, 2.0])
    # pair 2-3: the least residual, and of the two tied the first in file order
    assert best_edges_of_unkept_pairs(graph, parallel, kept, s).tolist() == [False] * 4 + [True, False]
    assert not best_edges_of_unkept_pairs(graph, parallel, np.ones(6, bool), s).any()


def test_a_trusted_edge_is_contradicted_when_every_edge_spanning_it_was_rejected():
    chain = [(k, k + 1) for k in range(7)]
    loops = [(0, 2), (5, 7), (1, 4), (5, 2), (3, 6), (1, 6), (0, 7)]
    graph = _chain(list(range(8)), chain + loops)
    known = np.array([True] * 7 + [False] * 7)
    kept = np.array([True] * 7 + [True, True, False, False, False, False, True])
    assert not contradicted_odometry(graph, known, kept).any()  # (0, 7) spans every pair, and was kept
    kept[-1] = False
    # rejected edges spanning pairs 0..6: 1, 3, 4, 5, 4, 3, 1; kept ones: 1, 1, 0, 0, 0, 1, 1
    assert np.flatnonzero(contradicted_odometry(graph, known, kept)).tolist() == [2, 3, 4]
    assert np.flatnonzero(contradicted_odometry(graph, known, kept, minimum=5)).tolist() == [3]


def test_a_stretch_no_kept_edge_spans_out_to_the_end_is_not_contradicted():
    """Random wrong loop closures across the end of a trajectory that never returns there."""
    chain = [(k, k + 1) for k in range(7)]
    graph = _chain(list(range(8)), chain + [(0, 2), (1, 4), (2, 5), (3, 7), (2, 6)])
    known = np.array([True] * 7 + [False] * 5)
    kept = np.array([True] * 7 + [True] + [False] * 4)
    # rejected edges spanning pairs 2..5: 3, 4, 3, 2; no kept edge spans any pair after pair 1
    assert not contradicted_odometry(graph, known, kept).any()
    # (3, 7) kept: pairs 3..6 covered, and pair 2 (three rejected edges span it) lies between covered pairs
    assert np.flatnonzero(contradicted_odometry(graph, known, kept | (np.arange(12) == 10))).tolist() == [2]


def test_known_inliers_above_the_threshold_and_their_chi2_per_dof():
    s = np.array([1.0, 20.0, 30.0, 2.0])
    known = np.array([True, True, False, True])
    assert known_inliers_above(s, known, 16.81).tolist() == [False, True, False, False]
    assert known_chi2_per_dof(s, known, 6) == pytest.approx(23.0 / 18.0)
    assert np.isnan(known_chi2_per_dof(s, np.zeros(4, bool), 6))


@pytest.fixture(scope="module")
def clean():
    return grid(4, 4, 3, seed=3).graph


@pytest.mark.parametrize("wrong_first", [False, True])
def test_wrong_edges_parallel_to_the_odometry_are_found_whichever_comes_first(clean, wrong_first):
    """With the wrong edge first in file order, trusting the first edge of each pair would keep the
    wrong one and reject the odometry it contradicts; GNC must judge both."""
    graph, indices = inject_outliers(clean, fraction=0.3, seed=4, on_odometry=3, on_loop_closures=2, wrong_first=wrong_first)
    assert np.count_nonzero(graph.odometry_mask()[indices]) == (3 if wrong_first else 0)
    robust = optimize_robust(graph)
    np.testing.assert_array_equal(robust.outlier_edges, np.sort(indices))
    assert cost(clean, robust.poses) == pytest.approx(optimize(clean).final_cost, rel=1e-7)
    assert robust.released.size == 0 and robust.suspicious.size == 0
    assert not robust.known[indices].any()


def _wrong_odometry(clean, count=2, seed=5):
    """``clean`` with ``count`` odometry measurements replaced by random poses (no parallel edge
    tells them apart), and their indices."""
    rng = np.random.default_rng(seed)
    odometry = np.flatnonzero(clean.odometry_mask())
    wrong = np.sort(rng.choice(odometry[5:-5], count, replace=False))
    measurements = clean.measurements.copy()
    measurements[wrong] = random_relative_poses(rng, count, 5.0)
    return replace(clean, measurements=measurements, edge_source=None), wrong


def test_a_wrong_trusted_edge_is_released_and_then_rejected(clean):
    graph, wrong = _wrong_odometry(clean)
    robust = optimize_robust(graph)
    assert set(wrong) <= set(robust.released)
    np.testing.assert_array_equal(robust.outlier_edges, wrong)
    assert robust.suspicious.size == 0 and not robust.known[wrong].any()
    without = replace(clean, edge_from=np.delete(clean.edge_from, wrong), edge_to=np.delete(clean.edge_to, wrong),
                      measurements=np.delete(clean.measurements, wrong, 0), information=np.delete(clean.information, wrong, 0))
    assert cost(without, robust.poses) == pytest.approx(optimize(without).final_cost, rel=1e-7)


def test_strict_known_inliers_are_kept_and_named(clean):
    graph, wrong = _wrong_odometry(clean)
    robust = optimize_robust(graph, strict_known_inliers=True)
    assert robust.released.size == 0
    assert set(wrong) <= set(robust.suspicious)
    assert robust.known[wrong].all() and (robust.weights[wrong] == 1).all()


def _shifted_odometry(clean, shift: float):
    """``clean`` with its middle odometry edge ``shift`` off along x, and that edge's index."""
    odometry = np.flatnonzero(clean.odometry_mask())
    k = odometry[len(odometry) // 2]
    shifted = np.eye(4)
    shifted[0, 3] = shift
    measurements = clean.measurements.copy()
    measurements[k] = measurements[k] @ shifted
    return replace(clean, measurements=measurements, edge_source=None), k


@pytest.mark.parametrize("strict", [False, True])
def test_a_trusted_edge_within_the_family_wise_tail_is_not_named(clean, strict):
    """An odometry edge 0.3 off along x: at the result its s lies between the per-edge c̄² and the
    family-wise doubt threshold, where ~1 % of right edges lie too: neither released, rejected nor
    named (at c̄² every large clean graph would get a warning)."""
    from posegraph.robust.gnc import GncParams, inlier_thresholds
    from posegraph.robust.measurements import measurement_dimensions, measurement_residuals
    from posegraph.robust.pipeline import doubt_thresholds

    graph, k = _shifted_odometry(clean, 0.3)
    robust = optimize_robust(graph, strict_known_inliers=strict)
    s = measurement_residuals(graph, robust.poses)[k]
    per_edge = np.broadcast_to(inlier_thresholds(measurement_dimensions(graph), graph.num_edges, GncParams()), (graph.num_edges,))
    family = np.broadcast_to(doubt_thresholds(graph, robust.known, GncParams()), (graph.num_edges,))
    assert per_edge[k] < s < family[k]  # the case this test is about
    assert robust.suspicious.size == 0
    assert robust.released.size == 0 and robust.outlier_edges.size == 0 and robust.known[k]


@pytest.mark.parametrize("shift, named", [(0.3, False), (0.6, True)])
def test_the_final_check_names_a_kept_trusted_edge_above_the_doubt_threshold(clean, shift, named):
    """When a run without trusting a doubtful edge fits no better (here: the same run), the edge is
    kept; the final check must still name it when its s is above the family-wise threshold, and only
    then."""
    from types import SimpleNamespace

    from posegraph.robust.gnc import GncParams, inlier_thresholds
    from posegraph.robust.measurements import measurement_dimensions
    from posegraph.robust.pipeline import _release_doubtful, _Run, doubt_thresholds

    graph, k = _shifted_odometry(clean, shift)
    m = graph.num_edges
    known = graph.odometry_mask()
    run = _Run(None, np.ones(m), SimpleNamespace(poses=optimize(graph).poses), known, 0.0)
    thresholds = inlier_thresholds(measurement_dimensions(graph), m, GncParams())
    doubt = doubt_thresholds(graph, known, GncParams())
    kept, released, suspicious = _release_doubtful(graph, run, lambda known: run, thresholds, doubt, strict=False)
    assert kept is run and not released.any()
    assert np.flatnonzero(suspicious).tolist() == ([k] if named else [])
