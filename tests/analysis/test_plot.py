"""Trajectory figures: what is drawn, and the PNG checked as an image."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="plotting needs matplotlib (pip install 'posegraph[plot]')")

from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402
from matplotlib.image import imread  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection  # noqa: E402

from posegraph.model.graph import PoseGraph  # noqa: E402
from posegraph.lie import se2  # noqa: E402
from posegraph.analysis.plot import LOOP_CLOSURE_ALPHA, plot_trajectories, trajectory_figure  # noqa: E402


def helix_graph(n=40, shift=0.0, shuffle_seed=None):
    """A helix with odometry edges and a loop closure every 10 vertices, ids 10, 11, …"""
    s = np.linspace(0, 4 * np.pi, n)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.cos(s) * 5 + shift
    poses[:, 1, 3] = np.sin(s) * 5
    poses[:, 2, 3] = s
    ids = np.arange(10, 10 + n)
    edge_from = np.r_[np.arange(n - 1), np.arange(0, n - 10, 10)]
    edge_to = np.r_[np.arange(1, n), np.arange(10, n, 10)]
    if shuffle_seed is not None:  # vertices in another file order: the path must still follow ids
        perm = np.random.default_rng(shuffle_seed).permutation(n)
        where = np.argsort(perm)
        poses, ids = poses[perm], ids[perm]
        edge_from, edge_to = where[edge_from], where[edge_to]
    m = len(edge_from)
    return PoseGraph(ids, poses, edge_from, edge_to, np.tile(np.eye(4), (m, 1, 1)), np.tile(np.eye(6), (m, 1, 1)))


def test_figure_draws_the_path_in_id_order_and_faint_loop_closures():
    graph = helix_graph(shuffle_seed=3)
    fig = trajectory_figure([graph], ["helix"])
    ax = fig.axes[0]
    (line,) = [l for l in ax.get_lines() if l.get_label() == "helix"]
    x, y, z = line.get_data_3d()
    order = np.argsort(graph.ids)
    np.testing.assert_allclose(np.c_[x, y, z], graph.poses[order, :3, 3])
    (closures,) = [c for c in ax.collections if isinstance(c, Line3DCollection)]
    fig.canvas.draw()  # a 3D collection holds its projected 2D segments once drawn
    assert closures.get_alpha() == LOOP_CLOSURE_ALPHA
    assert len(closures.get_segments()) == np.count_nonzero(~graph.odometry_mask()) == 3
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend[0] == "helix" and "loop closures" in legend[1]


def test_png_overlays_two_graphs_in_their_colours(tmp_path):
    before, after = helix_graph(), helix_graph(shift=3.0)
    path = tmp_path / "fig.png"
    plot_trajectories(path, [before, after], ["before", "after"], size_inches=(6, 5), dpi=100)
    image = imread(path)
    assert image.shape[:2] == (500, 600)
    rgb = image[..., :3].reshape(-1, 3)
    assert len(np.unique((rgb * 255).round().astype(int), axis=0)) > 50  # antialiased lines, text, panes
    for colour in ("#0072B2", "#D55E00"):  # first and second palette entries
        close = np.all(np.abs(rgb - to_rgb(colour)) < 0.08, axis=1)
        assert np.count_nonzero(close) > 200, colour
    assert [p.name for p in tmp_path.iterdir()] == ["fig.png"]  # no temporary file left


def test_failed_save_leaves_nothing(tmp_path):
    path = tmp_path / "fig.notaformat"
    with pytest.raises(ValueError):
        plot_trajectories(path, [helix_graph()])
    assert list(tmp_path.iterdir()) == []


def test_mismatched_labels_are_refused():
    with pytest.raises(ValueError, match="same length"):
        trajectory_figure([helix_graph()], ["a", "b"])


def planar_graph(n=40, shuffle_seed=None):
    """The helix's top view as an SE(2) graph: (n, 3, 3) poses, the same ids and edges."""
    helix = helix_graph(n, shuffle_seed=shuffle_seed)
    heading = np.arctan2(helix.poses[:, 1, 3], helix.poses[:, 0, 3])
    poses = se2.from_xytheta(np.c_[helix.poses[:, :2, 3], heading])
    m = helix.num_edges
    return PoseGraph(helix.ids, poses, helix.edge_from, helix.edge_to, np.tile(np.eye(3), (m, 1, 1)), np.tile(np.eye(3), (m, 1, 1)))


def test_2d_graphs_get_a_top_view_with_equal_scales():
    graph = planar_graph(shuffle_seed=4)
    fig = trajectory_figure([graph], ["planar"])
    (ax,) = fig.axes
    assert ax.name == "rectilinear" and ax.get_aspect() == 1.0
    (line,) = [l for l in ax.get_lines() if l.get_label() == "planar"]
    order = np.argsort(graph.ids)
    np.testing.assert_allclose(np.c_[line.get_xdata(), line.get_ydata()], graph.poses[order, :2, 2])
    (closures,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert closures.get_alpha() == LOOP_CLOSURE_ALPHA
    segments = closures.get_segments()
    closing = ~graph.odometry_mask()
    assert len(segments) == np.count_nonzero(closing) == 3
    np.testing.assert_allclose(segments[0], graph.poses[[graph.edge_from[closing][0], graph.edge_to[closing][0]], :2, 2])
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x", "y")


def test_2d_overlaid_on_3d_is_drawn_at_z0():
    fig = trajectory_figure([helix_graph(), planar_graph()], ["3d", "2d"])
    (ax,) = fig.axes
    assert ax.name == "3d"
    (flat,) = [l for l in ax.get_lines() if l.get_label() == "2d"]
    x, y, z = flat.get_data_3d()
    np.testing.assert_array_equal(z, 0.0)
    np.testing.assert_allclose(np.c_[x, y], helix_graph().poses[:, :2, 3])


def test_2d_png_shows_the_trajectory(tmp_path):
    path = tmp_path / "top.png"
    plot_trajectories(path, [planar_graph()], size_inches=(5, 5), dpi=100)
    rgb = imread(path)[..., :3].reshape(-1, 3)
    assert np.count_nonzero(np.all(np.abs(rgb - to_rgb("#0072B2")) < 0.08, axis=1)) > 200


def test_prior_positions_are_drawn_as_crosses_where_the_priors_put_their_vertices():
    from dataclasses import replace

    from posegraph.lie.group import SE3
    from posegraph.analysis.plot import prior_positions
    from posegraph.model.priors import Priors

    graph = helix_graph()
    offset = SE3.exp(np.array([0.0, 0.0, 0.5, 1.0, 2.0, 3.0]))
    measured = graph.poses[[4]] @ offset  # a pose prior measuring X·O: it puts vertex 4 at X's position
    priors = Priors(
        pose_vertex=np.array([4]), pose_measurements=measured, pose_offsets=offset[None],
        pose_information=np.eye(6)[None], position_vertex=np.array([7, 9]),
        position_measurements=np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), position_information=np.tile(np.eye(3), (2, 1, 1)),
    )  # fmt: skip
    graph = replace(graph, priors=priors)
    expected = np.r_[graph.poses[[4], :3, 3], [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]]
    np.testing.assert_allclose(prior_positions(graph), expected, atol=1e-12)
    ax = trajectory_figure([graph], ["helix"], top_view=True).axes[0]
    (crosses,) = [c for c in ax.collections if c.get_label() == "helix: priors"]
    np.testing.assert_allclose(crosses.get_offsets(), expected[:, :2], atol=1e-12)
