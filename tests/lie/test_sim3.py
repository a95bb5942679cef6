"""Sim(3) beyond the shared group tests (test_groups.py runs those over sim3 too): gtsam's
``Similarity3`` to 1e-12, V's coefficients against 40-digit quadrature in every regime of the
module docstring, identities over random batch shapes (hypothesis), g2o's own ``Sim3::log``.

gtsam's ``Similarity3(R, t, s)`` is ``[[R, t], [0, 1/s]]``; its image here is ``[[s R, s t], [0, 1]]``
and the tangent ``[ω; υ; λ]`` is the same (``posegraph/lie/sim3.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posegraph.lie import sim3
from tests.lie.helpers import sim3_tangents

gtsam = pytest.importorskip("gtsam", reason="gtsam's wheel is not installed: no Similarity3 to compare with")

pytestmark = pytest.mark.filterwarnings("error")


def ours(g) -> np.ndarray:
    """gtsam's ``Similarity3`` as this module's matrix ``[[s R, s t], [0, 1]]``."""
    s = g.scale()
    return sim3.from_rotation_translation_scale(g.rotation().matrix(), s * g.translation(), s)


def scaled(a, b) -> float:
    """``max |a − b| / (1 + |b|)``: relative for large entries, absolute for small ones."""
    return float(np.max(np.abs(np.asarray(a) - b) / (1.0 + np.abs(b))))


def cases(seed=0, n=60) -> np.ndarray:
    """Random tangents (θ < π, |υ| ~ 2, λ ~ N(0, ½)) and some with λ = 0, θ = 0, both small."""
    rng = np.random.default_rng(seed)
    xi = sim3_tangents(rng, (n,))
    xi[:5, 6] = 0.0
    xi[5:10, :3] = 0.0
    xi[10:15, :3] *= 1e-3 / np.linalg.norm(xi[10:15, :3], axis=1, keepdims=True)
    xi[10:15, 6] = 1e-4
    return xi


def test_matrix_form_is_gtsams_normalised():
    g = gtsam.Similarity3.Expmap(cases()[20])
    np.testing.assert_allclose(g.scale() * g.matrix(), ours(g), rtol=0, atol=1e-14)


def test_exp_log_adjoint_against_gtsam():
    xi = cases()
    reference = [gtsam.Similarity3.Expmap(x) for x in xi]
    S = sim3.exp(xi)
    assert scaled(S, np.stack([ours(g) for g in reference])) < 1e-12
    assert scaled(sim3.log(S), np.stack([gtsam.Similarity3.Logmap(g) for g in reference])) < 1e-12
    assert scaled(sim3.adjoint(S), np.stack([g.AdjointMap() for g in reference])) < 1e-12


def test_compose_between_inverse_against_gtsam():
    xi = cases(1)
    g = [gtsam.Similarity3.Expmap(x) for x in xi]
    S = sim3.exp(xi)
    assert scaled(sim3.compose(S[:-1], S[1:]), np.stack([ours(a.compose(b)) for a, b in zip(g[:-1], g[1:])])) < 1e-12
    assert scaled(sim3.between(S[:-1], S[1:]), np.stack([ours(a.between(b)) for a, b in zip(g[:-1], g[1:])])) < 1e-12
    assert scaled(sim3.inverse(S), np.stack([ours(a.inverse()) for a in g])) < 1e-12


def _v_reference(theta: float, lam: float) -> tuple[float, float, float]:
    """``(a, b, c)`` as the defining integrals ``∫₀¹ e^{λτ}(1, sin θτ/θ, (1 − cos θτ)/θ²) dτ``, 40 digits."""
    mpmath = pytest.importorskip("mpmath")
    with mpmath.workdps(40):
        t, l = mpmath.mpf(theta), mpmath.mpf(lam)
        sin_ratio = (lambda x: mpmath.sin(t * x) / t) if theta else (lambda x: x)
        cos_ratio = (lambda x: (1 - mpmath.cos(t * x)) / t**2) if theta else (lambda x: x * x / 2)
        return tuple(float(mpmath.quad(lambda x, f=f: mpmath.exp(l * x) * f(x), [0, 1])) for f in (lambda x: 1, sin_ratio, cos_ratio))


@pytest.mark.parametrize("theta", [0.0, 1e-9, 1e-4, 0.1, 0.35, 0.6999, 0.7001, 1.0, np.pi])
@pytest.mark.parametrize("lam", [0.0, 5e-324, -1e-310, 1e-200, 1e-12, -1e-7, 1e-3, 0.3, -0.6999, 0.7001, 1.5, -3.0])
def test_v_coefficients_in_every_regime(theta, lam):
    """Both-small series, θ → 0 alone, λ → 0 alone (down to subnormal λ), λ = 0 exactly, and either side of |z| = 0.7."""
    got = sim3.v_coefficients(np.array([theta]), np.array([lam]))
    for value, reference in zip(got, _v_reference(theta, lam)):
        assert abs(value[0] - reference) <= 4e-15 * abs(reference)


def test_v_inverse_is_exact_through_pi():
    xi = np.zeros((3, 7))
    xi[:, 0] = [np.pi, np.pi - 1e-9, 3.0]
    xi[:, 3:6] = [1.0, 2.0, 3.0]
    xi[1, 6] = 0.2
    np.testing.assert_allclose(sim3.log(sim3.exp(xi))[:, 3:], xi[:, 3:], rtol=0, atol=1e-13)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(1, 3), min_size=0, max_size=3).map(tuple), st.integers(0, 2**32 - 1))
def test_identities_over_batch_shapes(shape, seed):
    rng = np.random.default_rng(seed)
    xi = sim3_tangents(rng, shape, max_angle=3.0)
    S = sim3.exp(xi)
    assert S.shape == shape + (4, 4)
    np.testing.assert_allclose(sim3.log(S), xi, rtol=0, atol=1e-12)
    eye = np.broadcast_to(np.eye(7), shape + (7, 7))
    Jr = sim3.right_jacobian(xi)
    np.testing.assert_allclose(sim3.right_jacobian_inverse(xi) @ Jr, eye, atol=1e-12)
    np.testing.assert_allclose(sim3.left_jacobian(xi), sim3.adjoint(S) @ Jr, atol=1e-11)
    np.testing.assert_allclose(sim3.adjoint(sim3.inverse(S)) @ sim3.adjoint(S), eye, atol=1e-11)
    np.testing.assert_allclose(sim3.scale(S), np.exp(xi[..., 6]), rtol=1e-14)


def test_g2o_log_is_g2os_first_order_log():
    """Below g2o's thresholds (θ ≲ 4.5e-3, |σ| < 1e-5) its log differs from the exact one at first
    order; :func:`sim3.g2o_log` follows g2o's branches, checked against g2opy's ``Sim3.log``."""
    g2o = pytest.importorskip("g2opy", reason="the g2opy wheel is not installed")
    rng = np.random.default_rng(3)
    xi = sim3_tangents(rng, (48,))
    xi[:16, :3] *= 2e-3 / np.linalg.norm(xi[:16, :3], axis=1, keepdims=True)
    xi[8:24, 6] = rng.uniform(-5e-6, 5e-6, 16)
    S = sim3.exp(xi)
    reference = np.stack([g2o.Sim3(sim3.rotation(M), M[:3, 3].copy(), float(sim3.scale(M))).log() for M in S])
    assert scaled(sim3.g2o_log(S), reference) < 1e-12
    assert scaled(sim3.log(S)[:24], reference[:24]) > 1e-7  # the branches matter
