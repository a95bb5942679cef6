"""3D trajectory figures with matplotlib (``pip install "posegraph[plot]"``).

Matplotlib is imported inside the functions, and only its object-oriented API and the Agg
canvas are used (no ``pyplot``, no global backend switch), so the figures render on a machine
without a display and the library never changes the backend of the caller's own plots.

Each graph is drawn as its vertex positions joined in increasing id order (the trajectory), with
its loop-closure edges (``|id_i − id_j| ≠ 1``, see :meth:`PoseGraph.odometry_mask`) drawn as faint
segments of the same colour. Several graphs are overlaid with a legend — e.g. the input and the
optimised result.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from posegraph.atomic import atomic_path

__all__ = ["require_matplotlib", "trajectory_figure", "plot_trajectories"]

# Colour-blind-safe qualitative palette (Okabe & Ito 2008), cycled for more graphs.
_COLOURS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000")
LOOP_CLOSURE_ALPHA = 0.25
"""Opacity of loop-closure segments: visible where they bunch up, without hiding the trajectory."""


def require_matplotlib():
    """Import matplotlib, or raise ImportError saying how to install it."""
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            'plotting needs matplotlib: pip install "posegraph[plot]" (or pip install matplotlib)'
        ) from exc
    return matplotlib


def trajectory_figure(
    graphs: Sequence,
    labels: Sequence[str] | None = None,
    poses: Sequence[np.ndarray | None] | None = None,
    *,
    loop_closures: bool = True,
    title: str | None = None,
    size_inches: tuple[float, float] = (8.0, 6.5),
    dpi: int = 120,
):
    """A matplotlib ``Figure`` with one 3D axes showing every graph's trajectory.

    ``graphs``: :class:`~posegraph.graph.PoseGraph` objects; ``labels``: legend entries (default
    the graphs' ``source`` or ``graph k``); ``poses``: per graph an ``(n, 4, 4)`` array to draw
    instead of ``graph.poses`` (or None). Axes share one scale in x, y and z so that shapes are
    not distorted.
    """
    require_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    graphs = list(graphs)
    if labels is None:
        labels = [g.source or f"graph {k + 1}" for k, g in enumerate(graphs)]
    if poses is None:
        poses = [None] * len(graphs)
    if not (len(labels) == len(poses) == len(graphs)):
        raise ValueError("graphs, labels and poses must have the same length")

    fig = Figure(figsize=size_inches, dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    lows, highs = [], []
    for k, (graph, label, X) in enumerate(zip(graphs, labels, poses)):
        colour = _COLOURS[k % len(_COLOURS)]
        X = graph.poses if X is None else np.asarray(X)
        positions = X[:, :3, 3]
        order = np.argsort(graph.ids, kind="stable")
        path = positions[order]
        ax.plot(path[:, 0], path[:, 1], path[:, 2], color=colour, linewidth=1.0, label=label)
        if loop_closures:
            closing = ~graph.odometry_mask()
            if np.any(closing):
                segments = np.stack(
                    [positions[graph.edge_from[closing]], positions[graph.edge_to[closing]]], axis=1
                )
                ax.add_collection3d(
                    Line3DCollection(segments, colors=colour, linewidths=0.5, alpha=LOOP_CLOSURE_ALPHA)
                )
        if len(positions):
            lows.append(positions.min(axis=0))
            highs.append(positions.max(axis=0))
    if lows:
        low, high = np.min(lows, axis=0), np.max(highs, axis=0)
        centre, half = (low + high) / 2, max(float(np.max(high - low)) / 2, 1e-9)
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    if title:
        ax.set_title(title)
    if loop_closures:
        from matplotlib.lines import Line2D

        handles, names = ax.get_legend_handles_labels()
        handles.append(Line2D([], [], color="0.5", alpha=0.5, linewidth=0.8))
        names.append("loop closures (faint)")
        ax.legend(handles, names, loc="upper left", fontsize="small")
    else:
        ax.legend(loc="upper left", fontsize="small")
    fig.tight_layout()
    return fig


def plot_trajectories(
    path,
    graphs: Sequence,
    labels: Sequence[str] | None = None,
    poses: Sequence[np.ndarray | None] | None = None,
    **options,
) -> None:
    """Draw :func:`trajectory_figure` and save it to ``path`` atomically.

    The format follows the extension of ``path`` (``.png``, ``.pdf``, ``.svg``, …; matplotlib's
    list). ``options`` are passed to :func:`trajectory_figure`.
    """
    from pathlib import Path

    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    fig = trajectory_figure(graphs, labels, poses, **options)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt)
