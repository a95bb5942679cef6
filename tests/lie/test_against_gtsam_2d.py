"""Cross-validation of :mod:`se2`/:mod:`so2` against gtsam's ``Pose2``/``Rot2``.

Our batched functions run once over all inputs; gtsam runs in a Python loop.  Random inputs:
rotation angles with |ω| uniform in [0.3, 3] rad and random sign, translations ~ N(0, 3²) per
axis; edge cases: ω = 0, ±(π − 1e-6), ±π.  There every value agrees to 1e-12 (measured ~1e-14).

Small angles are compared differently, because gtsam's ``Pose2`` is not accurate there: its
closed forms cancel (``(cos ω − 1)/ω``, ``sin ω/(1 − cos ω)``, ``(v⊥ − R v⊥)/ω``), losing about
``eps/|ω|`` in ``Expmap``/``Logmap`` and up to ``eps/|ω|³`` in ``LogmapDerivative``, and below
|ω| = 1e-5 its ``ExpmapDerivative``/``LogmapDerivative`` keep only the first-order terms (an error
of ~|v||ω|/6).  At |ω| in [1e-12, 0.1] the test checks that ours is within a few ulps of a
40-digit mpmath value, and that ours and gtsam differ by no more than a model of gtsam's own
error (truncation plus cancellation; docs/lie.md lists the measured figures).
"""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.lie import se2, so2
from tests.lie import mpmath_reference as ref

gtsam = pytest.importorskip("gtsam")

TIGHT_TOLERANCE = 1e-12
N_RANDOM = 10_000
SMALL_ANGLES = (1e-12, 1e-8, 1e-6, 1e-5 * (1 - 1e-9), 1e-5 * (1 + 1e-9), 1e-4, 1e-3, 1e-2, 0.1)


def _signed(rng, magnitudes):
    return magnitudes * np.where(rng.uniform(size=magnitudes.shape) < 0.5, -1.0, 1.0)


def _inputs():
    rng = np.random.default_rng(2025)
    w = _signed(rng, rng.uniform(0.3, 3.0, size=N_RANDOM))
    random = np.c_[3.0 * rng.normal(size=(N_RANDOM, 2)), w]
    edge_angles = np.array([0.0, np.pi - 1e-6, -(np.pi - 1e-6), np.pi, -np.pi]).repeat(6)
    edge = np.c_[3.0 * rng.normal(size=(len(edge_angles), 2)), edge_angles]
    small_angles = np.array(SMALL_ANGLES).repeat(4)
    small = np.c_[3.0 * rng.normal(size=(len(small_angles), 2)), _signed(rng, small_angles)]
    return random, edge, small


RANDOM, EDGE, SMALL = _inputs()
AT_PI = np.abs(EDGE[:, 2]) == np.pi


def gtsam_pose(T):
    """gtsam's Pose2 holding exactly the rotation entries and translation of ``T (3, 3)``."""
    return gtsam.Pose2(gtsam.Rot2.fromCosSin(T[0, 0], T[1, 0]), np.ascontiguousarray(T[:2, 2]))


def _gtsam_references(xis):
    out = {k: [] for k in ("exp", "log", "Jr", "Jr_inv", "Jr_inv_pose", "Ad", "ad", "R", "w")}
    for xi in xis:
        pose = gtsam.Pose2.Expmap(xi)
        out["exp"].append(pose.matrix())
        out["log"].append(gtsam.Pose2.Logmap(pose))
        out["Jr"].append(gtsam.Pose2.ExpmapDerivative(xi))
        out["Jr_inv"].append(gtsam.Pose2.LogmapDerivative(xi))
        out["Jr_inv_pose"].append(gtsam.Pose2.LogmapDerivative(pose))
        out["Ad"].append(pose.AdjointMap())
        out["ad"].append(gtsam.Pose2.adjointMap(xi))
        rot = gtsam.Rot2.Expmap(xi[2:])
        out["R"].append(rot.matrix())
        out["w"].append(gtsam.Rot2.Logmap(rot))
    return {k: np.array(v) for k, v in out.items()}


def _ours(xi, gt):
    """Our values of everything gtsam computed, each in one batched call (Log of gtsam's poses)."""
    return {
        "exp": se2.exp(xi),
        "log": se2.log(gt["exp"]),
        "Jr": se2.right_jacobian(xi),
        "Jr_inv": se2.right_jacobian_inverse(xi),
        "Jr_inv_pose": se2.right_jacobian_inverse(se2.log(gt["exp"])),
        "Ad": se2.adjoint(gt["exp"]),
        "ad": se2.ad(xi),
        "R": so2.exp(xi[:, 2:]),
        "w": so2.log(gt["R"]),
    }


GTSAM_NAMES = {
    "exp": "Pose2.Expmap",
    "log": "Pose2.Logmap",
    "Jr": "Pose2.ExpmapDerivative",
    "Jr_inv": "Pose2.LogmapDerivative(xi)",
    "Jr_inv_pose": "Pose2.LogmapDerivative(pose)",
    "Ad": "Pose2.AdjointMap",
    "ad": "Pose2.adjointMap",
    "R": "Rot2.Expmap",
    "w": "Rot2.Logmap",
}


@pytest.fixture(scope="module")
def reference():
    return {"random": _gtsam_references(RANDOM), "edge": _gtsam_references(EDGE), "small": _gtsam_references(SMALL)}


def _max_abs(a, b):
    return float(np.abs(np.asarray(a) - np.asarray(b)).max())


@pytest.mark.parametrize("name", list(GTSAM_NAMES))
def test_random_inputs_match_gtsam(reference, name):
    gt = reference["random"]
    diff = _max_abs(_ours(RANDOM, gt)[name], gt[name])
    assert diff <= TIGHT_TOLERANCE, f"{GTSAM_NAMES[name]}: max |ours − gtsam| = {diff:.2e}"


@pytest.mark.parametrize("name", list(GTSAM_NAMES))
def test_zero_and_near_pi_match_gtsam(reference, name):
    gt = reference["edge"]
    ours = _ours(EDGE, gt)[name]
    if name in ("log", "w"):
        # at ω = ±π both signs are right: compare Exp of the logs there, the values elsewhere
        exp = se2.exp if name == "log" else so2.exp
        np.testing.assert_allclose(exp(ours[AT_PI]), exp(gt[name][AT_PI]), atol=1e-14)
        ours, values = ours[~AT_PI], gt[name][~AT_PI]
    else:
        values = gt[name]
    diff = _max_abs(ours, values)
    assert diff <= TIGHT_TOLERANCE, f"{GTSAM_NAMES[name]}: max |ours − gtsam| = {diff:.2e}"


_MPMATH = {
    "exp": lambda x, T: ref.se2_exp(x),
    "log": lambda x, T: ref.se2_log(T),
    "Jr": lambda x, T: ref.se2_right_jacobian(x),
    "Jr_inv": lambda x, T: ref.se2_right_jacobian_inverse(x),
}
# Power of 1/|ω| in the rounding error of gtsam's closed form (module docstring).
_GTSAM_CANCELLATION_ORDER = {"exp": 1, "log": 1, "Jr": 2, "Jr_inv": 3, "Jr_inv_pose": 3}
_GTSAM_FIRST_ORDER_BELOW = 1e-5  # below this gtsam's Pose2 derivatives keep the first-order terms only


def _gtsam_error_model(name, xi):
    """Bound on gtsam's error at small |ω|: first-order truncation + cancellation in its closed form.

    Truncation ``(1 + |v|)|ω|`` where gtsam drops the higher terms (its derivatives below 1e-5,
    Expmap/Logmap below 1e-10), rounding ``eps (1 + |v|)/|ω|ᵏ`` above (k = 1, 2, 3 as the closed
    form divides by ω once, twice, or by ω (1 − cos ω)).  Measured ratios stay below 0.6.
    """
    w, size = abs(xi[2]), 1.0 + np.linalg.norm(xi[:2])
    truncated = w < (_GTSAM_FIRST_ORDER_BELOW if name.startswith("Jr") else 1e-10)
    return (size * w if truncated else 0.0) + np.finfo(float).eps * size / w ** _GTSAM_CANCELLATION_ORDER[name]


@pytest.mark.parametrize("name", list(_MPMATH))
def test_small_angles_ours_matches_40_digit_values(reference, name):
    gt = reference["small"]
    ours = _ours(SMALL, gt)[name]
    for x, T, o in zip(SMALL, gt["exp"], ours):
        error = _max_abs(o, _MPMATH[name](x, T))
        assert error <= 1e-14, f"{name} at ω = {x[2]!r}: max |ours − mpmath| = {error:.1e}"


@pytest.mark.parametrize("name", list(_GTSAM_CANCELLATION_ORDER))
def test_small_angles_differ_from_gtsam_only_by_gtsams_known_error(reference, name):
    gt = reference["small"]
    ours = _ours(SMALL, gt)[name]
    for x, o, g in zip(SMALL, ours, gt[name]):
        diff, bound = _max_abs(o, g), _gtsam_error_model(name, x)
        assert diff <= bound, f"{GTSAM_NAMES[name]} at ω = {x[2]!r}: |ours − gtsam| = {diff:.1e} > {bound:.1e}"


def test_group_operation_jacobians_match_gtsam():
    rng = np.random.default_rng(7)
    n = 2_000
    a = se2.exp(np.r_[RANDOM[:n], EDGE, SMALL][:n])
    b = se2.exp(RANDOM[n : 2 * n])
    p = 5.0 * rng.normal(size=(n, 2))
    ours = {"compose": se2.compose_jacobians(a, b), "between": se2.between_jacobians(a, b), "act": se2.act_jacobians(a, p)}
    values = {"compose": se2.compose(a, b), "between": se2.between(a, b), "inverse": se2.inverse(a), "act": se2.act(a, p)}
    worst = 0.0
    for i in range(n):
        pa, pb = gtsam_pose(a[i]), gtsam_pose(b[i])
        H1, H2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        worst = max(worst, _max_abs(pa.compose(pb, H1, H2).matrix(), values["compose"][i]))
        worst = max(worst, _max_abs(H1, ours["compose"][0][i]), _max_abs(H2, ours["compose"][1][i]))
        worst = max(worst, _max_abs(pa.between(pb, H1, H2).matrix(), values["between"][i]))
        worst = max(worst, _max_abs(H1, ours["between"][0][i]), _max_abs(H2, ours["between"][1][i]))
        # the Python wrapper of Pose2.inverse takes no Jacobian (test_groups.py checks ours by finite differences)
        worst = max(worst, _max_abs(pa.inverse().matrix(), values["inverse"][i]))
        HT, Hp = np.zeros((2, 3), order="F"), np.zeros((2, 2), order="F")
        worst = max(worst, _max_abs(pa.transformFrom(p[i], HT, Hp), values["act"][i]))
        worst = max(worst, _max_abs(HT, ours["act"][0][i]), _max_abs(Hp, ours["act"][1][i]))
    assert worst <= TIGHT_TOLERANCE, f"max |ours − gtsam| over compose/between/inverse/act and their Jacobians = {worst:.2e}"
