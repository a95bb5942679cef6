"""posegraph: SE(3) pose-graph optimisation over g2o files.

Three lines from a file to an optimised file::

    import posegraph
    graph = posegraph.read_g2o("in.g2o")
    result = posegraph.optimize(graph)            # chordal start, then Levenberg-Marquardt
    posegraph.write_g2o("out.g2o", graph, result.poses)

Robust to wrong loop closures: ``posegraph.optimize(graph, params=posegraph.SolverParams(loss=
posegraph.make_loss("cauchy")))`` (an M-estimator, Ceres' ``loss_function``), or
``posegraph.optimize_robust(graph)`` (graduated non-convexity, gtsam's ``GncLMOptimizer``).

The Lie-group core is in :mod:`posegraph.lie` (``so2``, ``se2``, ``so3``, ``se3``; ``group``). Names below are imported on first
use, so ``import posegraph`` stays cheap (no scipy, gtsam, Open3D or matplotlib at start-up).
"""

from __future__ import annotations

import importlib
import importlib.util

__version__ = "0.1.0"

# public name -> module that defines it
_LAZY = {
    "PoseGraph": "posegraph.model.graph",
    "Priors": "posegraph.model.priors",
    "graph_facts": "posegraph.model.graph",
    "connected_components": "posegraph.model.graph",
    "component_anchors": "posegraph.model.graph",
    "read_g2o": "posegraph.io.g2o",
    "write_g2o": "posegraph.io.g2o",
    "cost": "posegraph.solve.residuals",
    "edge_residuals": "posegraph.solve.residuals",
    "optimize": "posegraph.solve",
    "SolverParams": "posegraph.solve",
    "OptimizeResult": "posegraph.solve",
    "initialize": "posegraph.init",
    "optimize_robust": "posegraph.robust.pipeline",
    "RobustResult": "posegraph.robust.pipeline",
    "GncParams": "posegraph.robust.gnc",
    "make_loss": "posegraph.robust.losses",
    "InputError": "posegraph.errors",
    "marginal_covariances": "posegraph.analysis.covariance",
    "joint_covariance": "posegraph.analysis.covariance",
    "landmark_covariances": "posegraph.analysis.covariance",
    "suspicious_edges": "posegraph.analysis.suspicious",
    "optimize_many": "posegraph.batch.many",
    "certify": "posegraph.certification.certificate",
    "Certificate": "posegraph.certification.certificate",
}

__all__ = sorted(_LAZY) + ["lie"]


def __getattr__(name: str):
    """A public name of ``_LAZY``, or a subpackage or module (``posegraph.incremental``, ``posegraph.io``)
    imported on first use, as ``import posegraph`` alone leaves them (PEP 562)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    return _submodule(__name__, name)


def _submodule(package: str, name: str):
    """The module ``package.name`` imported, or AttributeError when there is none: the PEP 562
    ``__getattr__`` of the face and of every subpackage (:func:`submodule_getattr`)."""
    if not name.startswith("_") and importlib.util.find_spec(f"{package}.{name}") is not None:
        return importlib.import_module(f"{package}.{name}")
    raise AttributeError(f"module {package!r} has no attribute {name!r}")


def submodule_getattr(package: str):
    """A module ``__getattr__`` for the subpackage ``package`` that imports its modules on first use, so
    that ``posegraph.model.landmarks`` works after ``import posegraph`` alone (PEP 562)."""
    return lambda name: _submodule(package, name)


def __dir__():
    return __all__
