"""gtsam beside ours: the bridge that runs gtsam on our graphs (:mod:`posegraph.crosscheck.gtsam_bridge`)
and the cross-validation of the Lie-group core and the edge Jacobians against gtsam, finite differences
and identities (:mod:`posegraph.crosscheck.jacobians`, ``posegraph verify-jacobians``). gtsam is optional
and imported only inside functions."""


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
