"""Graduated non-convexity: surrogate weights and μ schedule, the outer loop against gtsam's
``GncLMOptimizer`` on a linear problem, and outlier rejection on pose graphs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posegraph.robust.gnc import (
    GncParams,
    gnc_weights,
    initial_mu,
    inlier_thresholds,
    run_gnc,
    update_mu,
    weights_are_binary,
)
from posegraph.robust.losses import chi2_quantile, make_loss

CHI2_6 = 16.811893829770927  # chi2.ppf(0.99, 6)


# ---------------------------------------------------------------------------------------------
# Formulas


@settings(max_examples=60, deadline=None)
@given(mu=st.floats(1e-6, 1e6), threshold=st.floats(0.1, 100.0))
def test_tls_weights_are_continuous_and_decreasing(mu, threshold):
    """Eq. (14): 1 up to μ/(μ+1) c̄², 0 from (μ+1)/μ c̄², continuous and decreasing between."""
    lower, upper = mu / (mu + 1) * threshold, (mu + 1) / mu * threshold
    s = np.concatenate([np.linspace(0.0, 2 * upper, 2001), [lower, upper]])
    s.sort()
    w = gnc_weights(s, np.full_like(s, threshold), mu, "tls")
    assert np.all((w >= 0) & (w <= 1)) and np.all(np.diff(w) <= 1e-12)
    assert np.all(w[s <= lower * (1 - 1e-12)] == 1.0) and np.all(w[s >= upper] == 0.0)
    # Continuity at both ends of the transition (slope ~ μ/2 per unit of relative offset).
    delta = 1e-9 / (mu + 1)
    edge = gnc_weights(np.array([lower * (1 + delta), upper * (1 - delta)]), np.full(2, threshold), mu, "tls")
    np.testing.assert_allclose(edge, [1.0, 0.0], atol=1e-8)


def test_surrogates_tend_to_their_losses():
    """TLS at large μ is the TLS weight with scale c̄; Geman-McClure at μ = 1 is GM with scale c̄;
    TLS at small μ is convex, ℓ1-like (w √s constant), and GM at large μ nearly least squares."""
    s = np.geomspace(1e-3, 1e3, 400) * CHI2_6
    s = s[np.abs(s / CHI2_6 - 1) > 1e-3]
    thresholds = np.full_like(s, CHI2_6)
    c = np.sqrt(CHI2_6)
    np.testing.assert_array_equal(gnc_weights(s, thresholds, 1e9, "tls"), make_loss("tls", c).weight(s))
    np.testing.assert_allclose(gnc_weights(s, thresholds, 1.0, "gm"), make_loss("geman_mcclure", c).weight(s), rtol=1e-14)
    small = s[s < 10 * CHI2_6]
    mu = 1e-6
    l1 = gnc_weights(small, np.full_like(small, CHI2_6), mu, "tls") * np.sqrt(small)
    np.testing.assert_allclose(l1, np.sqrt(CHI2_6 * mu * (mu + 1)), rtol=5e-3)
    assert np.all(gnc_weights(small, np.full_like(small, CHI2_6), 1e6, "gm") > 0.99)


def test_initial_mu_and_schedule():
    thresholds = np.full(3, CHI2_6)
    s = np.array([1.0, 50.0, 400.0])
    # Remark 5: TLS μ₀ = c̄² / (2 s_max − c̄²); GM μ₀ = 2 s_max / c̄².
    assert initial_mu(s, thresholds, "tls") == pytest.approx(CHI2_6 / (2 * 400.0 - CHI2_6), rel=1e-15)
    assert initial_mu(s, thresholds, "gm") == pytest.approx(2 * 400.0 / CHI2_6, rel=1e-15)
    assert initial_mu(np.array([1.0, 2.0]), thresholds[:2], "tls") < 0  # nothing to reject
    assert initial_mu(np.array([1e30]), thresholds[:1], "tls") == 1e-6  # floor
    tls, gm = GncParams(), GncParams(loss="gm")
    assert update_mu(2.0, tls) == pytest.approx(2.8) and update_mu(2.0, gm) == pytest.approx(2.0 / 1.4)
    assert update_mu(1.2, gm) == 1.0


def test_thresholds_and_parameters():
    np.testing.assert_allclose(inlier_thresholds(6, 4, GncParams()), CHI2_6, rtol=1e-12)
    mixed = inlier_thresholds(np.array([3, 6, 3]), 3, GncParams())
    np.testing.assert_allclose(mixed, [chi2_quantile(0.99, 3), CHI2_6, chi2_quantile(0.99, 3)])
    np.testing.assert_array_equal(inlier_thresholds(6, 2, GncParams(inlier_threshold=9.0)), [9.0, 9.0])
    assert weights_are_binary(np.array([0.0, 1.0, 0.99995]), 1e-4) and not weights_are_binary(np.array([0.5]), 1e-4)
    for bad in (dict(loss="huber"), dict(mu_step=1.0), dict(max_iterations=0), dict(inlier_probability=1.0), dict(inlier_threshold=-1.0)):
        with pytest.raises(ValueError):
            GncParams(**bad)


# ---------------------------------------------------------------------------------------------
# The outer loop on a linear problem, step for step against gtsam


def linear_problem(seed: int, n: int = 12, outliers: int = 4):
    """Points ``x_v ∈ R³``: a chain ``x_{v+1} − x_v`` and random loop closures ``x_j − x_i``, each
    with a random SPD information; ``outliers`` of the loop closures measure a random vector.
    Edge 0 is a prior on ``x_0`` (the gauge). Returns (edges (m, 2) with −1 for the prior's
    'from', measurements (m, 3), information (m, 3, 3), known-inlier mask, outlier mask)."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(-10, 10, size=(n, 3))
    chain = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    loops = np.array([(i, j) for i in range(n) for j in range(i + 2, n)])
    loops = loops[rng.choice(len(loops), size=2 * n, replace=False)]
    edges = np.concatenate([[[-1, 0]], chain, loops])
    m = len(edges)
    a = rng.standard_normal((m, 3, 3))
    information = a @ np.swapaxes(a, 1, 2) + 0.5 * np.eye(3)
    start = np.where(edges[:, :1] >= 0, truth[np.maximum(edges[:, 0], 0)], 0.0)
    # noise ~ N(0, Ω⁻¹): L⁻ᵀ g with Ω = L Lᵀ
    noise = np.einsum("mji,mj->mi", np.linalg.inv(np.swapaxes(np.linalg.cholesky(information), 1, 2)), rng.standard_normal((m, 3)))
    measurements = truth[edges[:, 1]] - start + 0.3 * noise
    outlier = np.zeros(m, bool)
    outlier[rng.choice(np.arange(n, m), size=outliers, replace=False)] = True
    measurements[outlier] = rng.uniform(-20, 20, size=(outliers, 3))
    known = np.zeros(m, bool)
    known[:n] = True  # prior and chain
    return edges, measurements, information, known, outlier


def linear_residuals(x, edges, measurements):
    start = np.where(edges[:, :1] >= 0, x[np.maximum(edges[:, 0], 0)], 0.0)
    return x[edges[:, 1]] - start - measurements


def linear_callables(edges, measurements, information, n):
    """``squared_residuals`` and ``solve_weighted`` for :func:`run_gnc` (dense normal equations)."""

    def squared_residuals(x):
        e = linear_residuals(x, edges, measurements)
        return np.einsum("mi,mij,mj->m", e, information, e)

    def solve_weighted(start, weights):
        # e = A x − z; minimise ½ Σ w eᵀΩe: (Σ w AᵀΩA) x = Σ w AᵀΩz.
        m = len(edges)
        A = np.zeros((m, 3, 3 * n))
        for k, (i, j) in enumerate(edges):
            A[k, :, 3 * j : 3 * j + 3] = np.eye(3)
            if i >= 0:
                A[k, :, 3 * i : 3 * i + 3] = -np.eye(3)
        WA = weights[:, None, None] * information @ A
        H = np.einsum("mia,mib->ab", A, WA)
        b = np.einsum("mia,mi->a", WA, measurements)
        return np.linalg.solve(H, b).reshape(n, 3)

    return squared_residuals, solve_weighted


def gtsam_linear_gnc(edges, measurements, information, known, start, loss: str, max_iterations: int):
    gtsam = pytest.importorskip("gtsam")
    graph = gtsam.NonlinearFactorGraph()
    for (i, j), z, info in zip(edges.tolist(), measurements, information):
        noise = gtsam.noiseModel.Gaussian.Information(info)
        if i < 0:
            graph.add(gtsam.PriorFactorPoint3(j, z, noise))
        else:
            graph.add(gtsam.BetweenFactorPoint3(i, j, z, noise))
    values = gtsam.Values()
    for v, point in enumerate(start):
        values.insert(v, point)
    params = gtsam.GncLMParams()
    params.setLossType(gtsam.GncLossType.TLS if loss == "tls" else gtsam.GncLossType.GM)
    params.setKnownInliers(np.flatnonzero(known).tolist())
    params.setMaxIterations(max_iterations)
    base = params.baseOptimizerParams
    base.setRelativeErrorTol(1e-14)
    base.setAbsoluteErrorTol(1e-14)
    params.baseOptimizerParams = base
    optimizer = gtsam.GncLMOptimizer(graph, values, params)
    result = optimizer.optimize()
    return np.asarray(optimizer.getWeights()), np.array([result.atPoint3(v) for v in range(len(start))])


@pytest.mark.parametrize("loss", ["tls", "gm"])
@pytest.mark.parametrize("iterations", [1, 2, 3, 6])
def test_outer_iterations_match_gtsam(loss, iterations):
    """With gtsam's restart from x₀ (``warm_start=False``) and a linear problem, whose weighted
    solves have one solution, the weights after each of the first outer iterations — fractional,
    so they test μ₀, the μ update and the weight formulas — equal gtsam's."""
    edges, z, info, known, _ = linear_problem(seed=4)
    n = edges.max() + 1
    start = np.zeros((n, 3))
    squared, solve = linear_callables(edges, z, info, n)
    ours = run_gnc(squared, solve, start, known, GncParams(loss=loss, max_iterations=iterations, warm_start=False), dimension=3)
    assert ours.iterations == iterations  # not converged yet: the weights are mid-way
    assert not weights_are_binary(ours.weights, 1e-4)
    theirs, _ = gtsam_linear_gnc(edges, z, info, known, start, loss, iterations)
    np.testing.assert_allclose(ours.weights, theirs, rtol=0, atol=1e-7)


@pytest.mark.parametrize("loss", ["tls", "gm"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_converged_weights_match_gtsam_and_find_the_outliers(loss, seed):
    edges, z, info, known, outlier = linear_problem(seed=seed)
    n = edges.max() + 1
    start = np.zeros((n, 3))
    squared, solve = linear_callables(edges, z, info, n)
    history = []
    ours = run_gnc(squared, solve, start, known, GncParams(loss=loss, warm_start=False), dimension=3, progress=history.append)
    theirs, theirs_x = gtsam_linear_gnc(edges, z, info, known, start, loss, 100)
    np.testing.assert_array_equal(ours.weights > 0.5, theirs > 0.5)
    np.testing.assert_array_equal(ours.weights < 0.5, outlier)
    np.testing.assert_allclose(ours.poses, theirs_x, atol=1e-6)
    # The progress records: μ schedule and inlier counts.
    mus = np.array([record.mu for record in history])
    expected = mus[:-1] * 1.4 if loss == "tls" else np.maximum(1.0, mus[:-1] / 1.4)
    np.testing.assert_allclose(mus[1:], expected, rtol=1e-12)
    assert history[-1].inliers == len(z) - outlier.sum()
    assert ours.reason in ("weights", "cost", "mu")


def test_known_inliers_stay_at_weight_one():
    edges, z, info, known, outlier = linear_problem(seed=5)
    n = edges.max() + 1
    z = z.copy()
    z[3] += 50.0  # a wrong chain edge, declared a known inlier: it must keep weight 1
    squared, solve = linear_callables(edges, z, info, n)
    result = run_gnc(squared, solve, np.zeros((n, 3)), known, dimension=3)
    assert np.all(result.weights[known] == 1.0)
    unknown = run_gnc(squared, solve, np.zeros((n, 3)), None, dimension=3)
    assert unknown.weights[3] < 0.5


def test_nothing_to_do():
    edges, z, info, known, _ = linear_problem(seed=6, outliers=0)
    n = edges.max() + 1
    squared, solve = linear_callables(edges, z, info, n)
    everything_known = run_gnc(squared, solve, np.zeros((n, 3)), np.ones(len(z), bool), dimension=3)
    assert everything_known.reason == "all_known" and everything_known.iterations == 0
    truth_start = solve(None, np.ones(len(z)))
    small = run_gnc(squared, solve, truth_start, known, GncParams(inlier_threshold=1e9), dimension=3)
    assert small.reason == "no_large_residual" and np.all(small.weights == 1.0)
    with pytest.raises(ValueError, match="known_inliers"):
        run_gnc(squared, solve, truth_start, np.ones(3, bool), dimension=3)


# ---------------------------------------------------------------------------------------------
# Pose graphs with injected outliers


def pose_graph_gnc(graph, start: str = "odometry", params: GncParams | None = None):
    from posegraph.init import initialize
    from posegraph.solve import optimize
    from posegraph.solve.residuals import edge_residuals

    def squared_residuals(poses):
        e = edge_residuals(poses, graph)
        return np.einsum("mi,mij,mj->m", e, graph.information, e)

    def solve_weighted(poses, weights):
        weighted = dataclasses.replace(graph, information=graph.information * weights[:, None, None], edge_source=None)
        return optimize(weighted, initial=poses).poses

    return run_gnc(squared_residuals, solve_weighted, initialize(graph, start), graph.odometry_mask(), params)


def test_gnc_finds_every_injected_outlier_in_a_grid():
    from datasets.synthetic import grid, inject_outliers

    graph, indices = inject_outliers(grid(4, 4, 3, seed=1).graph, fraction=0.2, seed=1)
    result = pose_graph_gnc(graph)
    outlier = np.zeros(graph.num_edges, bool)
    outlier[indices] = True
    np.testing.assert_array_equal(~result.inliers, outlier)
    assert result.reason == "weights"


def test_gnc_finds_every_injected_outlier_in_small_grid3d(shared_dataset):
    from datasets.synthetic import inject_outliers
    from posegraph.io.g2o import read_g2o

    graph, indices = inject_outliers(read_g2o(shared_dataset("smallGrid3D")), fraction=0.2, seed=1)
    result = pose_graph_gnc(graph)
    outlier = np.zeros(graph.num_edges, bool)
    outlier[indices] = True
    assert not np.any(result.inliers & outlier)  # every outlier rejected
    loops = ~graph.odometry_mask() & ~outlier
    assert np.count_nonzero(~result.inliers & loops) <= 0.02 * np.count_nonzero(loops)  # few inliers lost
