"""Certified global optimality for SE-Sync's isotropic pose-graph problem (``docs/certify.md``).

:func:`posegraph.certify` (:mod:`posegraph.certification.certificate`) is the entry point; the
problem (κ, τ, F, M) is in :mod:`~posegraph.certification.problem`, the rank-d Newton refinement in
:mod:`~posegraph.certification.local`, Λ and S and the PSD test in :mod:`~posegraph.certification.verify`,
the Riemannian staircase and SE-Sync's rounding in :mod:`~posegraph.certification.staircase`. (The
package is not named ``certify``: ``posegraph.certify`` is the function.)
"""


def __getattr__(name: str):
    """A module of this package imported on first use (``posegraph.certification.<module>`` after ``import posegraph``
    alone; PEP 562)."""
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
