"""SO(2), SE(2), SO(3) and SE(3) as plain functions over batched numpy arrays: :mod:`so2`, :mod:`se2`, :mod:`so3`, :mod:`se3`."""
from posegraph.lie import se2, se3, so2, so3

__all__ = ["so2", "se2", "so3", "se3"]


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
