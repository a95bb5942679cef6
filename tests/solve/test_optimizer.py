"""Gauss-Newton and Levenberg-Marquardt: gtsam's optimum on the standard files, gauge, records, stops."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from posegraph.model.graph import PoseGraph
from posegraph.io.g2o import read_g2o
from posegraph.lie.group import SE2, SE3
from posegraph.solve import IterationRecord, OptimizeResult, SolverParams, optimize
from posegraph.solve.residuals import cost
from posegraph.solve.sparsity import lower_csc
from tests.solve.gtsam_reference import gtsam_graph, perturbed_poses

# gtsam 4.3 LevenbergMarquardtOptimizer, default parameters, prior (σ=1e-6) on the first pose, from the
# file's poses: torus3D stops at this cost (measured here; 20 s, too slow to recompute in a test).
GTSAM_TORUS3D_FROM_FILE = 29953.8001826
# The optimum of torus3D (guide's reference, gtsam LM from a good start).
TORUS3D_OPTIMUM = 12117.6368794


@functools.lru_cache(maxsize=None)
def gtsam_lm_cost(path, tolerance=1e-5):
    """gtsam LM's final cost (edges only) from the file's values, the first pose held by a tight prior.

    ``tolerance`` is gtsam's relative and absolute error tolerance: its default 1e-5 can stop short
    of the optimum (pose3example: 18853.0674 against 18853.0207 at 1e-12), so the optimum is taken
    from a run at 1e-12 and the default run is the cost to beat.
    """
    gtsam = pytest.importorskip("gtsam")
    factors, values = gtsam_graph(path)
    first = min(values.keys())
    anchored = gtsam.NonlinearFactorGraph(factors)
    anchored.add(gtsam.PriorFactorPose3(first, values.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(tolerance)
    params.setAbsoluteErrorTol(tolerance)
    result = gtsam.LevenbergMarquardtOptimizer(anchored, values, params).optimize()
    return factors.error(result)


def check_optimum(result, path):
    assert result.converged, result.termination
    assert result.final_cost == pytest.approx(gtsam_lm_cost(str(path), 1e-12), rel=1e-6)
    assert result.final_cost <= gtsam_lm_cost(str(path)) * (1 + 1e-12)  # at least as low as gtsam's default run


STANDARD = ["tinyGrid3D", "smallGrid3D", "sphere2500", "parking-garage"]


@pytest.mark.parametrize("method", ["lm", "gn"])
@pytest.mark.parametrize("name", STANDARD)
def test_reaches_gtsam_lm_cost_on_standard_files(name, method, shared_dataset):
    path = shared_dataset(name)
    graph = read_g2o(path)
    result = optimize(graph, initial="file", params=SolverParams(method=method))
    check_optimum(result, path)
    assert cost(graph, result.poses) == pytest.approx(result.final_cost, rel=1e-12)  # no prior in the cost


@pytest.mark.parametrize("method", ["lm", "gn"])
def test_reaches_gtsam_lm_cost_on_pose3example(method, gtsam_example_file):
    path = gtsam_example_file("pose3example.txt")
    graph = read_g2o(path)
    result = optimize(graph, initial="file", params=SolverParams(method=method))
    check_optimum(result, path)


def test_backends_reach_the_same_optimum(shared_dataset, cholmod_backend):
    graph = read_g2o(shared_dataset("smallGrid3D"))
    a = optimize(graph, initial="file", params=SolverParams(linear_solver="cholmod"))
    b = optimize(graph, initial="file", params=SolverParams(linear_solver="scipy"))
    assert a.linear_solver.startswith("cholmod") and b.linear_solver.startswith("scipy")
    assert a.final_cost == pytest.approx(b.final_cost, rel=1e-10)
    np.testing.assert_allclose(a.poses, b.poses, atol=1e-6)


@pytest.mark.slow
def test_torus3d_from_file_at_least_as_good_as_gtsam(shared_dataset):
    """From the file's poses LM crawls (about 0.05 a step near iteration 100, where the default cap
    would stop it below gtsam's cost without converging); with room it stops on its own convergence
    test, measured at 137 iterations and 29950.04. The cap leaves twice that room."""
    graph = read_g2o(shared_dataset("torus3D"))
    params = SolverParams(method="lm", max_iterations=300)
    result = optimize(graph, initial="file", params=params)
    assert result.converged, result.termination  # not stopped by the cap
    assert result.iterations < params.max_iterations
    assert result.final_cost <= GTSAM_TORUS3D_FROM_FILE


@pytest.mark.slow
def test_torus3d_with_chordal_start_reaches_the_optimum(shared_dataset):
    pytest.importorskip("posegraph.init")
    graph = read_g2o(shared_dataset("torus3D"))
    result = optimize(graph, initial="chordal")
    assert result.converged, result.termination
    assert result.final_cost == pytest.approx(TORUS3D_OPTIMUM, rel=1e-6)


# ---------------------------------------------------------------- synthetic graphs


GROUPS = [SE3, SE2]


def synthetic_graph(seed, n=30, loops=20, noise=0.05, fixed=None, components=1, group=SE3):
    """A noisy random walk with loop closures; initial poses = odometry with extra drift (3D or 2D)."""
    rng = np.random.default_rng(seed)
    k = group.matrix_size
    truth = np.tile(np.eye(k), (n, 1, 1))
    for v in range(1, n):
        truth[v] = truth[v - 1] @ perturbed_poses(np.eye(k)[None], rng, 0.3, 1.0)[0]
    pairs = [(k, k + 1) for k in range(n - 1)]
    pairs += [tuple(sorted(rng.choice(n, 2, replace=False))) for _ in range(loops)]
    if components == 2:  # cut the walk in the middle, no loops across
        half = n // 2
        pairs = [(i, j) for i, j in pairs if (i < half) == (j < half)]
    edge_from = np.array([p[0] for p in pairs])
    edge_to = np.array([p[1] for p in pairs])
    exact = np.linalg.inv(truth[edge_from]) @ truth[edge_to]
    measurements = perturbed_poses(exact, rng, noise, noise)
    diagonal = np.full(group.dim, 100.0)
    diagonal[list(group.rotation_axes)] = 400.0
    information = np.tile(np.diag(diagonal), (len(pairs), 1, 1))
    initial = perturbed_poses(truth, rng, 0.1, 0.3)
    mask = np.zeros(n, dtype=bool)
    if fixed is not None:
        mask[list(fixed)] = True
    return PoseGraph(
        ids=np.arange(n) * 3 + 7,  # ids need not be 0..n-1
        poses=initial,
        edge_from=edge_from,
        edge_to=edge_to,
        measurements=measurements,
        information=information,
        fixed=mask,
        group=group,
    )


@pytest.mark.parametrize("group", GROUPS, ids=lambda g: g.name)
@pytest.mark.parametrize("linear_solver", ["scipy", "auto"])
def test_lm_and_gn_agree_on_a_synthetic_graph(linear_solver, group):
    graph = synthetic_graph(0, group=group)
    tight = dict(relative_tolerance=1e-14, absolute_tolerance=1e-14, linear_solver=linear_solver)
    lm = optimize(graph, initial="file", params=SolverParams(method="lm", **tight))
    gn = optimize(graph, initial="file", params=SolverParams(method="gn", **tight))
    assert lm.converged and gn.converged
    assert lm.final_cost < 0.1 * lm.initial_cost
    assert lm.final_cost == pytest.approx(gn.final_cost, rel=1e-9)
    np.testing.assert_allclose(lm.poses, gn.poses, atol=1e-6)


@pytest.mark.parametrize("group", GROUPS, ids=lambda g: g.name)
def test_held_vertices_do_not_move_and_the_gauge_adds_nothing_to_the_cost(group):
    graph = synthetic_graph(1, fixed=[3, 12], group=group)
    result = optimize(graph, initial="file")
    np.testing.assert_array_equal(result.poses[[3, 12]], graph.poses[[3, 12]])
    # the anchor (smallest id) is free to move when the component has FIX vertices
    assert not np.array_equal(result.poses[0], graph.poses[0])
    assert result.final_cost == pytest.approx(cost(graph, result.poses), rel=1e-13)


@pytest.mark.parametrize("group", GROUPS, ids=lambda g: g.name)
def test_each_component_is_anchored_at_its_smallest_id(group):
    graph = synthetic_graph(2, n=20, components=2, group=group)
    result = optimize(graph, initial="file")
    assert result.converged
    np.testing.assert_array_equal(result.poses[[0, 10]], graph.poses[[0, 10]])
    assert np.abs(result.poses - graph.poses).max() > 1e-3


@pytest.mark.parametrize("group", GROUPS, ids=lambda g: g.name)
def test_optimum_does_not_depend_on_which_single_vertex_holds_the_gauge(group):
    free = synthetic_graph(3, group=group)
    fixed_elsewhere = synthetic_graph(3, fixed=[17], group=group)
    tight = SolverParams(relative_tolerance=1e-14, absolute_tolerance=1e-14)
    a = optimize(free, initial="file", params=tight)
    b = optimize(fixed_elsewhere, initial="file", params=tight)
    assert a.final_cost == pytest.approx(b.final_cost, rel=1e-9)
    # the two solutions differ by one rigid motion: relative poses agree
    rel_a = np.linalg.inv(a.poses[:-1]) @ a.poses[1:]
    rel_b = np.linalg.inv(b.poses[:-1]) @ b.poses[1:]
    np.testing.assert_allclose(rel_a, rel_b, atol=1e-7)


def test_records_are_consistent_and_lm_cost_never_increases():
    graph = synthetic_graph(4, noise=0.1)
    seen = []
    result = optimize(graph, initial="file", params=SolverParams(callback=seen.append))
    assert isinstance(result, OptimizeResult)
    assert seen == result.records and all(isinstance(r, IterationRecord) for r in seen)
    assert result.iterations == len(result.records) > 0
    costs = [result.initial_cost] + [r.cost for r in result.records]
    assert all(b <= a for a, b in zip(costs, costs[1:]))
    for before, record in zip(costs, result.records):
        assert record.cost_decrease == pytest.approx(before - record.cost, abs=1e-12)
        assert record.seconds >= 0
        # attempts == 0: the step came from the previous iteration's factorisation (reuse_factorization)
        assert record.attempts >= 1 or (record.attempts == 0 and record.seconds_factorize == 0 and record.accepted)
    assert result.final_cost == result.records[-1].cost
    assert result.seconds_total >= result.seconds_linearize + result.seconds_factorize


@pytest.mark.parametrize("group", GROUPS, ids=lambda g: g.name)
@pytest.mark.parametrize("max_iterations", [1, 100])
def test_final_residuals_are_the_residuals_at_the_returned_poses(group, max_iterations):
    from posegraph.analysis.report import chi2_summary
    from posegraph.solve.residuals import edge_residuals

    graph = synthetic_graph(6, noise=0.1, group=group)
    result = optimize(graph, initial="file", params=SolverParams(max_iterations=max_iterations))
    assert result.final_residuals.shape == (graph.num_edges, group.dim)
    np.testing.assert_array_equal(result.final_residuals, edge_residuals(result.poses, graph))
    given = chi2_summary(graph, result.poses, result.final_residuals)
    assert given == chi2_summary(graph, result.poses)
    assert given["cost"] == pytest.approx(result.final_cost, rel=1e-12)


def test_maximum_iterations_and_callback_stop():
    graph = synthetic_graph(5)
    result = optimize(graph, initial="file", params=SolverParams(max_iterations=2))
    assert (result.iterations, result.termination, result.converged) == (2, "maximum iterations", False)
    result = optimize(graph, initial="file", params=SolverParams(callback=lambda record: True))
    assert (result.iterations, result.termination) == (1, "callback")


def test_lambda_bound_stops_lm():
    # A λ ceiling below the first λ increase: the first rejected step ends the run. (Without the
    # line search, which would otherwise accept a shortened step instead of raising λ.)
    graph = synthetic_graph(6, noise=0.2)
    params = SolverParams(
        initial_lambda=1e-8, lambda_max=1e-8, lambda_min=0.0, min_gain_ratio=0.999999, line_search=False
    )
    result = optimize(graph, initial="file", params=params)
    assert result.termination == "lambda exceeded bound"
    assert not result.converged
    assert result.final_cost <= result.initial_cost


@pytest.mark.parametrize("group", GROUPS, ids=lambda g: g.name)
def test_gauss_newton_on_an_exactly_consistent_graph_converges_to_zero(group):
    graph = synthetic_graph(7, noise=0.0, group=group)
    result = optimize(graph, initial="file", params=SolverParams(method="gn"))
    assert result.converged
    assert result.final_cost < 1e-15


def test_nothing_to_optimise_when_every_vertex_is_held():
    graph = synthetic_graph(8, n=5, loops=0, fixed=range(5))
    result = optimize(graph, initial="file")
    assert (result.termination, result.iterations, result.converged) == ("converged: nothing to optimise", 0, True)
    np.testing.assert_array_equal(result.poses, graph.poses)


def test_bad_initial_poses_and_parameters_are_refused():
    graph = synthetic_graph(9, n=5, loops=0)
    with pytest.raises(ValueError, match="shape"):
        optimize(graph, initial=np.zeros((4, 4, 4)))
    bad = graph.poses.copy()
    bad[2, 0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        optimize(graph, initial=bad)
    for field, value in [("method", "newton"), ("linear_solver", "mumps"), ("max_iterations", -1), ("lambda_factor", 1.0)]:
        with pytest.raises(ValueError, match=field):
            SolverParams(**{field: value})


def test_initial_poses_are_not_modified():
    graph = synthetic_graph(10)
    start = graph.poses.copy()
    optimize(graph, initial=start)
    np.testing.assert_array_equal(start, graph.poses)


@pytest.mark.parametrize("group", GROUPS, ids=lambda g: g.name)
@pytest.mark.parametrize("method", ["lm", "gn"])
def test_starting_at_an_exact_optimum_converges_at_once(method, group):
    graph = synthetic_graph(11, noise=0.0, group=group)
    exact = graph.poses.copy()
    # make every measurement exact for the initial poses: zero residuals, zero gradient
    relative = np.linalg.inv(exact[graph.edge_from]) @ exact[graph.edge_to]
    graph = PoseGraph(graph.ids, exact, graph.edge_from, graph.edge_to, relative, graph.information, group=group)
    result = optimize(graph, initial="file", params=SolverParams(method=method))
    assert result.converged, result.termination
    assert result.iterations <= 1
    assert result.final_cost < 1e-20
    np.testing.assert_allclose(result.poses, exact, atol=1e-12)


def test_gauss_newton_reports_a_singular_system():
    # An edge whose information constrains nothing in some directions: H is singular for GN.
    graph = synthetic_graph(12, n=4, loops=0)
    information = graph.information.copy()
    information[:, 3:, :] = 0.0
    information[:, :, 3:] = 0.0  # rotations only: translations of vertices 1..3 are free
    graph = PoseGraph(graph.ids, graph.poses, graph.edge_from, graph.edge_to, graph.measurements, information)
    gn = optimize(graph, initial="file", params=SolverParams(method="gn", linear_solver="auto"))
    assert gn.termination == "linear system not positive definite" and not gn.converged
    lm = optimize(graph, initial="file", params=SolverParams(method="lm"))  # damping copes
    assert lm.converged and lm.final_cost < 1e-3 * lm.initial_cost


def factorizations(result) -> int:
    return sum(record.attempts for record in result.records)


@pytest.mark.parametrize("method", ["lm", "gn"])
@pytest.mark.parametrize("linear_solver", ["scipy", "auto"])
def test_chord_steps_save_factorizations_and_reach_the_same_optimum(method, linear_solver):
    graph = synthetic_graph(3, n=40, loops=30)
    params = dict(method=method, linear_solver=linear_solver)
    fresh = optimize(graph, initial="file", params=SolverParams(reuse_factorization=False, **params))
    reused = optimize(graph, initial="file", params=SolverParams(**params))
    assert fresh.converged and reused.converged
    assert all(record.attempts >= 1 for record in fresh.records)
    chords = [k for k, record in enumerate(reused.records) if record.attempts == 0]
    assert chords and chords[0] > 0
    assert factorizations(reused) < factorizations(fresh)
    for k in chords:  # an accepted full step, made with the damping of the last factorisation
        record = reused.records[k]
        assert (record.seconds_factorize, record.accepted, record.step_scale) == (0.0, True, 1.0)
        last_factorized = max(j for j in range(k) if reused.records[j].attempts >= 1)
        assert record.lambda_ == reused.records[last_factorized].lambda_
    assert reused.final_cost == pytest.approx(fresh.final_cost, rel=1e-9)
    assert reused.final_cost == pytest.approx(cost(graph, reused.poses), rel=1e-12)
    costs = [reused.initial_cost] + [record.cost for record in reused.records]
    assert all(b <= a for a, b in zip(costs, costs[1:]))


def test_chord_steps_are_tried_only_after_accurate_full_steps_and_taken_only_when_they_qualify(monkeypatch):
    """Tried after an accepted full step with gain ratio in [0.9, 1/0.9] (nowhere else), and taken
    only when H agrees with the held factorisation along the step and the decrease it promises is
    a tenth of the last one or within the tolerances."""
    import posegraph.solve.optimizer as optimizer_module

    solves, verdicts = [], []
    original_step, original_decrease = optimizer_module._chord_step, optimizer_module._chord_step_decrease

    def step_spy(solver, gradient):
        step, slope = original_step(solver, gradient)
        np.testing.assert_allclose(step, solver.solve(-gradient), rtol=0, atol=0)
        assert slope == pytest.approx(float(gradient @ step), rel=1e-12)
        solves.append(slope)
        return step, slope

    def decrease_spy(pattern, data, step, slope, cost_now, params, last_decrease):
        found = original_decrease(pattern, data, step, slope, cost_now, params, last_decrease)
        curvature = float(step @ (lower_csc(pattern, data) @ step)) * 2 - float(np.sum(data[pattern.diagonal] * step**2))
        predicted = -slope - 0.5 * curvature
        qualifies = predicted >= optimizer_module.CHORD_AGREEMENT * (-0.5 * slope) and (
            predicted <= optimizer_module.CHORD_CONTRACTION * last_decrease
            or predicted <= params.relative_tolerance * cost_now
        )
        assert (found is not None) == qualifies
        if found is not None:
            assert found == pytest.approx(predicted, rel=1e-9)
        verdicts.append(found is not None)
        return found

    monkeypatch.setattr(optimizer_module, "_chord_step", step_spy)
    monkeypatch.setattr(optimizer_module, "_chord_step_decrease", decrease_spy)
    graph = synthetic_graph(3, n=40, loops=30)
    result = optimize(graph, initial="file")
    records = result.records
    tried_after = [
        r.accepted and r.step_scale == 1.0 and 0.9 <= r.gain_ratio <= 1 / 0.9 for r in records[:-1]
    ]
    assert len(solves) == sum(tried_after) > 0
    # every solve goes on to the chord test unless the decrement stop ended the run there
    stopped = result.termination == optimizer_module.CONVERGED_DECREMENT
    assert len(verdicts) == len(solves) - stopped
    assert [r.attempts for r in records].count(0) == sum(verdicts) + stopped > 0
    assert records[0].attempts >= 1  # the first iteration always factorises


def test_a_negligible_newton_decrement_under_the_held_factorization_ends_the_run(shared_dataset):
    """parking-garage from the chordal start: after the chord step of iteration 3 the next one is
    stale (H is 2.3 times M along it), but ½gᵀM⁻¹g is 4e-10 of the cost, far below the tolerance:
    the run stops there, one factorisation earlier, within 1e-9 of the cost a new one reaches."""
    import posegraph.solve.optimizer as optimizer_module
    from posegraph.init import initialize

    graph = read_g2o(shared_dataset("parking-garage"))
    start = initialize(graph, "chordal")
    result = optimize(graph, initial=start)
    fresh = optimize(graph, initial=start, params=SolverParams(reuse_factorization=False))
    assert result.termination == optimizer_module.CONVERGED_DECREMENT and result.converged
    last = result.records[-1]
    assert (last.attempts, last.accepted, last.seconds_factorize) == (0, False, 0.0)
    assert last.cost == result.records[-2].cost == result.final_cost
    assert factorizations(result) < factorizations(fresh)
    assert result.final_cost == pytest.approx(fresh.final_cost, rel=1e-9)
    assert result.final_cost == pytest.approx(cost(graph, result.poses), rel=1e-12)


def test_the_decrement_test_needs_a_barely_damped_factorization_and_its_margin():
    import posegraph.solve.optimizer as optimizer_module

    params = SolverParams()
    cost_now = 2.0
    limit = params.relative_tolerance * cost_now / optimizer_module.DECREMENT_MARGIN
    negligible = optimizer_module._decrement_negligible
    assert negligible(0.5 * limit, cost_now, 1e-12, params)
    assert not negligible(2.0 * limit, cost_now, 1e-12, params)
    assert not negligible(0.5 * limit, cost_now, 10 * optimizer_module.DECREMENT_MAX_LAMBDA, params)
    assert not negligible(float("nan"), cost_now, 1e-12, params)
    assert not negligible(-1e-30, cost_now, 1e-12, params)


def test_the_decrement_stop_takes_the_chord_step_the_cost_confirms(shared_dataset):
    """sphere2500 from the chordal start: at the negligible decrement of iteration 4 the chord step
    still follows the held factorisation's model (gain ratio within 10 % of 1), so it is taken for one
    cost evaluation: the run ends 6e-12 above the optimum instead of 2.4e-10, with no factorisation
    more; without the stop the same step is taken as an ordinary chord step."""
    import posegraph.solve.optimizer as optimizer_module
    from posegraph.init import initialize

    graph = read_g2o(shared_dataset("sphere2500"))
    start = initialize(graph, "chordal")
    result = optimize(graph, initial=start)
    optimum = optimize(graph, initial=start, params=SolverParams(relative_tolerance=1e-13, reuse_factorization=False))
    plain = optimize(graph, initial=start, params=SolverParams(decrement_stop=False))
    assert result.termination == optimizer_module.CONVERGED_DECREMENT and result.converged
    last = result.records[-1]
    assert (last.attempts, last.accepted, last.step_scale, last.seconds_factorize) == (0, True, 1.0, 0.0)
    assert 0.9 <= last.gain_ratio <= 1 / 0.9 and last.cost < result.records[-2].cost
    assert factorizations(result) == factorizations(plain) < factorizations(optimum)
    assert result.final_cost == pytest.approx(optimum.final_cost, rel=1e-10)
    assert result.final_cost == pytest.approx(cost(graph, result.poses), rel=1e-12)
    np.testing.assert_allclose(result.poses, plain.poses, rtol=0, atol=1e-12)


def _sim3_graph(seed):
    from tests.init.test_sim3_init import drifted_graph

    return drifted_graph(np.random.default_rng(seed), noise=0.01)[0]


PCG_GRAPHS = {
    "SE3": lambda: synthetic_graph(4, n=60, loops=40),
    "SE2": lambda: synthetic_graph(5, n=60, loops=40, group=SE2),
    "SE3, two components and FIX vertices": lambda: synthetic_graph(6, n=60, loops=40, fixed=[5, 40], components=2),
    "Sim3": lambda: _sim3_graph(7),
}


@pytest.mark.parametrize("name", PCG_GRAPHS)
def test_pcg_reaches_the_factorisations_optimum(name, monkeypatch):
    pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")
    from posegraph.linalg import multigrid

    monkeypatch.setattr(multigrid, "COARSEST_UNKNOWNS", 24)  # coarse levels even on a small graph
    graph = PCG_GRAPHS[name]()
    direct = optimize(graph, params=SolverParams(linear_solver="scipy"))
    iterative = optimize(graph, params=SolverParams(linear_solver="pcg"))
    assert iterative.linear_solver.startswith("pcg") and iterative.converged
    assert iterative.final_cost == pytest.approx(direct.final_cost, rel=1e-9)
    # both stop at LM's tolerances (relative decrease 1e-7), not at the same digit
    np.testing.assert_allclose(iterative.poses, direct.poses, rtol=0, atol=1e-3)


@pytest.mark.parametrize("name", ["sphere2500", "intel", "parking-garage"])
def test_pcg_reaches_the_factorisations_optimum_on_standard_files(name, shared_dataset):
    pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")
    graph = read_g2o(shared_dataset(name))
    direct = optimize(graph, params=SolverParams())
    iterative = optimize(graph, params=SolverParams(linear_solver="pcg"))
    assert iterative.converged  # (parking-garage's flat directions leave poses ~4e-3 apart at equal costs)
    assert iterative.final_cost == pytest.approx(direct.final_cost, rel=1e-9)


def test_auto_turns_to_pcg_when_the_factor_would_not_fit_and_reaches_the_same_optimum(monkeypatch):
    pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")
    from posegraph.linalg import cholmod, heap
    from posegraph.errors import PosegraphWarning

    if cholmod.load() is None:
        pytest.skip(f"CHOLMOD is not available: {cholmod.unavailable_reason()}")
    graph = PCG_GRAPHS["SE3"]()
    direct = optimize(graph)
    assert direct.linear_solver.startswith("cholmod")
    monkeypatch.setattr(heap, "available_bytes", lambda: 1000)  # no factor fits in 1 kB
    with pytest.warns(PosegraphWarning, match="would take"):
        iterative = optimize(graph)
    assert iterative.linear_solver.startswith("pcg") and iterative.converged
    assert iterative.final_cost == pytest.approx(direct.final_cost, rel=1e-9)
