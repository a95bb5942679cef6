"""Certified global optimality for SE-Sync's isotropic pose-graph problem (``docs/certify.md``).

:func:`posegraph.certify` (:mod:`posegraph.certification.certificate`) is the entry point; the
problem (κ, τ, F, M) is in :mod:`~posegraph.certification.problem`, the rank-d Newton refinement in
:mod:`~posegraph.certification.local`, Λ and S and the PSD test in :mod:`~posegraph.certification.verify`,
the Riemannian staircase and SE-Sync's rounding in :mod:`~posegraph.certification.staircase`. (The
package is not named ``certify``: ``posegraph.certify`` is the function.)
"""


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
