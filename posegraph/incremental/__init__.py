"""Incremental optimisation: a pose graph that grows in batches, its estimate kept at the optimum (``docs/incremental.md``)."""

from posegraph.incremental.optimizer import IncrementalOptimizer, UpdateInfo

__all__ = ["IncrementalOptimizer", "UpdateInfo"]


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
