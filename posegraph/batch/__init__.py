"""Many pose graphs at once: ``posegraph batch`` and :func:`posegraph.optimize_many` on Dask.

Modules: :mod:`~posegraph.batch.many` (:func:`optimize_many`), :mod:`~posegraph.batch.options`
(``optimize``'s per-file options as keywords and back to a command line),
:mod:`~posegraph.batch.files` (output names in OUT_DIR, and whether a run is complete),
:mod:`~posegraph.batch.task` (one file on a worker: ``posegraph optimize`` in-process),
:mod:`~posegraph.batch.rows` (the summary's rows, JSON and CSV), :mod:`~posegraph.batch.cluster`
(the Dask client: given, ``--scheduler``, or a local cluster). ``dask.distributed`` is imported
only when files are run.
"""

from posegraph.batch.many import optimize_many
from posegraph.batch.options import BatchError

__all__ = ["optimize_many", "BatchError"]


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.batch.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
