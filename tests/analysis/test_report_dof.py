"""χ²'s degrees of freedom: measurement rows per family minus free unknowns per kind of variable."""

from __future__ import annotations

import json

import numpy as np
import pytest

from datasets.synthetic import landmark_graph
from posegraph.analysis.report import chi2_summary, dof_equation, per_dof_text
from posegraph.lie.group import SE2, SE3


def test_landmark_graph_counts_points_as_points_and_their_rows_as_theirs():
    """30 SE(2) poses (29 odometry edges, 3 rows), 12 points (2 unknowns each), position (2 rows) and
    bearing (1 row) measurements, 4 per point and family: dof = 3·29 + 2·48 + 1·48 − 3·29 − 2·12."""
    graph, _, _ = landmark_graph(SE2, 30, 12, ("position", "bearing"), noise=0.02, seed=11, per_landmark=4)
    chi2 = chi2_summary(graph)
    assert chi2["dof"] == 3 * 29 + 2 * 48 + 1 * 48 - 3 * 29 - 2 * 12
    assert dof_equation(chi2) == ("3·29 edges + 2·48 position measurements + 1·48 bearing measurements"
                                  " − 3·29 free poses − 2·12 free points = 120")
    assert chi2["chi2_per_dof"] == pytest.approx(chi2["chi2"] / 120)


def test_3d_points_count_three_unknowns():
    graph, _, _ = landmark_graph(SE3, 10, 5, ("position",), noise=0.02, seed=3, per_landmark=3)
    chi2 = chi2_summary(graph)
    assert chi2["dof"] == 6 * 9 + 3 * 15 - 6 * 9 - 3 * 5
    assert "3·5 free points" in dof_equation(chi2)


def test_zero_dof_is_undefined_not_nan_and_reports_null():
    """An odometry chain: as many rows as unknowns; χ²/dof is undefined, printed so, null in JSON."""
    from posegraph.io.atomic import json_text

    graph, _, _ = landmark_graph(SE2, 6, 1, (), noise=0.02, seed=1)
    graph = _without_landmarks(graph)
    chi2 = chi2_summary(graph)
    assert chi2["dof"] == 0 and np.isnan(chi2["chi2_per_dof"])
    assert per_dof_text(chi2) == "undefined (dof 0)"
    assert json.loads(json_text(chi2), parse_constant=_refuse)["chi2_per_dof"] is None


def _without_landmarks(graph):
    import dataclasses

    return dataclasses.replace(graph, landmarks=None)


def _refuse(name):
    raise AssertionError(f"non-strict JSON constant {name}")
