"""SO(3) and SE(3) as plain functions over batched numpy arrays: :mod:`so3`, :mod:`se3`."""
from posegraph.lie import se3, so3

__all__ = ["so3", "se3"]
