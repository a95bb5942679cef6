"""What is learnt from a solved graph: marginal covariances (:mod:`posegraph.analysis.covariance`),
trajectory metrics against a reference (:mod:`posegraph.analysis.evaluate`: ATE, RPE), the JSON reports
(:mod:`posegraph.analysis.report`), the broken-map check
(:mod:`posegraph.analysis.suspicious`) and figures (:mod:`posegraph.analysis.plot`). Above the solver; the
command imports these."""


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.analysis.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
