"""Which vertices the initialisers hold at their file pose (the gauge).

A pose graph's cost is invariant under one rigid motion per connected
component, so each component needs one held vertex to pin it. The project's
rule (``docs/architecture.md``): ``FIX`` vertices are held; a component without
one is held at its anchor, the vertex with the smallest id
(:func:`posegraph.graph.component_anchors`). Held vertices keep their file pose
in every initialiser, exactly as the solver keeps them constant, and no prior
is added to any cost.
"""

from __future__ import annotations

import numpy as np

from posegraph.graph import PoseGraph, component_anchors

__all__ = ["held_vertices"]


def held_vertices(graph: PoseGraph) -> np.ndarray:
    """``(n,)`` bool: True for fixed vertices and for the anchors of components without one."""
    held = np.array(graph.fixed, dtype=bool, copy=True)
    if graph.num_vertices:  # component_anchors needs at least one vertex
        held[component_anchors(graph)] = True
    return held
