"""Edges the rest of a least-squares solution disagrees with: the evidence of a broken map.

A wrong loop closure bends a least-squares answer: the edges around it stretch to meet it, so at
the optimum its error is spread over many edges and no fixed χ²/dof tells a broken map from one
whose information matrices are merely over- or underconfident (χ² scales with Ω). The edges are
judged against each other instead, in a scale-free test:

1. the *level* of the graph is the median χ²_e = e_eᵀΩ_e e_e of its loop closures at the given
   (least-squares) poses;
2. from those poses, :data:`ROUNDS` short refits minimise ½ Σ ρ(χ²_e) with Cauchy's loss
   ρ(s) = c² log(1 + s/c²), c² = :data:`LEVEL_MULTIPLE` × the current level: an edge far above the
   bulk is down-weighted, the bulk keeps about its least-squares weight;
3. the *agreement gain* is Σ χ²_e over the edges whose refit χ² is at most :data:`STANDOUT` × the
   refit level, at the least-squares poses, divided by the same sum at the refit poses: how much
   better the bulk of the graph agrees once the edges far above it stop pulling;
4. the *suspicious* edges are the loop closures above :data:`STANDOUT` × the refit level whose refit
   χ² is above their least-squares one (an edge merely stretched by a wrong one relaxes once the
   wrong one stops pulling; the wrong one is left further off). Odometry edges are not named: the
   loss down-weights them too, and those next to a wrong loop closure stay stretched.

The map is judged *broken* when the gain is at least :data:`BROKEN_GAIN`. When no loop closure is
above :data:`SCREEN` × the level at the given poses, nothing pulls the bulk: the refits are skipped
and the gain is 1 (most clean files: one χ² pass instead of three short solves). Every step is invariant
under Ω → kΩ (the levels scale, the loss scales with them), so information matrices that overstate
or understate the noise by any common factor give the same verdict.

Measured (``python -m benchmarks.bench_suspicious``, ``docs/robust.md``): the gain is at most 1.2 on
every clean graph tried (the shared benchmark files, the bundled example, the generator's shapes, ×0.01
and ×100 information), 1.8 on cubicle (its information matrices repaired), and 2.7 to 1,200 on graphs
with 5–20 % random wrong loop closures (intel, manhattan, sphere2500, smallGrid3D, the generator's grid,
manhattan, torus, garage, sphere at 5 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from posegraph.robust.losses import Cauchy

__all__ = ["SuspiciousEdges", "suspicious_edges", "BROKEN_GAIN", "STANDOUT", "SCREEN", "LEVEL_MULTIPLE", "ROUNDS",
           "MIN_LOOP_CLOSURES"]

LEVEL_MULTIPLE = 9.0
"""Cauchy's c² in units of the loop closures' median χ²: an edge at the median keeps weight 0.9, one at
100× it 0.08."""
ROUNDS = 3
"""Refits, each from the last one's poses with c² from its level."""
ITERATIONS_PER_ROUND = 10
"""The iteration cap of each refit (its solves start near their answer)."""
REFIT_TOLERANCE = 1e-4
"""Each refit stops when an iteration lowers its cost by at most this fraction: the verdict needs the
levels to a per cent, not the refit's optimum to the solver's 1e-7."""
STANDOUT = 30.0
"""An edge whose refit χ² is above this many times the refit level (and grew in the refit) is named suspicious."""
BROKEN_GAIN = 2.5
"""The agreement gain at and above which the map is judged broken: clean graphs gave at most 1.8."""
SCREEN = STANDOUT / 2
"""No loop closure above this many times the level at the poses judged: no refit, gain 1. Half of
:data:`STANDOUT` because wrong loop closures raise the level they are measured against: the broken
maps this check finds had a loop closure at 20–2,800× the level before the refits (sphere2500 with 5 %
wrong closures within 3 m: 24.6×), the clean files with well-modelled noise at most 8.6×."""
MIN_LOOP_CLOSURES = 5
"""Fewer loop closures than this: no level to judge against, no verdict."""


@dataclass(frozen=True, eq=False)
class SuspiciousEdges:
    """The verdict of :func:`suspicious_edges`.

    ``edges`` ``(k,)`` 0-based edge indices (the g2o file's edge-line order), the largest refit χ²
    relative to the refit level first; ``chi2`` ``(k,)`` their χ²_e at the poses judged; ``refit_chi2``
    ``(k,)`` theirs after the refit; ``level`` and ``refit_level`` the loop closures' median χ² at the
    poses judged and after the refit; ``gain`` the agreement gain (NaN when not judged); ``broken``
    whether ``gain ≥ BROKEN_GAIN``; ``screened`` (below); ``judged`` False when the graph has fewer than
    :data:`MIN_LOOP_CLOSURES` loop closures or landmarks (no verdict, nothing named).
    """

    edges: np.ndarray
    chi2: np.ndarray
    refit_chi2: np.ndarray
    level: float
    refit_level: float
    gain: float
    broken: bool
    judged: bool
    screened: bool = False
    """No loop closure above :data:`SCREEN` × the level: the edges agree with each other at any χ²/dof
    (no refit was run): a high χ²/dof is then a matter of the information matrices' scale, not of wrong edges."""

    def rows(self, graph, limit: int | None = None) -> list[dict]:
        """The first ``limit`` (all: None) suspicious edges as ``{"edge", "line", "from_id", "to_id", "chi2"}``
        (:func:`posegraph.analysis.report.edge_rows`)."""
        from posegraph.analysis.report import edge_rows

        return edge_rows(graph, self.edges[:limit], self.chi2[:limit])

    def as_dict(self, graph, limit: int | None = None) -> dict:
        """A JSON dict: ``judged, broken, agreement_gain, level, refit_level, count, edges`` (:meth:`rows`)."""
        return {"judged": self.judged, "broken": self.broken, "agreement_gain": float(self.gain),
                "level": float(self.level), "refit_level": float(self.refit_level), "count": int(len(self.edges)),
                "edges": self.rows(graph, limit)}


def suspicious_edges(graph, poses, params=None) -> SuspiciousEdges:
    """Judge the edges of ``graph`` at ``poses`` ``(n, k, k)`` (a least-squares optimum) against each other.

    The test is the module's (:mod:`posegraph.analysis.suspicious`); it costs :data:`ROUNDS` short
    robust solves (:func:`posegraph.solve.optimize`, with ``params``' linear solver and method; held
    vertices as ``graph`` holds them). Returns a :class:`SuspiciousEdges`; ``broken`` is the verdict.
    """
    from posegraph.analysis.report import edge_chi2

    loops = ~graph.odometry_mask()
    if np.count_nonzero(loops) < MIN_LOOP_CLOSURES or graph.landmarks is not None:
        empty = np.zeros(0)
        return SuspiciousEdges(empty.astype(np.int64), empty, empty, float("nan"), float("nan"), float("nan"),
                               False, False)
    chi2 = edge_chi2(graph, poses)
    level = float(np.median(chi2[loops]))
    if not np.any(_relative(chi2[loops], level) > SCREEN):
        # no loop closure stands out even before the refits: a graph agreeing with itself, judged at the
        # price of one χ² pass (sphere2500, torus3D: the refits cost as much as the solve again)
        empty = np.zeros(0)
        return SuspiciousEdges(empty.astype(np.int64), empty, empty, level, level, 1.0, False, True, True)
    refit = _refit_chi2(graph, poses, chi2, loops, params)
    refit_level = float(np.median(refit[loops]))
    ratio = _relative(refit, refit_level)
    rest = ratio <= STANDOUT
    standout = loops & ~rest & (refit > chi2)  # a stretched edge relaxes; a wrong one is left further off
    after = float(refit[rest].sum())
    gain = float(chi2[rest].sum()) / after if after > 0 else (1.0 if chi2[rest].sum() == 0 else float("inf"))
    order = np.flatnonzero(standout)[np.argsort(-ratio[standout], kind="stable")]
    return SuspiciousEdges(order, chi2[order], refit[order], level, refit_level, gain, bool(gain >= BROKEN_GAIN), True)


def _relative(chi2: np.ndarray, level: float) -> np.ndarray:
    """``chi2`` over ``level`` (∞ for a positive χ² over a zero level)."""
    return chi2 / level if level > 0 else np.where(chi2 > 0, np.inf, 0.0)


def _refit_chi2(graph, poses, chi2, loops, params) -> np.ndarray:
    """``(m,)`` χ²_e after :data:`ROUNDS` Cauchy refits from ``poses``, each scaled to the last level."""
    from dataclasses import replace

    from posegraph.analysis.report import edge_chi2
    from posegraph.solve import SolverParams, analyze, optimize

    # the refits are the check's own business: no progress lines, no recorded estimates
    base = SolverParams() if params is None else replace(params, callback=None, estimate_callback=None)
    analysis = analyze(graph, base)  # the symbolic work, once for every round
    for _ in range(ROUNDS):
        level = float(np.median(chi2[loops]))
        if not level > 0:  # the loop closures agree exactly: nothing to down-weight against
            break
        round_params = replace(base, loss=Cauchy(math.sqrt(LEVEL_MULTIPLE * level)), max_iterations=ITERATIONS_PER_ROUND,
                               relative_tolerance=REFIT_TOLERANCE)
        poses = optimize(graph, initial=poses, params=round_params, analysis=analysis).poses
        chi2 = edge_chi2(graph, poses)
    return chi2
