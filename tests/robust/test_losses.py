"""Robust losses: values and weights against gtsam's mEstimators, derivatives against finite
differences, and the robust cost of a real graph against gtsam's ``graph.error``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posegraph.robust.losses import DEFAULT_SCALES, LOSS_NAMES, chi2_quantile, make_loss

SCALES = (0.3, 1.0, 2.5, 7.0)


def gtsam_estimator(name: str, scale: float):
    """gtsam's mEstimator for our loss ``name`` at scale ``c`` (DCS takes Φ = c²)."""
    gtsam = pytest.importorskip("gtsam")
    m = gtsam.noiseModel.mEstimator
    factories = {
        "huber": lambda: m.Huber.Create(scale),
        "cauchy": lambda: m.Cauchy.Create(scale),
        "geman_mcclure": lambda: m.GemanMcClure.Create(scale),
        "tukey": lambda: m.Tukey.Create(scale),
        "dcs": lambda: m.DCS.Create(scale * scale),
        "tls": lambda: m.TruncatedLeastSquares.Create(scale),
    }
    return factories[name]()


def test_every_loss_has_a_gtsam_counterpart():
    pytest.importorskip("gtsam")
    for name in LOSS_NAMES:
        assert gtsam_estimator(name, 1.0) is not None


@pytest.mark.parametrize("scale", SCALES)
@pytest.mark.parametrize("name", LOSS_NAMES)
def test_rho_and_weight_match_gtsam(name, scale):
    """ρ(s) = 2 · loss(√s) and ρ'(s) = weight(√s) over both sides of the scale."""
    estimator = gtsam_estimator(name, scale)
    # Squared norms from far inside to far beyond c², avoiding the exact switch point.
    s = np.concatenate([[0.0], scale**2 * np.geomspace(1e-6, 1e4, 301)])
    s = s[np.abs(s - scale**2) > 1e-9 * scale**2]
    loss = make_loss(name, scale)
    expected_rho = np.array([2.0 * estimator.loss(np.sqrt(v)) for v in s])
    expected_weight = np.array([estimator.weight(np.sqrt(v)) for v in s])
    # gtsam's Tukey evaluates c²/6 (1 − (1 − x²/c²)³), which loses digits to cancellation as
    # x → 0 (absolute error ~ ε c²); ours has none, hence the absolute tolerance in units of c².
    np.testing.assert_allclose(loss.rho(s), expected_rho, rtol=1e-13, atol=1e-14 * scale**2)
    np.testing.assert_allclose(loss.weight(s), expected_weight, rtol=1e-13, atol=1e-300)
    # Both branches were exercised: the weight left 1 somewhere.
    assert expected_weight.min() < 0.5


@pytest.mark.parametrize("name", LOSS_NAMES)
def test_small_residuals_are_least_squares(name):
    loss = make_loss(name, 2.0)
    s = np.array([0.0, 1e-12])
    np.testing.assert_allclose(loss.rho(s), s, rtol=1e-6, atol=0)
    np.testing.assert_allclose(loss.weight(0.0), 1.0)


def _central_difference(f, s, h):
    return (f(s + h) - f(s - h)) / (2.0 * h)


@settings(max_examples=60, deadline=None)
@given(
    name=st.sampled_from(LOSS_NAMES),
    scale=st.floats(0.05, 50.0),
    ratio=st.floats(1e-3, 1e3),
)
def test_weight_and_second_derivative_are_derivatives(name, scale, ratio):
    """ρ' and ρ'' equal central differences of ρ and ρ' away from the loss's switch point."""
    c2 = scale * scale
    s = ratio * c2
    if abs(ratio - 1.0) < 1e-3:  # Huber, Tukey, DCS and TLS switch branch at s = c²
        return
    loss = make_loss(name, scale)
    h = 1e-5 * min(s, abs(s - c2))
    tol = 1e-6
    # a central difference of f carries round-off up to ~eps·|f|/h: where ρ is nearly flat (Tukey
    # just below c², ρ' = 6e-5 of ρ) that, not the derivative, sets the tolerance
    rounding = lambda f: 4 * np.finfo(float).eps * abs(float(f(s))) / h  # noqa: E731
    rho_prime = _central_difference(loss.rho, s, h)
    np.testing.assert_allclose(loss.weight(s), rho_prime, rtol=tol, atol=tol * abs(loss.weight(s)) + 1e-13 + rounding(loss.rho))
    rho_second = _central_difference(loss.weight, s, h)
    np.testing.assert_allclose(loss.second_derivative(s), rho_second, rtol=tol, atol=1e-12 / c2 + rounding(loss.weight))


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(LOSS_NAMES), scale=st.floats(0.05, 50.0), s=st.floats(0.0, 1e8))
def test_loss_properties(name, scale, s):
    """ρ is increasing, never above s, and its weight lies in [0, 1]."""
    loss = make_loss(name, scale)
    rho, weight = float(loss.rho(s)), float(loss.weight(s))
    assert 0.0 <= weight <= 1.0
    assert 0.0 <= rho <= s * (1 + 1e-12) + np.finfo(float).tiny  # subnormal s: no relative precision left
    assert float(loss.rho(s * 1.5 + 1.0)) >= rho - 1e-12 * rho


@pytest.mark.parametrize("shape", [(), (7,), (3, 4), (2, 0)])
@pytest.mark.parametrize("name", LOSS_NAMES)
def test_vectorised_over_any_shape(name, shape):
    rng = np.random.default_rng(1)
    s = rng.exponential(5.0, size=shape)
    loss = make_loss(name, 1.5)
    for method in (loss.rho, loss.weight, loss.second_derivative):
        values = method(s)
        assert np.shape(values) == shape
        flat = np.array([float(method(v)) for v in np.ravel(s)])
        np.testing.assert_array_equal(np.ravel(values), flat)


def test_defaults():
    for name, scale in DEFAULT_SCALES.items():
        assert make_loss(name).scale == scale
    # TLS: the χ² quantile at 0.99 for the residual's dimension (gtsam's GNC inlier threshold).
    assert make_loss("tls").scale == pytest.approx(np.sqrt(16.811893829770927), rel=1e-12)
    assert make_loss("tls", dimension=3).scale == pytest.approx(np.sqrt(11.344866730144373), rel=1e-12)
    assert make_loss("Geman-McClure", 2.0).name == "geman_mcclure"


def test_chi2_quantile_matches_scipy():
    stats = pytest.importorskip("scipy.stats")
    for dimension in (1, 3, 6):
        for p in (0.5, 0.95, 0.99):
            assert chi2_quantile(p, dimension) == pytest.approx(stats.chi2.ppf(p, dimension), rel=1e-12)
    with pytest.raises(ValueError, match="probability"):
        chi2_quantile(1.0, 6)
    with pytest.raises(ValueError, match="dimension"):
        chi2_quantile(0.99, 0)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "1"])
def test_bad_scale_is_a_clear_error(bad):
    with pytest.raises(ValueError, match="scale must be a finite number > 0"):
        make_loss("huber", bad)


def test_unknown_name_lists_the_allowed_ones():
    with pytest.raises(ValueError) as info:
        make_loss("l1")
    for name in LOSS_NAMES:
        assert name in str(info.value)


def test_import_does_not_load_scipy():
    code = "import posegraph.robust, posegraph.robust.gnc, posegraph.robust.starts, posegraph.robust.measurements, sys; print('scipy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ---------------------------------------------------------------------------------------------
# The robust cost of a real graph equals gtsam's graph.error with Robust noise models.


def _robust_gtsam_graph(graph, estimator):
    gtsam = pytest.importorskip("gtsam")
    factors = gtsam.NonlinearFactorGraph()
    ids = graph.ids.tolist()
    for i, j, Z, info in zip(graph.edge_from.tolist(), graph.edge_to.tolist(), graph.measurements, graph.information):
        noise = gtsam.noiseModel.Robust.Create(estimator, gtsam.noiseModel.Gaussian.Information(info))
        factors.add(gtsam.BetweenFactorPose3(ids[i], ids[j], gtsam.Pose3(Z), noise))
    return factors


@pytest.mark.parametrize("dataset", ["tinyGrid3D", "smallGrid3D"])
@pytest.mark.parametrize("name", LOSS_NAMES)
def test_robust_cost_equals_gtsam_graph_error(shared_dataset, dataset, name):
    from posegraph.crosscheck.gtsam_bridge import poses_to_values
    from posegraph.io.g2o import read_g2o
    from posegraph.solve.residuals import edge_residuals

    graph = read_g2o(shared_dataset(dataset))
    # Perturbed poses so that residuals spread over both sides of the scale.
    rng = np.random.default_rng(3)
    from posegraph.lie import se3

    poses = graph.poses @ se3.exp(0.05 * rng.standard_normal((graph.num_vertices, 6)))
    e = edge_residuals(poses, graph)
    s = np.einsum("mi,mij,mj->m", e, graph.information, e)
    scale = float(np.sqrt(np.median(s)))  # half the edges beyond the scale
    loss = make_loss(name, scale)
    ours = loss.cost(s)
    theirs = _robust_gtsam_graph(graph, gtsam_estimator(name, scale)).error(poses_to_values(graph.ids, poses))
    assert ours == pytest.approx(theirs, rel=1e-11)
    assert ours < 0.5 * float(np.sum(s)) * 0.99  # the loss did cut the cost
