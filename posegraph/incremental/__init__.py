"""Incremental optimisation: a pose graph that grows in batches, its estimate kept at the optimum (``docs/incremental.md``)."""

from posegraph.incremental.optimizer import IncrementalOptimizer, UpdateInfo

__all__ = ["IncrementalOptimizer", "UpdateInfo"]


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.incremental.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
