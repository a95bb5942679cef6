"""Checks the initialisers run before touching a graph's numbers.

The g2o reader already rejects malformed files; these checks guard graphs built in code, so that
a NaN or an out-of-range edge gives a :class:`~posegraph.errors.GraphError` naming the edge or
vertex rather than NaN poses or an IndexError deep inside a sparse solve.
"""

from __future__ import annotations

import numpy as np

from posegraph.errors import GraphError
from posegraph.model.graph import PoseGraph

__all__ = ["require_usable"]


def require_usable(graph: PoseGraph) -> None:
    """Raise :class:`GraphError` unless edges index existing vertices and all numbers are finite."""
    n = graph.num_vertices
    for name, index in (("edge_from", graph.edge_from), ("edge_to", graph.edge_to)):
        bad = np.flatnonzero((index < 0) | (index >= n))
        if bad.size:
            raise GraphError(
                f"edge {bad[0]} has {name} index {index[bad[0]]} outside 0..{n - 1}", path=graph.source
            )
    for name, array, what in (
        ("measurements", graph.measurements, "edge"),
        ("information", graph.information, "edge"),
        ("poses", graph.poses, "vertex"),
    ):
        finite = np.isfinite(array).all(axis=tuple(range(1, array.ndim)))
        if not finite.all():
            k = int(np.flatnonzero(~finite)[0])
            if what == "vertex":
                label = f"vertex {graph.ids[k]}"
            else:
                label = f"edge {k} ({graph.ids[graph.edge_from[k]]} -> {graph.ids[graph.edge_to[k]]})"
            raise GraphError(f"{label} has a non-finite value in its {name}", path=graph.source)
