"""verify-jacobians logic: passes on the real core, and catches a planted mistake."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.crosscheck.jacobians import (
    CLOSED_FORM_TOLERANCE,
    FINITE_DIFFERENCE_TOLERANCE,
    GTSAM_NEAR_PI_TOLERANCE,
    format_checks,
    verify_all,
)


def test_every_check_passes_and_covers_the_hard_cases():
    pytest.importorskip("gtsam")
    checks = verify_all(samples=40, seed=1)
    failed = [c.name for c in checks if not c.passed]
    assert not failed, format_checks(checks)
    families = {c.cases for c in checks}
    assert {"random", "near 0", "near π"} <= families
    references = {c.reference for c in checks}
    assert "finite differences" in references and any(r.startswith("gtsam") for r in references)
    tolerances = {CLOSED_FORM_TOLERANCE, FINITE_DIFFERENCE_TOLERANCE, GTSAM_NEAR_PI_TOLERANCE}
    assert {c.tolerance for c in checks} == tolerances
    # The looser gtsam tolerance applies only near π, where gtsam itself is the less accurate side.
    assert all(c.tolerance == CLOSED_FORM_TOLERANCE for c in checks
               if c.reference.startswith("gtsam") and c.cases != "near π")


def test_without_gtsam_finite_differences_still_run():
    checks = verify_all(samples=20, use_gtsam=False)
    assert checks and all(not c.reference.startswith("gtsam") for c in checks)
    assert all(c.passed for c in checks), format_checks(checks)


def test_a_transposed_jacobian_is_caught(monkeypatch):
    from posegraph.lie import se3

    real = se3.right_jacobian_inverse
    monkeypatch.setattr(se3, "right_jacobian_inverse", lambda xi: np.swapaxes(real(xi), -1, -2))
    checks = verify_all(samples=20, use_gtsam=False)
    failed = {c.quantity for c in checks if not c.passed}
    assert "se3.right_jacobian_inverse" in failed
    assert "edge Jacobian ∂e/∂δj" in failed
    assert "FAIL" in format_checks(checks)


def test_a_wrong_small_angle_branch_is_caught(monkeypatch):
    """Jl in place of Jr (they differ in the sign of the odd-order terms) is caught."""
    from posegraph.lie import so3

    monkeypatch.setattr(so3, "right_jacobian", so3.left_jacobian)
    checks = verify_all(samples=20, use_gtsam=False)
    assert any(c.quantity == "so3.right_jacobian" and not c.passed for c in checks)


@pytest.mark.parametrize("group_name", ["SE3", "SE2"])
def test_a_graph_with_priors_gets_its_prior_jacobians_checked_and_a_wrong_one_caught(monkeypatch, group_name):
    pytest.importorskip("gtsam")
    from posegraph.lie.group import SE2, SE3
    from posegraph.solve import unary
    from tests.solve.test_unary import chain_graph, make_priors

    group = SE3 if group_name == "SE3" else SE2
    rng = np.random.default_rng(3)
    graph = chain_graph(rng, group, priors=make_priors(rng, group, 6))
    checks = [c for c in verify_all(graph, samples=5) if c.cases.startswith("priors of")]
    assert {c.quantity for c in checks} == {"pose prior Jacobian ∂e/∂δ", "position prior Jacobian ∂e/∂δ", "prior eᵀΩe"}
    assert all(c.passed for c in checks), format_checks(checks)
    real = unary.prior_jacobians
    monkeypatch.setattr(unary, "prior_jacobians", lambda *a: (real(*a)[0], -real(*a)[1]))
    failed = {c.quantity for c in verify_all(graph, samples=5, use_gtsam=False) if not c.passed}
    assert failed == {"position prior Jacobian ∂e/∂δ"}
def test_sim3_is_covered_and_a_wrong_quadrature_is_caught(monkeypatch):
    """Sim(3) runs every family and its edges; too few Gauss–Legendre nodes for Jr's integral fail."""
    from posegraph.lie import sim3

    checks = verify_all(samples=20, use_gtsam=False)
    sim3_checks = [c for c in checks if c.quantity.startswith("sim3.") or c.cases.startswith("Sim(3)")]
    assert {c.cases for c in sim3_checks} >= {"random", "near 0", "near π", "Sim(3) random, small residuals"}
    assert all(c.passed for c in sim3_checks)
    nodes, weights = np.polynomial.legendre.leggauss(1)
    monkeypatch.setattr(sim3, "_TAU", 0.5 * (nodes + 1.0))
    monkeypatch.setattr(sim3, "_TAU_WEIGHTS", 0.5 * weights)
    failed = {c.quantity for c in verify_all(samples=20, use_gtsam=False) if not c.passed}
    assert {"sim3.right_jacobian", "sim3.right_jacobian_inverse", "edge Jacobian ∂e/∂δi"} <= failed
