"""Incremental optimisation: a pose graph that grows in batches, its estimate kept at the optimum (``docs/incremental.md``)."""

from posegraph.incremental.optimizer import IncrementalOptimizer, UpdateInfo

__all__ = ["IncrementalOptimizer", "UpdateInfo"]
