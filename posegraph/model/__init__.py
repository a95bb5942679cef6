"""The data model: the pose graph (:mod:`posegraph.model.graph`) and its priors, unary edges
(:mod:`posegraph.model.priors`). Above the Lie groups; below everything that reads, writes or solves a graph."""


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
