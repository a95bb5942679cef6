"""SO(2), SE(2), SO(3) and SE(3) as plain functions over batched numpy arrays: :mod:`so2`, :mod:`se2`, :mod:`so3`, :mod:`se3`."""
from posegraph.lie import se2, se3, so2, so3

__all__ = ["so2", "se2", "so3", "se3"]


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.lie.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
