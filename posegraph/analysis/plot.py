"""Trajectory figures with matplotlib (``pip install "posegraph[plot]"``).

Matplotlib is imported inside the functions, and only its object-oriented API and the Agg
canvas are used (no ``pyplot``, no global backend switch), so the figures render on a machine
without a display and the library never changes the backend of the caller's own plots.

Each graph is drawn as its vertex positions joined in increasing id order (the trajectory), with
its loop-closure edges (``|id_i − id_j| ≠ 1``, see :meth:`PoseGraph.odometry_mask`) drawn as faint
segments of the same colour, and where its priors put its vertices (:func:`prior_positions`) as
crosses. Several graphs are overlaid with a legend — e.g. the input and the
optimised result.

3D graphs (poses ``(n, 4, 4)``) are drawn on 3D axes; 2D graphs (``(n, 3, 3)``, SE(2)) as a top
view of the x–y plane with equal scales. When 2D and 3D graphs are overlaid, the 2D ones are
drawn at ``z = 0`` on the 3D axes (:func:`posegraph.lie.se2.to_se3`). ``top_view`` draws 3D
graphs from above (x–y); uncertainty ellipses (:func:`draw_uncertainty_ellipses`, from
:func:`posegraph.analysis.covariance.marginal_covariances`) are drawn on such a top view.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from posegraph.io.atomic import atomic_path
from posegraph.lie.group import embed_in_se3

__all__ = ["require_matplotlib", "trajectory_figure", "plot_trajectories", "planar_translation_covariances", "position_covariances",
           "draw_uncertainty_ellipses", "prior_positions"]

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
    top_view: bool = False,
    uncertainty: dict | None = None,
):
    """A matplotlib ``Figure`` with one axes showing every graph's trajectory.

    ``graphs``: :class:`~posegraph.model.graph.PoseGraph` objects; ``labels``: legend entries (default
    the graphs' ``source`` or ``graph k``); ``poses``: per graph an ``(n, 4, 4)`` or ``(n, 3, 3)``
    array to draw instead of ``graph.poses`` (or None). 3D axes when any graph is 3D, a top view
    when all are 2D (module docstring), or with ``top_view`` (3D graphs projected on x–y). Axes
    share one scale in every direction so that shapes are not distorted. ``uncertainty``: keyword
    arguments of :func:`draw_uncertainty_ellipses` (``covariances`` and optionally ``every``,
    ``scale``) for the first graph, drawn on a top view.
    """
    require_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    graphs = list(graphs)
    if labels is None:
        labels = [g.source or f"graph {k + 1}" for k, g in enumerate(graphs)]
    if poses is None:
        poses = [None] * len(graphs)
    if not (len(labels) == len(poses) == len(graphs)):
        raise ValueError("graphs, labels and poses must have the same length")
    poses = [graph.poses if X is None else np.asarray(X, dtype=np.float64) for graph, X in zip(graphs, poses)]
    planar = top_view or uncertainty is not None or all(X.shape[-1] == 3 for X in poses)
    if not planar:
        poses = [embed_in_se3(X) for X in poses]

    fig = Figure(figsize=size_inches, dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot() if planar else fig.add_subplot(projection="3d")
    lows, highs = [], []
    for k, (graph, label, X) in enumerate(zip(graphs, labels, poses)):
        positions = X[:, :2, -1] if planar else X[:, :-1, -1]
        _draw_graph(ax, graph, positions, _COLOURS[k % len(_COLOURS)], label, loop_closures)
        if len(positions):
            lows.append(positions.min(axis=0))
            highs.append(positions.max(axis=0))
    _equal_scales(ax, lows, highs)
    _legend(ax, poses[0] if uncertainty is not None and graphs else None, uncertainty, loop_closures)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig


def _legend(ax, poses, uncertainty: dict | None, loop_closures: bool) -> None:
    """The legend: the drawn lines, then (given ``poses``) the uncertainty ellipses drawn here for
    them and the faint loop closures' entry."""
    handles, names = ax.get_legend_handles_labels()
    if poses is not None:
        from matplotlib.patches import Ellipse

        scale = draw_uncertainty_ellipses(ax, poses, **uncertainty)
        handles.append(Ellipse((0, 0), 1, 0.6, facecolor="none", edgecolor=ELLIPSE_COLOUR))
        names.append(f"1σ position ellipses ×{scale:.3g}")
    if loop_closures:
        from matplotlib.lines import Line2D

        handles.append(Line2D([], [], color="0.5", alpha=0.5, linewidth=0.8))
        names.append("loop closures (faint)")
    ax.legend(handles, names, loc="upper left", fontsize="small")


def _draw_graph(ax, graph, positions: np.ndarray, colour: str, label: str, loop_closures: bool) -> None:
    """The id-ordered path of ``positions (n, d)`` and, optionally, faint loop-closure segments."""
    path = positions[np.argsort(graph.ids, kind="stable")]
    ax.plot(*path.T, color=colour, linewidth=1.0, label=label)
    _draw_prior_positions(ax, graph, positions.shape[1], colour, label)
    _draw_landmarks(ax, graph, positions.shape[1], colour, label)
    closing = ~graph.odometry_mask() if loop_closures else np.zeros(graph.num_edges, dtype=bool)
    if not np.any(closing):
        return
    segments = np.stack([positions[graph.edge_from[closing]], positions[graph.edge_to[closing]]], axis=1)
    style = dict(colors=colour, linewidths=0.5, alpha=LOOP_CLOSURE_ALPHA)
    if positions.shape[1] == 2:
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(segments, **style))
    else:
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        ax.add_collection3d(Line3DCollection(segments, **style))


def prior_positions(graph) -> np.ndarray:
    """``(a + b, r)``: where the priors put their vertices — ``t(Z O⁻¹)`` of each pose prior (the vertex
    pose it measures), ``z`` of each position prior (:func:`posegraph.model.priors.prior_poses`); empty without priors."""
    from posegraph.model.priors import prior_poses

    r = graph.group.space_dim
    return prior_poses(graph)[1][:, :r, r]


def _draw_prior_positions(ax, graph, dimension: int, colour: str, label: str) -> None:
    """The priors' positions (:func:`prior_positions`) as crosses, in ``dimension`` 2 (top view) or 3."""
    points = prior_positions(graph)
    if not len(points):
        return
    points = np.pad(points, ((0, 0), (0, max(dimension - points.shape[1], 0))))[:, :dimension]
    ax.scatter(*points.T, marker="x", s=18, color=colour, linewidths=0.8, label=f"{label}: priors")


def _draw_landmarks(ax, graph, dimension: int, colour: str, label: str) -> None:
    """The graph's landmarks at their positions as dots, in ``dimension`` 2 (top view: x, y) or 3."""
    if graph.landmarks is None or not graph.landmarks.count:
        return
    points = np.pad(graph.landmarks.positions, ((0, 0), (0, max(dimension - graph.landmarks.space_dim, 0))))[:, :dimension]
    ax.scatter(*points.T, marker="o", s=6, color=colour, alpha=0.8, linewidths=0, label=f"{label}: landmarks")


def _equal_scales(ax, lows: list, highs: list) -> None:
    """One scale on every axis, centred on the data; axis labels x, y (and z on 3D axes)."""
    d = 3 if hasattr(ax, "set_zlim") else 2
    setters = (ax.set_xlim, ax.set_ylim, getattr(ax, "set_zlim", None))[:d]
    if lows:
        low, high = np.min(lows, axis=0), np.max(highs, axis=0)
        centre, half = (low + high) / 2, max(float(np.max(high - low)) / 2, 1e-9)
        for set_limits, c in zip(setters, centre):
            set_limits(c - half, c + half)
        if d == 3:
            ax.set_box_aspect((1, 1, 1))
        else:
            # The limits above already span a square, so the box (not the data limits) adapts:
            # adjustable="datalim" would override those limits with a warning.
            ax.set_aspect("equal", adjustable="box")
    for name, set_label in zip("xyz", (ax.set_xlabel, ax.set_ylabel, getattr(ax, "set_zlabel", None))[:d]):
        set_label(name)


def planar_translation_covariances(poses: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """``(n, 2, 2)`` world-frame covariance of each pose's x–y position (the top view): the x–y block of
    :func:`position_covariances`."""
    return position_covariances(poses, covariances)[:, :2, :2]


def position_covariances(poses: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """``(n, k, k)`` world-frame covariance of each pose's position, from its tangent covariance.

    ``poses`` ``(n, 4, 4)`` with ``covariances`` ``(n, 6, 6)`` in gtsam's SE(3) order ``[ω; v]``, or
    ``(n, 3, 3)`` with ``(n, 3, 3)`` in SE(2)'s ``[v_x, v_y, ω]``. Under the right perturbation
    ``X·Exp(δ)`` the position moves by ``R·v`` to first order (``R`` the pose's rotation, ``v`` the
    translational part of ``δ``, in the body frame), so the position's covariance is ``R Σ_vv Rᵀ``.
    """
    poses, covariances = np.asarray(poses, dtype=np.float64), np.asarray(covariances, dtype=np.float64)
    k = poses.shape[-1] - 1  # 3 for SE(3), 2 for SE(2)
    d = covariances.shape[-1]
    if poses.shape[0] != covariances.shape[0] or (k, d) not in ((3, 6), (2, 3)):
        raise ValueError(f"poses {poses.shape} and covariances {covariances.shape} do not match: expected "
                         "(n, 4, 4) with (n, 6, 6) or (n, 3, 3) with (n, 3, 3)")
    v = slice(3, 6) if d == 6 else slice(0, 2)
    R = poses[:, :k, :k]
    return R @ covariances[:, v, v] @ np.swapaxes(R, -1, -2)


ELLIPSE_COLOUR = "#D55E00"
"""Edge colour of the uncertainty ellipses."""
ELLIPSE_SHARE_OF_VIEW = 0.04
"""Automatic ``scale`` of :func:`draw_uncertainty_ellipses`: the largest drawn semi-axis becomes this
fraction of the plot's extent (real 1σ ellipses of a well-constrained map are sub-pixel)."""


def draw_uncertainty_ellipses(ax, poses: np.ndarray, covariances: np.ndarray, every: int = 1,
                              scale: float | None = None, colour: str = ELLIPSE_COLOUR) -> float:
    """Draw the 1σ ellipse of every ``every``-th pose's x–y position (index order), axes scaled by ``scale``.

    Ellipses of :func:`planar_translation_covariances` (semi-axes ``scale·√λ`` along the
    eigenvectors) as one ``EllipseCollection`` on the 2D axes ``ax`` (the caller makes its legend
    entry); held vertices (zero covariance) draw as points. ``scale`` None: :data:`ELLIPSE_SHARE_OF_VIEW`.
    Returns the scale used.
    """
    from matplotlib.collections import EllipseCollection

    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    chosen = np.arange(0, np.shape(poses)[0], every)
    planar = planar_translation_covariances(np.asarray(poses)[chosen], np.asarray(covariances)[chosen])
    eigenvalues, eigenvectors = np.linalg.eigh(planar)  # ascending
    semi = np.sqrt(np.clip(eigenvalues, 0.0, None))
    if scale is None:
        low, high = ax.get_xlim()
        largest = float(semi.max(initial=0.0))
        scale = ELLIPSE_SHARE_OF_VIEW * (high - low) / largest if largest > 0 else 1.0
    angles = np.degrees(np.arctan2(eigenvectors[:, 1, 1], eigenvectors[:, 0, 1]))  # of the major axis
    ellipses = EllipseCollection(2 * scale * semi[:, 1], 2 * scale * semi[:, 0], angles, units="xy",
                                 offsets=np.asarray(poses)[chosen, :2, -1], offset_transform=ax.transData,
                                 facecolors="none", edgecolors=colour, linewidths=0.8)
    ax.add_collection(ellipses)
    return float(scale)


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
