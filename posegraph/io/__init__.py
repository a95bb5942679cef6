"""Files in and out: the g2o reader and writer (:mod:`posegraph.io.g2o`), TUM/KITTI trajectories
(:mod:`posegraph.io.trajectory`), compressed and streamed input (:mod:`posegraph.io.text_input`),
all-or-nothing output files (:mod:`posegraph.io.atomic`) and the Open3D export
(:mod:`posegraph.io.export_open3d`). Above the data model; nothing here solves."""


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.io.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
