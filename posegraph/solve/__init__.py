"""Sparse Gauss-Newton / Levenberg-Marquardt for pose graphs (SE(3) by default, any ``graph.group``).

::

    from posegraph.io.g2o import read_g2o
    from posegraph.solve import SolverParams, optimize

    graph = read_g2o("sphere2500.g2o")
    result = optimize(graph, initial="file", params=SolverParams(method="lm"))
    print(result.summary())

Modules: :mod:`~posegraph.solve.residuals` (residuals, cost, Jacobians),
:mod:`~posegraph.solve.linearize` (per-edge normal-equation blocks, optional per-edge weights),
:mod:`~posegraph.solve.objective` (the cost the loop minimises, with an optional robust loss),
:mod:`~posegraph.solve.sparsity` (block pattern and scatter),
:mod:`~posegraph.solve.linear` (CHOLMOD / SuperLU backends),
:mod:`~posegraph.solve.optimizer` (the trust-region loop),
:mod:`~posegraph.solve.trust_region` (damping, line search, stopping tests),
:mod:`~posegraph.solve.clock` (seconds per phase),
:mod:`~posegraph.solve.params` and :mod:`~posegraph.solve.result` (dataclasses).
"""

from posegraph.solve.optimizer import Analysis, analyze, optimize
from posegraph.solve.params import SolverParams
from posegraph.solve.result import IterationRecord, OptimizeResult

__all__ = ["SolverParams", "OptimizeResult", "IterationRecord", "Analysis", "analyze", "optimize"]


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
