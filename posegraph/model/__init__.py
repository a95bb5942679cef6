"""The data model: the pose graph (:mod:`posegraph.model.graph`) and its priors, unary edges
(:mod:`posegraph.model.priors`). Above the Lie groups; below everything that reads, writes or solves a graph."""


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.model.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
