"""Landmarks in the held analysis (posegraph.incremental.held_points): a landmark update is Gauss-Newton on
the whole graph ("whole"), its estimate — poses and points — the batch optimum of the graph so far."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.analysis.covariance import _solver_hessian
from posegraph.incremental import IncrementalOptimizer
from posegraph.incremental.replay import replay
from posegraph.lie.group import SE2, SE3
from posegraph.solve import SolverParams, optimize
from posegraph.solve.landmark_terms import point_variables
from posegraph.solve.objective import Objective
from posegraph.solve.sparsity import analyze_pattern

EXACT = 1e-6  # poses and points against the batch optimum, relative to the graph's extent
TIGHT = 1e-12  # the optimiser's tolerance in these tests: its estimate then is the optimum, not within 1e-7 of its cost

CASES = {
    "SE2-position": (SE2, ("position",), False),
    "SE2-bearing-range": (SE2, ("bearing_range",), False),
    "SE3-position": (SE3, ("position",), True),
    "SE3-point-prior": (SE3, ("position", "prior"), False),
}


def _graph(case, seed=1, poses=20, landmarks=6, fixed=()):
    group, kinds, offsets = CASES[case]
    graph, _, _ = landmark_graph(group, poses, landmarks, kinds, noise=0.02, seed=seed, offsets=offsets)
    if fixed:
        flags = np.zeros(landmarks, dtype=bool)
        flags[list(fixed)] = True
        graph = replace(graph, landmarks=replace(graph.landmarks, fixed=flags))
    return graph


def _batch(opt):
    """The batch optimum of the optimiser's graph so far, from its estimate: ``(poses, points)``."""
    graph = replace(opt.graph(), fixed=opt.held())
    result = optimize(graph, initial=graph.poses, initial_points=graph.landmarks.positions,
                      params=SolverParams(relative_tolerance=1e-14, absolute_tolerance=0.0, max_iterations=200))
    return result.poses, result.points


def _replay_checked(graph):
    """Replay ``graph`` one pose at a time, comparing every update's estimate with the batch optimum."""
    checked = []

    def check(result, number):
        opt = result.optimizer
        if opt.last_update.kind not in ("whole", "full") or opt.landmark_ids.shape[0] == 0:
            return
        poses, points = _batch(opt)
        scale = max(1.0, np.abs(points).max())
        assert np.abs(opt.poses - poses).max() <= EXACT * scale, (number, np.abs(opt.poses - poses).max())
        assert np.abs(opt.landmark_positions - points).max() <= EXACT * scale, (number, np.abs(opt.landmark_positions - points).max())
        checked.append(number)

    result = replay(graph, optimizer=IncrementalOptimizer(graph.group, tolerance=TIGHT), progress=check)
    return result, checked


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_landmark_update_is_the_batch_optimum_on_the_held_path(case):
    result, checked = _replay_checked(_graph(case))
    # With point priors, the first one releases the first pose's anchor while one point prior fixes no
    # rotation: H is singular (or nearly, by round-off) until more priors tie it, and the damped batch
    # solver takes those early updates; from the second half of the replay on the held path takes all.
    later = result.kinds[len(result.kinds) // 2 :] if case.endswith("prior") else result.kinds
    assert "full" not in later and result.kinds.count("full") <= 3, result.kinds
    assert result.kinds.count("whole") >= 5 and len(checked) == result.kinds.count("whole") + result.kinds.count("full")


def test_a_fixed_landmark_stays_put_and_the_rest_is_the_batch_optimum():
    graph = _graph("SE2-position", seed=2, fixed=(0, 3))
    result, checked = _replay_checked(graph)
    opt = result.optimizer
    # A FIX landmark anchors the poses that see it, but one point leaves their rotation free: H is singular
    # until more tie them, and the damped batch solver takes those updates; from then on the held path does.
    first = result.kinds.index("whole")
    assert "full" not in result.kinds[first:] and result.kinds.count("whole") >= 5, result.kinds
    assert len(checked) == len(result.kinds) - result.kinds.count("exact")
    order = np.argsort(opt.landmark_ids)
    np.testing.assert_array_equal(opt.landmark_positions[order][[0, 3]], graph.landmarks.positions[[0, 3]])


def test_landmarks_past_the_capacity_make_a_new_analysis():
    graph = _graph("SE2-position", seed=3, poses=24, landmarks=40)
    capacities = []

    def check(result, number):
        capacities.append(result.optimizer._whole.points.capacity)

    opt = IncrementalOptimizer(graph.group, tolerance=TIGHT)
    result = replay(graph, optimizer=opt, progress=check)
    assert "full" not in result.kinds
    grown = [c for a, c in zip(capacities, capacities[1:]) if 0 < a < c]
    assert grown  # the point capacity was exceeded and a larger analysis made
    assert opt._whole.points.capacity >= opt.landmark_ids.shape[0]
    poses, points = _batch(opt)
    assert np.abs(opt.landmark_positions - points).max() <= EXACT * max(1.0, np.abs(points).max())


def _rows(pattern, n: int, count: int, d: int, s: int) -> np.ndarray:
    """Scalar rows of the free poses ``< n`` then the free points ``< count`` in ``pattern``."""
    pose = pattern.variable_of[:n]
    point = pattern.point_variable_of[:count]
    return np.concatenate([(pattern.offsets[pose[pose >= 0]][:, None] + np.arange(d)).ravel(),
                           (pattern.offsets[point[point >= 0]][:, None] + np.arange(s)).ravel()])


def _dense(pattern, data: np.ndarray) -> np.ndarray:
    """The symmetric H from its lower-triangle CSC ``data``."""
    size = pattern.dimension
    lower = np.zeros((size, size))
    columns = np.repeat(np.arange(size), np.diff(pattern.indptr))
    lower[pattern.indices, columns] = data[: pattern.nnz]
    return lower + np.tril(lower, -1).T


@pytest.mark.parametrize("case", ["SE2-position", "SE3-point-prior"])
def test_the_held_system_is_the_batch_solvers_system(case):
    """H and g as the held analysis scatters them (points' rows included) equal the batch solver's."""
    graph = _graph(case, seed=4, fixed=(1,))
    opt = replay(graph, optimizer=IncrementalOptimizer(graph.group, tolerance=TIGHT)).optimizer
    whole, estimate = opt._whole, replace(opt.graph(), fixed=opt.held())
    n, count, d, s = estimate.num_vertices, estimate.landmarks.count, graph.group.dim, graph.group.space_dim
    points = estimate.landmarks.positions
    assert whole._ready(opt.held())
    objective = whole._objective(opt.held())
    blocks = objective.linearize(estimate.poses, objective.evaluate(estimate.poses, points))
    data, g = whole._system(blocks, n, True)
    mixed = analyze_pattern(n, estimate.edge_from, estimate.edge_to, opt.held(), d, point_variables(estimate))
    expected = _dense(mixed, _solver_hessian(estimate, mixed, estimate.poses, points))
    ours, theirs = _rows(whole.pattern, n, count, d, s), _rows(mixed, n, count, d, s)
    held_h = _dense(whole.pattern, data)
    np.testing.assert_allclose(held_h[np.ix_(ours, ours)], expected[np.ix_(theirs, theirs)], rtol=1e-10, atol=1e-8)
    rest = np.setdiff1d(np.arange(whole.pattern.dimension), ours)
    np.testing.assert_array_equal(held_h[np.ix_(rest, ours)], 0.0)  # the decoupled variables (to come)
    np.testing.assert_array_equal(np.diag(held_h)[rest], 1.0)
    full = Objective(estimate)
    theirs_g = _gradient(full, estimate, points, mixed)
    np.testing.assert_allclose(g[ours], theirs_g[theirs], rtol=1e-10, atol=1e-8)


def _gradient(objective, graph, points, pattern) -> np.ndarray:
    """The batch solver's gradient ``(D,)`` in ``pattern`` (:func:`posegraph.solve.sparsity.gradient_values` + landmarks)."""
    from posegraph.solve.landmark_terms import add_landmark_gradient
    from posegraph.solve.sparsity import gradient_values
    from posegraph.solve.unary import add_prior_gradient

    blocks = objective.linearize(graph.poses, objective.evaluate(graph.poses, points))
    g = gradient_values(pattern, blocks.gradient)
    if blocks.priors is not None:
        add_prior_gradient(pattern, g, blocks.priors)
    add_landmark_gradient(pattern, g, blocks.landmarks)
    return g


def test_measurements_since_the_factor_are_exact_low_rank_terms():
    """H without the last measurements of each family (as a factor made before them holds it) plus the
    landmark terms is H with them: the terms carry every entry of the new measurements' Hessians, and take
    back the unit diagonal of a point first reached by them."""
    from posegraph.incremental.held_factor import LowRankTerms
    from posegraph.solve.landmark_terms import LandmarkBlocks

    graph = _graph("SE2-bearing-range", seed=6)
    opt = replay(graph, optimizer=IncrementalOptimizer(graph.group, tolerance=TIGHT)).optimizer
    whole, held = opt._whole, opt.held()
    assert whole._ready(held)
    objective = whole._objective(held)
    poses, points = opt.poses, opt.landmark_positions
    blocks = objective.linearize(poses, objective.evaluate(poses, points))
    full, _ = whole._system(blocks, opt.num_vertices, True)
    family = next(iter(whole.points.store.families.values()))
    last = int(family.landmark.view[-1])
    since = np.flatnonzero(family.landmark.view == last)  # every measurement of one landmark: its point unreached
    keep = np.ones(family.count, dtype=bool)
    keep[since] = False
    d, s = graph.group.dim, graph.group.space_dim
    h = blocks.landmarks.hessian[0]
    q = family.count
    parts = [h[: q * d * d].reshape(q, -1), h[q * d * d : q * (d * d + s * s)].reshape(q, -1), h[q * (d * d + s * s) :].reshape(q, -1)]
    before = LandmarkBlocks((np.concatenate([(p * keep[:, None]).ravel() for p in parts]),), blocks.landmarks.gradient)
    partial, _ = whole._system(replace(blocks, landmarks=before), opt.num_vertices, True)
    point_rows = whole.pattern.offsets[whole.pattern.point_variable_of[last]] + np.arange(s)
    partial[whole.pattern.diagonal[point_rows]] = 1.0  # the factor made before decoupled the point
    # the measurements of that landmark come last in the terms' view: reorder the family so they do
    order = np.concatenate([np.flatnonzero(keep), since])
    for rows in whole.points.placed[next(iter(whole.points.placed))]:
        rows.data[: q] = rows.view[order]
    reordered = [p[order] for p in parts]
    blocks_now = LandmarkBlocks((np.concatenate([p.ravel() for p in reordered]),), blocks.landmarks.gradient)
    key = next(iter(whole.points.store.families))
    whole.points.held_counts = {key: q - since.shape[0]}
    whole.points.held_decoupled = np.concatenate([whole.points.decoupled_rows(whole.pattern), point_rows])
    terms = whole.points.terms(whole.pattern, LowRankTerms.empty(), blocks_now)
    expected = _dense(whole.pattern, full)
    got = _dense(whole.pattern, partial)
    got[np.ix_(terms.columns, terms.columns)] += terms.matrix
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-9)


RESIGHT_AT = 80  # the pose that sees landmarks 0 and 1 again, ~78 poses after they were last seen
SIGMA = 0.1  # of the sightings (odometry 0.02): the drift over the gap is not a drastic update (a batch solve)


def _resighted_graph(case: str, poses: int = 100, landmarks: int = 30, seed: int = 7):
    """Landmark ``l`` seen by poses ``3l .. 3l+2``; landmarks 0 and 1 seen again by poses RESIGHT_AT ..
    RESIGHT_AT+3, after a gap longer than RECENT (and than AHEAD): their blocks are in no analysis then."""
    from datasets.synthetic import LANDMARK_TAGS
    from posegraph.model.landmarks import Observations, measurement_size
    from posegraph.solve.landmark_residuals import landmark_residuals

    group, (kind,), _ = CASES[case]
    graph, truth, points = landmark_graph(group, poses, landmarks, (kind,), noise=0.02, seed=seed)
    again = RESIGHT_AT + np.arange(4)
    pose = np.concatenate([(3 * np.arange(landmarks)[:, None] + np.arange(3)).ravel(), again, again])
    landmark = np.concatenate([np.repeat(np.arange(landmarks), 3), np.repeat([0, 1], 4)])
    r = measurement_size(kind, group.space_dim)
    zero = Observations(kind, pose, landmark, np.zeros((pose.size, r)), np.zeros((pose.size, r, r)))
    z = landmark_residuals(group, truth, points, zero) + SIGMA * np.random.default_rng(seed).standard_normal((pose.size, r))
    family = Observations(kind, pose, landmark, z, np.broadcast_to(np.eye(r) / SIGMA**2, (pose.size, r, r)).copy(),
                          tag=LANDMARK_TAGS[(kind, group.space_dim)])
    return replace(graph, landmarks=replace(graph.landmarks, observations=(family,)))


def _left_out_terms_complete_h(opt) -> None:
    """H as the held analysis scatters it (left-out measurements dropped) plus the left-out measurements'
    low-rank terms at the current point equals the batch solver's H there."""
    from posegraph.incremental.held_factor import LowRankTerms

    whole, held = opt._whole, opt.held()
    points_side = whole.points
    estimate = replace(opt.graph(), fixed=held)
    n, count, d, s = estimate.num_vertices, estimate.landmarks.count, estimate.group.dim, estimate.group.space_dim
    objective = whole._objective(held)
    points = estimate.landmarks.positions
    blocks = objective.linearize(estimate.poses, objective.evaluate(estimate.poses, points))
    data, _ = whole._system(blocks, n, True)
    saved = points_side.held_counts, points_side.held_decoupled
    points_side.held_counts = {key: family.count for key, family in points_side.store.families.items()}
    points_side.held_decoupled = points_side.decoupled_rows(whole.pattern)
    try:  # as a factor made now would see them: the left-out measurements are the only terms
        terms = points_side.terms(whole.pattern, LowRankTerms.empty(), blocks.landmarks)
    finally:
        points_side.held_counts, points_side.held_decoupled = saved
    got = _dense(whole.pattern, data)
    got[np.ix_(terms.columns, terms.columns)] += terms.matrix
    mixed = analyze_pattern(n, estimate.edge_from, estimate.edge_to, held, d, point_variables(estimate))
    expected = _dense(mixed, _solver_hessian(estimate, mixed, estimate.poses, points))
    ours, theirs = _rows(whole.pattern, n, count, d, s), _rows(mixed, n, count, d, s)
    assert terms.columns.shape[0] > 0
    np.testing.assert_allclose(got[np.ix_(ours, ours)], expected[np.ix_(theirs, theirs)], rtol=1e-10, atol=1e-8)


def _replay_resighted(graph, check_terms: bool):
    """Replay ``graph`` one pose at a time, every solving update's estimate against the batch optimum;
    ``(analyses after each update, left-out measurements after each update)``."""
    analyses, left_out = [], []

    def check(result, number):
        opt = result.optimizer
        analyses.append(opt._whole.analyses)
        left_out.append(opt._whole.points.left_out_count() if opt._whole.points is not None else 0)
        if opt.last_update.kind in ("whole", "full") and opt.landmark_ids.shape[0]:
            poses, points = _batch(opt)
            scale = max(1.0, np.abs(points).max())
            assert np.abs(opt.poses - poses).max() <= EXACT * scale, number
            assert np.abs(opt.landmark_positions - points).max() <= EXACT * scale, number
        if check_terms and left_out[-1] and opt.last_update.kind == "whole":
            _left_out_terms_complete_h(opt)

    result = replay(graph, optimizer=IncrementalOptimizer(graph.group, tolerance=TIGHT), progress=check)
    return result, np.array(analyses), np.array(left_out)


@pytest.mark.parametrize("case", ["SE2-bearing-range", "SE3-position"])
def test_a_landmark_seen_again_after_a_gap_is_a_left_out_term_not_an_analysis(case, monkeypatch):
    """Landmarks re-sighted after a gap longer than RECENT: their measurements are left out of H as low-rank
    terms (no new analysis at those updates), H without them plus their terms is the batch H, and every
    update's estimate is the batch optimum."""
    from posegraph.incremental.held_points import HeldPoints

    graph = _resighted_graph(case)
    result, analyses, left_out = _replay_resighted(graph, check_terms=True)
    at = RESIGHT_AT  # update RESIGHT_AT adds pose RESIGHT_AT: analyses[at] is the count after it
    assert "full" not in result.kinds and result.kinds[at] == "whole"
    assert left_out[at] == 2 and analyses[at] == analyses[at - 1], (left_out[at - 2 : at + 4], analyses[at - 2 : at + 4])
    assert left_out[at + 1] == 4 and analyses[at + 1] == analyses[at]
    # without left-out measurements the same re-sighting makes an analysis: the case above tests something
    monkeypatch.setattr(HeldPoints, "max_left_out", 0)
    result, analyses, left_out = _replay_resighted(graph, check_terms=False)
    assert not left_out.any() and analyses[at] == analyses[at - 1] + 1
