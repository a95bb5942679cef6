"""The whole graph's last evaluation and linearisation, extended to new edges instead of recomputed.

Gauss-Newton on the whole graph stops after linearising at its final point (the stopping test needs
the gradient there). Until the next update that solves, the front end only adds vertices placed by
composition and their edges: the poses already in do not move, so every old edge's residual, Jacobian
factors and gradient blocks at the next start are those of that final point. :class:`LastPoint` keeps
them and, at the next solve, computes only the new edges' (the solver's own
:class:`~posegraph.solve.objective.Objective` on those edges) and joins the two: one whole-graph
evaluation and one linearisation fewer per update. It is used only when it is exact: the first ``n``
poses equal bit for bit the ones it was made at, the edges are the same ones with new ones appended
(a removal resets it), and the graph has no priors (their terms are not split by edge here).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.solve.linearize import EdgeBlocks
from posegraph.solve.objective import Evaluation, Objective

__all__ = ["LastPoint"]


class LastPoint:
    """The evaluation and linearisation of the whole graph at its last solved point (module docstring)."""

    def __init__(self):
        self.clear()

    def clear(self) -> None:
        self.poses = self.evaluation = self.blocks = None

    def keep(self, poses: np.ndarray, evaluation: Evaluation, blocks: EdgeBlocks | None) -> None:
        """Remember ``evaluation`` and ``blocks`` (None: a solve that stopped without linearising), both
        made at ``poses`` ``(n, k, k)`` (copied)."""
        self.poses, self.evaluation, self.blocks = poses.copy(), evaluation, blocks

    def extended(self, objective: Objective, poses: np.ndarray) -> tuple[Evaluation, EdgeBlocks | None] | None:
        """``(evaluation, blocks)`` of ``objective`` at ``poses``, from the kept ones and the new edges
        alone (``blocks`` None when none were kept); None when the kept ones do not apply (nothing kept,
        priors, a kept pose moved)."""
        graph, kept = objective.graph, self.poses
        if kept is None or graph.priors is not None or graph.landmarks is not None or poses.shape[0] < kept.shape[0]:
            return None
        if not np.array_equal(poses[: kept.shape[0]], kept):
            return None
        old = self.evaluation.residuals.shape[0]
        part = slice(old, graph.num_edges)
        new_graph = replace(graph, edge_from=graph.edge_from[part], edge_to=graph.edge_to[part],
                            measurements=graph.measurements[part], information=graph.information[part])
        new = Objective(new_graph, objective.loss)
        evaluation = new.evaluate(poses)
        if self.blocks is None:
            return _joined_evaluation(self.evaluation, evaluation), None
        return _joined_evaluation(self.evaluation, evaluation), _joined_blocks(self.blocks, new.linearize(poses, evaluation),
                                                                               objective.information)


def _join(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    return None if a is None else np.concatenate([a, b])


def _joined_evaluation(old: Evaluation, new: Evaluation) -> Evaluation:
    """The evaluation of the old edges then the new ones (no priors, no landmarks): per-edge arrays
    joined, costs summed."""
    return Evaluation(relative=np.concatenate([old.relative, new.relative]),
                      residuals=np.concatenate([old.residuals, new.residuals]),
                      cost=old.cost + new.cost, weights=_join(old.weights, new.weights))


def _joined_blocks(old: EdgeBlocks, new: EdgeBlocks, information: np.ndarray) -> EdgeBlocks:
    """The linearisation of the old edges then the new ones; ``information`` ``(m, d, d)`` all edges'."""
    return EdgeBlocks(residuals=np.concatenate([old.residuals, new.residuals]), cost=old.cost + new.cost,
                      gradient=np.concatenate([old.gradient, new.gradient]),
                      jacobian_inverse=np.concatenate([old.jacobian_inverse, new.jacobian_inverse]),
                      adjoint=np.concatenate([old.adjoint, new.adjoint]), information=information,
                      weights=_join(old.weights, new.weights))
