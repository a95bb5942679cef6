"""The sparse linear-algebra backends that both the initialisers and the solver use: CHOLMOD and the
fill-reducing orders (:mod:`posegraph.linalg.cholmod`), multigrid-preconditioned CG
(:mod:`posegraph.linalg.multigrid`), the BLAS threads under CHOLMOD (:mod:`posegraph.linalg.native_threads`)
and the process's memory, which decides whether a factor fits (:mod:`posegraph.linalg.heap`).
Nothing here knows about graphs: it imports no other floor of the package but the error types."""


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.linalg.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
