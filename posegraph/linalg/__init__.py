"""The sparse linear-algebra backends that both the initialisers and the solver use: CHOLMOD and the
fill-reducing orders (:mod:`posegraph.linalg.cholmod`), multigrid-preconditioned CG
(:mod:`posegraph.linalg.multigrid`), the BLAS threads under CHOLMOD (:mod:`posegraph.linalg.native_threads`)
and the process's memory, which decides whether a factor fits (:mod:`posegraph.linalg.heap`).
Nothing here knows about graphs: it imports no other floor of the package but the error types."""


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
