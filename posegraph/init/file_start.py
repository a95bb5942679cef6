"""Whether a landmark graph's own values already fit its measurements, so that they are its start.

A landmark graph's chordal start is a relaxation over its poses and points
(:mod:`posegraph.init.relaxation`): three factorisations of a system larger than the solver's, as long
as LM's iterations on the small files. Many files carry values a front end already refined (g2o's
simulated worlds: their values are within 0.001 % of the optimum's cost on
``world-2000-lownoise-default``); LM from them takes as few iterations as from the relaxation, or fewer,
to the same optimum. Others carry dead reckoning (Victoria Park, DLR), 10⁴ times the optimum's cost.

The test is the cost of the file's poses and landmark positions per residual row,

    ½ Σ eᵀΩe ≤ FIT_COST_PER_ROW · (rows of every pose edge and landmark measurement),

i.e. the whitened residuals average at most √2 per row: values that explain the measurements to
within about their stated noise. The cost is the solver's (``Log``-based edge residuals; landmark
residuals predicted − measured, :mod:`posegraph.solve.landmark_residuals`), computed here from the lie
and model floors (checked equal in ``tests/init/test_file_start.py``).
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.model.landmarks import measurement_size

__all__ = ["FIT_COST_PER_ROW", "file_values_fit", "file_cost"]

FIT_COST_PER_ROW = 1.0
"""Largest cost per residual row at which the file's values are the start (module docstring).
Measured (``docs/landmarks.md``): the g2o worlds' files 0.50–0.83 (they start there), DLR 4,800,
Victoria Park 1,500, world-1000-dense-highnoise 9.1 (they start from the relaxation, though that file's values are
the optimum's to 5e-9 relative: its information matrices understate its noise)."""


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``[−π, π)``."""
    return np.mod(angle + np.pi, 2.0 * np.pi) - np.pi


def _family_residuals(graph: PoseGraph, family) -> np.ndarray:
    """``(q, r)`` residuals, predicted − measured, of one landmark family at the file's values."""
    z = np.asarray(family.measurements, dtype=np.float64)
    points = np.asarray(graph.landmarks.positions, dtype=np.float64)[family.landmark]
    if family.kind == "prior":
        return points - z
    sensor = np.asarray(graph.poses, dtype=np.float64)[family.pose]  # S = X_i O
    if family.offsets is not None:
        sensor = sensor @ np.asarray(family.offsets, dtype=np.float64)
    s = sensor.shape[-1] - 1
    y = np.einsum("qji,qj->qi", sensor[:, :s, :s], points - sensor[:, :s, s])  # R_sᵀ(p − t_s), the sensor frame's point
    if family.kind == "position":
        return y - z
    bearing = _wrap(np.arctan2(y[:, 1], y[:, 0]) - z[:, 0])[:, None]
    if family.kind == "bearing":
        return bearing
    return np.concatenate([bearing, np.hypot(y[:, 0], y[:, 1])[:, None] - z[:, 1:2]], axis=1)


def file_cost(graph: PoseGraph) -> tuple[float, int]:
    """``(½ Σ eᵀΩe, rows)`` at the file's poses and landmark positions over every pose edge and landmark
    measurement of ``graph`` (the priors on poses are not in it)."""
    group, poses = graph.group, np.asarray(graph.poses, dtype=np.float64)
    relative = group.between(poses[graph.edge_from], poses[graph.edge_to])
    e = group.edge_log(group.between(graph.measurements, relative))
    total = 0.5 * float(np.einsum("mi,mij,mj->", e, np.asarray(graph.information, dtype=np.float64), e))
    rows = e.size
    for family in graph.landmarks.observations if graph.landmarks is not None else ():
        e = _family_residuals(graph, family)
        total += 0.5 * float(np.einsum("qi,qij,qj->", e, np.asarray(family.information, dtype=np.float64), e))
        rows += family.count * measurement_size(family.kind, group.space_dim)
    return total, rows


def file_values_fit(graph: PoseGraph) -> bool:
    """Whether the file's values are a landmark graph's start: finite and at most :data:`FIT_COST_PER_ROW`
    of cost per residual row (module docstring)."""
    with np.errstate(all="ignore"):
        total, rows = file_cost(graph)
    return bool(np.isfinite(total)) and rows > 0 and total <= FIT_COST_PER_ROW * rows
