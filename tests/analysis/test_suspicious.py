"""The broken-map check: edges judged against each other, silent on clean graphs at any information scale."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from datasets.synthetic import NoiseParams, generate, inject_outliers
from posegraph.analysis.suspicious import BROKEN_GAIN, suspicious_edges
from posegraph.solve import optimize


def _grid(outliers: float):
    data = generate("grid", 216, noise=NoiseParams(loop_closure_density=0.5, outlier_fraction=outliers), seed=1)
    return data.graph, np.flatnonzero(data.outliers)


def _judged(graph):
    return suspicious_edges(graph, optimize(graph).poses)


@pytest.mark.parametrize("scale", [1.0, 0.01, 100.0])
def test_clean_graph_is_not_broken_whatever_the_information_scale(scale):
    """A clean grid, its information as generated, underconfident (×0.01) and overconfident (×100):
    no verdict of broken, and the gain the same at every scale (the test is scale-free)."""
    graph, _ = _grid(0.0)
    graph = dataclasses.replace(graph, information=graph.information * scale)
    verdict = _judged(graph)
    assert verdict.judged and not verdict.broken
    assert verdict.gain < 1.5 and len(verdict.edges) == 0
    assert verdict.gain == pytest.approx(_judged(_grid(0.0)[0]).gain, rel=1e-6)


def test_wrong_loop_closures_make_the_map_broken_and_are_named():
    """10 % look-alike wrong loop closures: broken, and every named edge is one of them, most of them named."""
    graph, wrong = _grid(0.1)
    verdict = _judged(graph)
    assert verdict.broken and verdict.gain >= BROKEN_GAIN
    assert set(verdict.edges.tolist()) <= set(wrong.tolist())
    assert len(verdict.edges) >= 0.8 * len(wrong)
    # named worst first: the refit χ² over the refit level, decreasing
    ratios = verdict.refit_chi2 / verdict.refit_level
    assert np.all(np.diff(ratios) <= 0)
    rows = verdict.rows(graph, 2)
    assert len(rows) == 2 and rows[0]["edge"] == verdict.edges[0]
    assert (rows[0]["from_id"], rows[0]["to_id"]) == (int(graph.ids[graph.edge_from[verdict.edges[0]]]),
                                                     int(graph.ids[graph.edge_to[verdict.edges[0]]]))


def test_random_wrong_loop_closures_in_a_planar_graph():
    """2D: the generator's Manhattan world with 5 % random wrong loop closures (inject_outliers) is judged
    broken, the clean one not."""
    clean = generate("manhattan", 500, noise=NoiseParams(loop_closure_density=0.5), seed=1).graph
    corrupted, wrong = inject_outliers(clean, fraction=0.05, seed=1)
    assert not _judged(clean).broken
    verdict = _judged(corrupted)
    assert verdict.broken and np.isin(verdict.edges, wrong).mean() >= 0.8


def test_no_verdict_without_enough_loop_closures():
    """An odometry chain with a couple of loop closures: nothing to judge against, nothing named."""
    graph, _ = _grid(0.0)
    odometry = np.flatnonzero(graph.odometry_mask())
    loops = np.flatnonzero(~graph.odometry_mask())[:2]
    keep = np.sort(np.concatenate([odometry, loops]))
    small = dataclasses.replace(graph, edge_from=graph.edge_from[keep], edge_to=graph.edge_to[keep],
                                measurements=graph.measurements[keep], information=graph.information[keep],
                                edge_source=None, edge_lines=None)
    verdict = _judged(small)
    assert not verdict.judged and not verdict.broken and len(verdict.edges) == 0
    assert verdict.as_dict(small)["agreement_gain"] != verdict.as_dict(small)["agreement_gain"]  # NaN: not judged


def test_the_refits_use_the_callers_solver_options_but_not_its_callbacks():
    """The run's progress printer and recorder see the run's iterations only, not the check's refits."""
    from posegraph.solve import SolverParams

    calls = []
    params = SolverParams(linear_solver="scipy", callback=lambda *a: calls.append("callback"),
                          estimate_callback=lambda *a: calls.append("estimate"))
    graph, _ = _grid(0.1)
    verdict = suspicious_edges(graph, optimize(graph).poses, params)
    assert calls == [] and verdict.broken


def test_no_refit_when_no_loop_closure_stands_out(monkeypatch):
    """A clean grid has no loop closure above SCREEN × the level: judged without a solve (gain 1); one
    wrong loop closure makes the check refit."""
    import posegraph.solve

    graph, _ = _grid(0.0)
    poses = optimize(graph).poses
    calls = []
    real = posegraph.solve.optimize
    monkeypatch.setattr(posegraph.solve, "optimize", lambda *a, **k: calls.append(1) or real(*a, **k))
    verdict = suspicious_edges(graph, poses)
    assert verdict.judged and not verdict.broken and verdict.gain == 1.0 and calls == []
    corrupted, _ = inject_outliers(graph, fraction=0.05, seed=1)
    suspicious_edges(corrupted, real(corrupted).poses)
    assert len(calls) > 0
