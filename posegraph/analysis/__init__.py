"""What is learnt from a solved graph: marginal covariances (:mod:`posegraph.analysis.covariance`),
trajectory metrics against a reference (:mod:`posegraph.analysis.evaluate`: ATE, RPE), the JSON reports
(:mod:`posegraph.analysis.report`), the broken-map check
(:mod:`posegraph.analysis.suspicious`) and figures (:mod:`posegraph.analysis.plot`). Above the solver; the
command imports these."""


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
