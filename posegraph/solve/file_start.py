"""A landmark graph's start: its own values when they already fit its measurements, else the chordal start.

A landmark graph's chordal start is a relaxation over its poses and points
(:mod:`posegraph.init.relaxation`): three or more factorisations of a system larger than the solver's,
as long as LM's iterations on the small files. Many files carry values a front end already refined (g2o's
simulated worlds: their values are within 0.001 % of the optimum's cost on
``world-2000-lownoise-default``); LM from them takes as few iterations as from the relaxation, or fewer,
to the same optimum. Others carry dead reckoning (Victoria Park, DLR), 10⁴ times the optimum's cost.

The test is the solver's own cost (:class:`~posegraph.solve.objective.Objective`) of the file's poses and
landmark positions per residual row,

    ½ Σ eᵀΩe ≤ FIT_COST_PER_ROW · (rows of every pose edge and landmark measurement),

i.e. the whitened residuals average at most √2 per row: values that explain the measurements to
within about their stated noise. Graphs with priors, pose graphs, and starts other than ``"chordal"``
are started as :func:`posegraph.init.initialize` starts them.
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.model.landmarks import measurement_size
from posegraph.solve.objective import Objective

__all__ = ["FIT_COST_PER_ROW", "file_values_fit", "file_cost", "start_poses"]

FIT_COST_PER_ROW = 1.0
"""Largest cost per residual row at which the file's values are the start (module docstring).
Measured (``docs/landmarks.md``): the g2o worlds' files 0.50–0.83 (they start there), DLR 4,800,
Victoria Park 1,500, world-1000-dense-highnoise 9.1 (they start from the relaxation, though that file's values are
the optimum's to 5e-9 relative: its information matrices understate its noise)."""


def file_cost(graph: PoseGraph) -> tuple[float, int]:
    """``(½ Σ eᵀΩe, rows)``: the solver's cost at the file's poses and landmark positions, and the residual
    rows of every pose edge and landmark measurement (no priors: :func:`start_poses` does not test graphs with them)."""
    points = None if graph.landmarks is None else graph.landmarks.positions
    with np.errstate(all="ignore"):
        total = Objective(graph).evaluate(np.asarray(graph.poses, dtype=np.float64), points).cost
    rows = graph.num_edges * graph.group.dim
    for family in graph.landmarks.observations if graph.landmarks is not None else ():
        rows += family.count * measurement_size(family.kind, graph.group.space_dim)
    return total, rows


def file_values_fit(graph: PoseGraph) -> bool:
    """Whether the file's values are a landmark graph's start: finite and at most :data:`FIT_COST_PER_ROW`
    of cost per residual row (module docstring)."""
    total, rows = file_cost(graph)
    return bool(np.isfinite(total)) and rows > 0 and total <= FIT_COST_PER_ROW * rows


def start_poses(graph: PoseGraph, method: str = "chordal", **options) -> np.ndarray:
    """The start ``(n, k, k)`` by ``method`` (:func:`posegraph.init.initialize`'s), except that a landmark
    graph without priors whose file values fit (:func:`file_values_fit`) starts there for ``"chordal"``."""
    from posegraph.init import initialize

    if method == "chordal" and graph.landmarks is not None and graph.priors is None and file_values_fit(graph):
        return np.array(graph.poses, dtype=np.float64, copy=True)  # values a front end refined: as good a start
    return initialize(graph, method, **options)
