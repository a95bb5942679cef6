"""The Rerun recording's summary says what its numbers are, as the command's summary does (no Rerun needed)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from datasets.synthetic import NoiseParams, generate
from posegraph.analysis.report import chi2_summary
from posegraph.analysis.rerun_log import _summary_markdown


def _graph_and_result():
    graph = generate("grid", 27, noise=NoiseParams(loop_closure_density=0.5), seed=1).graph
    result = SimpleNamespace(initial_cost=10.0, final_cost=4.5, iterations=3, termination="converged")
    return graph, result


def test_plain_summary_labels_half_chi2():
    graph, result = _graph_and_result()
    chi2 = chi2_summary(graph)
    text = _summary_markdown(graph, result, np.ones(graph.num_edges), chi2, "t")
    assert "4.5 (½χ²)" in text and "| χ² / dof |" in text and "every measurement" not in text


def test_robust_summary_labels_the_robust_cost_and_gives_the_plain_one():
    graph, result = _graph_and_result()
    chi2 = dict(chi2_summary(graph), every=chi2_summary(graph))
    text = _summary_markdown(graph, result, np.ones(graph.num_edges), chi2, "t", robust=True)
    assert "(½χ²)" not in text and "what the robust solve minimised" in text
    assert f"| ½χ², every measurement | {chi2['every']['cost']:.10g}" in text
    assert "| χ² of the inliers / dof |" in text


def test_zero_dof_is_undefined_not_nan():
    graph, result = _graph_and_result()
    chi2 = dict(chi2_summary(graph), dof=0, chi2_per_dof=float("nan"))
    text = _summary_markdown(graph, result, np.ones(graph.num_edges), chi2, "t")
    assert "nan" not in text and "undefined (dof 0)" in text
