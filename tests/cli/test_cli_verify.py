"""`posegraph verify-jacobians` end to end (the checks themselves are tested in tests/crosscheck/test_jacobians.py)."""

from __future__ import annotations

import re

import pytest

from tests.cli.conftest import run_cli


def test_verify_jacobians_passes_on_a_real_graph(shared_dataset):
    pytest.importorskip("gtsam")
    run = run_cli("verify-jacobians", shared_dataset("parking-garage"), "--samples", "60")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "edges of parking-garage.g2o" in run.stdout
    for quantity in ("so3.exp", "se3.log", "se3.right_jacobian_inverse", "edge Jacobian"):
        assert quantity in run.stdout
    assert "gtsam" in run.stdout and "finite differences" in run.stdout and "near π" in run.stdout
    passed, total = map(int, re.search(r"(\d+) of (\d+) checks within tolerance", run.stdout).groups())
    assert passed == total > 40
    assert "FAIL" not in run.stdout
