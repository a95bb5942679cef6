"""gtsam beside ours: the bridge that runs gtsam on our graphs (:mod:`posegraph.crosscheck.gtsam_bridge`)
and the cross-validation of the Lie-group core and the edge Jacobians against gtsam, finite differences
and identities (:mod:`posegraph.crosscheck.jacobians`, ``posegraph verify-jacobians``). gtsam is optional
and imported only inside functions."""


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.crosscheck.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
