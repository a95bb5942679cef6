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


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
