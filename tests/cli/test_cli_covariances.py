"""`posegraph optimize --covariances` (the npz against marginal_covariances) and `posegraph plot --covariances`
(ellipses drawn: counted on the figure, and seen in the PNG)."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.analysis.covariance import marginal_covariances
from posegraph.model.graph import held_vertices
from posegraph.io.g2o import read_g2o
from tests.cli.conftest import assert_one_error_line, run_cli


@pytest.fixture
def optimized(tmp_path, shared_dataset):
    """``(input, output g2o, covariance npz)`` of ``optimize smallGrid3D --covariances``."""
    source = shared_dataset("smallGrid3D")
    out, cov = tmp_path / "out.g2o", tmp_path / "cov.npz"
    run = run_cli("optimize", source, "-o", out, "--covariances", cov, "-q")
    assert run.returncode == 0, run.stderr
    return source, out, cov


def test_optimize_writes_the_marginal_covariances_at_the_result(optimized):
    source, out, cov = optimized
    graph, result = read_g2o(source), read_g2o(out)
    with np.load(cov) as data:
        assert sorted(data.files) == ["covariances", "ids"]
        ids, covariances = data["ids"], data["covariances"]
    np.testing.assert_array_equal(ids, graph.ids)
    assert covariances.shape == (graph.num_vertices, 6, 6)
    expected = marginal_covariances(graph, result.poses)  # the result file rounds the poses: close, not equal
    scale = np.abs(expected).max(axis=(1, 2), keepdims=True)
    held = held_vertices(graph)
    assert held.sum() == 1 and np.all(covariances[held] == 0.0)
    assert np.all(np.abs(covariances - expected)[~held] <= 1e-6 * scale[~held])
    assert np.all(np.linalg.eigvalsh(covariances[~held]) > 0)


def test_covariances_are_checked_before_solving_and_written_with_the_result_or_not_at_all(tmp_path, shared_dataset):
    source = shared_dataset("tinyGrid3D")
    out = tmp_path / "out.g2o"
    assert_one_error_line(run_cli("optimize", source, "-o", out, "--covariances", "-"), "covariances", "standard output")
    assert_one_error_line(run_cli("optimize", source, "-o", out, "--covariances", tmp_path / "no" / "cov.npz"),
                          "folder", "does not exist")
    assert_one_error_line(run_cli("optimize", source, "-o", out, "--covariances", out), "same file")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    # the name is kept as given: numpy would append ".npz" to a path without it
    cov = tmp_path / "cov.bin"
    run = run_cli("optimize", source, "-o", out, "--covariances", cov)
    assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cov.bin", "out.g2o"]
    assert "cov.bin" in run.stdout and "covariances" in run.stderr


def ellipse_counts(figure) -> list[int]:
    from matplotlib.collections import EllipseCollection

    return [len(c.get_offsets()) for c in figure.axes[0].collections if isinstance(c, EllipseCollection)]


def test_plot_draws_every_kth_ellipse_on_a_top_view(optimized, tmp_path):
    pytest.importorskip("matplotlib")
    from matplotlib.image import imread

    from posegraph.cli.plot import read_covariances
    from posegraph.analysis.plot import trajectory_figure

    _, out, cov = optimized
    graph = read_g2o(out)
    covariances = read_covariances(str(cov), graph)
    figure = trajectory_figure([graph], ["result"], uncertainty=dict(covariances=covariances, every=7))
    assert not hasattr(figure.axes[0], "set_zlim")  # a top view
    assert ellipse_counts(figure) == [len(range(0, graph.num_vertices, 7))]
    plain, with_ellipses = tmp_path / "plain.png", tmp_path / "ellipses.png"
    assert run_cli("plot", out, "-o", plain, "--top-view").returncode == 0
    run = run_cli("plot", out, "-o", with_ellipses, "--covariances", cov, "--every", "3")
    assert run.returncode == 0, run.stderr
    a, b = imread(plain)[..., :3], imread(with_ellipses)[..., :3]
    assert a.shape == b.shape
    # the ellipses' colour (#D55E00) appears only in the second figure
    orange = np.all(np.abs(b - np.array([0xD5, 0x5E, 0x00]) / 255) < 0.1, axis=-1)
    orange_plain = np.all(np.abs(a - np.array([0xD5, 0x5E, 0x00]) / 255) < 0.1, axis=-1)
    assert orange.sum() > 200 and orange_plain.sum() == 0


def test_ellipse_axes_follow_the_world_frame_position_covariance():
    pytest.importorskip("matplotlib")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from posegraph.lie import se3
    from posegraph.analysis.plot import draw_uncertainty_ellipses, planar_translation_covariances

    pose = se3.exp(np.array([0.0, 0.0, np.pi / 2, 1.0, 2.0, 0.0]))  # a quarter turn about z
    covariance = np.zeros((6, 6))
    covariance[3:, 3:] = np.diag([4.0, 1.0, 9.0])  # body x: σ 2, body y: σ 1
    planar = planar_translation_covariances(pose[None], covariance[None])[0]
    np.testing.assert_allclose(planar, np.diag([1.0, 4.0]), atol=1e-12)  # body x is world y
    figure = Figure()
    FigureCanvasAgg(figure)
    ax = figure.add_subplot()
    assert draw_uncertainty_ellipses(ax, pose[None], covariance[None], scale=3.0) == 3.0
    ellipses = ax.collections[0]
    np.testing.assert_allclose(ellipses._widths * 2, [2 * 3.0 * 2.0])  # stored as half-widths: major 2σ·scale
    np.testing.assert_allclose(ellipses._heights * 2, [2 * 3.0 * 1.0])
    np.testing.assert_allclose(np.rad2deg(ellipses._angles) % 180, [90.0])
    np.testing.assert_allclose(ellipses.get_offsets(), [pose[:2, 3]])


def test_plot_refuses_covariances_of_another_graph(optimized, tmp_path, shared_dataset):
    pytest.importorskip("matplotlib")
    _, _, cov = optimized
    figure = tmp_path / "fig.png"
    assert_one_error_line(run_cli("plot", shared_dataset("parking-garage"), "-o", figure, "--covariances", cov),
                          str(cov), "no covariance for vertex ids")  # its ids go beyond smallGrid3D's
    not_npz = tmp_path / "x.npz"
    not_npz.write_text("hello")
    assert_one_error_line(run_cli("plot", shared_dataset("tinyGrid3D"), "-o", figure, "--covariances", not_npz),
                          str(not_npz), "cannot read covariances")
    assert_one_error_line(run_cli("plot", shared_dataset("tinyGrid3D"), "-o", figure, "--every", "2"),
                          "--covariances")
    assert not figure.exists()


def test_covariances_take_the_gauge_of_fix(tmp_path, shared_dataset):
    """``--fix ID`` holds that vertex instead of the component's anchor: its covariance is the zero one."""
    import dataclasses

    source = shared_dataset("tinyGrid3D")
    out, cov = tmp_path / "out.g2o", tmp_path / "cov.npz"
    assert run_cli("optimize", source, "-o", out, "--covariances", cov, "--fix", "3", "-q").returncode == 0
    graph = read_g2o(source)
    fixed = graph.fixed.copy()
    fixed[graph.index_of([3])] = True
    held_graph = dataclasses.replace(graph, fixed=fixed)
    with np.load(cov) as data:
        covariances = data["covariances"]
    zero = [k for k in range(graph.num_vertices) if not covariances[k].any()]
    assert zero == graph.index_of([3]).tolist()
    expected = marginal_covariances(held_graph, read_g2o(out).poses)
    scale = np.abs(expected).max()
    assert np.abs(covariances - expected).max() <= 1e-6 * scale


def test_planar_position_covariance_of_an_se2_pose():
    """SE(2): ``[v_x, v_y, ω]``, the first two entries rotated to the world frame."""
    from posegraph.lie import se2
    from posegraph.analysis.plot import planar_translation_covariances

    pose = se2.from_xytheta(np.array([1.0, 2.0, np.pi / 2]))
    covariance = np.array([[4.0, 0.0, 0.3], [0.0, 1.0, 0.0], [0.3, 0.0, 0.5]])
    np.testing.assert_allclose(planar_translation_covariances(pose[None], covariance[None])[0], np.diag([1.0, 4.0]),
                               atol=1e-12)
    with pytest.raises(ValueError, match="do not match"):
        planar_translation_covariances(pose[None], np.zeros((1, 6, 6)))
