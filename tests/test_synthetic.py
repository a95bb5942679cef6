"""Synthetic datasets: determinism, ground truth against the measurements, noise model, outliers, sizes, CLI."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from datasets import synthetic
from datasets.synthetic import NoiseParams, garage, generate, grid, sphere, torus
from posegraph.io.g2o import read_g2o
from posegraph.lie import se3
from posegraph.solve.residuals import cost, edge_residuals

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "datasets" / "example_sphere.g2o"
# The command in datasets/README.md that made the bundled example.
EXAMPLE_ARGS = ["sphere", "--size", "225", "--loop-density", "0.5", "--seed", "7"]

SMALL = {
    "sphere": lambda **kw: sphere(rings=6, nodes_per_ring=7, **kw),
    "torus": lambda **kw: torus(rings=5, nodes_per_ring=8, **kw),
    "grid": lambda **kw: grid(4, 3, 3, **kw),
    "grid-facing": lambda **kw: grid(3, 3, 2, random_orientation=False, **kw),
    "garage": lambda **kw: garage(floors=3, laps_per_floor=3, nodes_per_lap=12, ramp_nodes=4, **kw),
}


def _is_rigid(poses: np.ndarray) -> bool:
    rotations = poses[:, :3, :3]
    orthonormal = np.allclose(rotations @ np.swapaxes(rotations, 1, 2), np.eye(3), atol=1e-12)
    proper = np.allclose(np.linalg.det(rotations), 1.0, atol=1e-12)
    bottom = np.array_equal(poses[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (len(poses), 1)))
    return bool(orthonormal and proper and bottom)


@pytest.mark.parametrize("shape", sorted(SMALL))
def test_noiseless_ground_truth_has_zero_cost(shape):
    data = SMALL[shape](noise=NoiseParams(noiseless=True))
    residuals = edge_residuals(data.ground_truth, data.graph)
    assert np.abs(residuals).max() < 1e-9
    assert cost(data.graph, data.ground_truth) < 1e-12
    assert _is_rigid(data.ground_truth)
    # ...while the composed odometry is the start, and noiseless odometry reproduces the truth.
    np.testing.assert_allclose(data.graph.poses, data.ground_truth, atol=1e-9)


@pytest.mark.parametrize("shape", sorted(SMALL))
def test_cost_at_ground_truth_follows_the_noise_model(shape):
    """2·cost(truth) is χ² with 6m degrees of freedom: mean 3m, standard deviation √(3m) for the cost."""
    data = SMALL[shape](seed=3)
    m = data.graph.num_edges
    value = cost(data.graph, data.ground_truth)
    assert abs(value - 3 * m) < 5 * np.sqrt(3 * m), (value, 3 * m)


@pytest.mark.parametrize("shape", sorted(SMALL))
def test_initial_poses_are_composed_noisy_odometry(shape):
    data = SMALL[shape](seed=1)
    graph = data.graph
    odometry = np.flatnonzero(data.odometry)
    i, j = graph.edge_from[odometry], graph.edge_to[odometry]
    assert np.array_equal(j, i + 1) and len(odometry) == graph.num_vertices - 1
    predicted = se3.compose(graph.poses[i], graph.measurements[odometry])
    np.testing.assert_allclose(predicted, graph.poses[j], atol=1e-9)
    np.testing.assert_array_equal(graph.poses[0], data.ground_truth[0])
    assert _is_rigid(graph.poses)
    # With noise, the start has drifted away from the truth.
    assert np.abs(graph.poses[-1, :3, 3] - data.ground_truth[-1, :3, 3]).max() > 1e-3


@pytest.mark.parametrize("steps", [0, 1, 2, 3, 17, 64])
def test_prefix_product_equals_the_sequential_product(steps):
    rng = np.random.default_rng(steps)
    increments = se3.exp(rng.normal(scale=0.5, size=(steps, 6)))
    first = se3.exp(rng.normal(size=6))
    expected = [first]
    for step in increments:
        expected.append(expected[-1] @ step)
    np.testing.assert_allclose(synthetic._compose_chain(first, increments), np.array(expected), atol=1e-12)


def test_same_seed_gives_identical_files_and_other_seeds_differ(tmp_path):
    paths = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        data = torus(rings=4, nodes_per_ring=9, noise=NoiseParams(outlier_fraction=0.2), seed=seed)
        paths.append(synthetic.write_dataset(tmp_path / f"{name}.g2o", data))
    (a, a_truth), (b, b_truth), (c, _) = paths
    assert a.read_bytes() == b.read_bytes()
    assert a_truth.read_bytes() == b_truth.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    assert a_truth == tmp_path / "a_groundtruth.g2o"


@pytest.mark.parametrize("fraction", [0.0, 0.1, 0.25, 0.5])
def test_outlier_fraction_is_honoured(fraction):
    data = sphere(rings=8, nodes_per_ring=10, noise=NoiseParams(outlier_fraction=fraction, noiseless=True), seed=2)
    graph = data.graph
    loops = ~data.odometry
    outliers = int(data.outliers.sum())
    inliers = int(loops.sum()) - outliers
    assert inliers == (3 * 10 - 1) * 7
    assert outliers == round(fraction / (1 - fraction) * inliers)
    assert abs(outliers / loops.sum() - fraction) <= 1 / loops.sum()
    assert not np.any(data.outliers & data.odometry)
    # Outliers join non-consecutive vertices and disagree with the truth; inliers agree with it.
    i, j = graph.edge_from[data.outliers], graph.edge_to[data.outliers]
    assert np.all(np.abs(j - i) > 1)
    residual_norm = np.linalg.norm(edge_residuals(data.ground_truth, graph), axis=1)
    assert np.all(residual_norm[~data.outliers] < 1e-9)
    assert np.all(residual_norm[data.outliers] > 1e-3)


@pytest.mark.parametrize("density", [0.0, 0.3, 1.0])
def test_loop_closure_density(density):
    data = torus(rings=4, nodes_per_ring=10, noise=NoiseParams(loop_closure_density=density))
    assert data.num_loop_closures == round(density * (3 * 10 * 4 - 3))
    assert data.graph.num_edges == 39 + data.num_loop_closures


def test_sizes_and_topology():
    s = sphere(rings=5, nodes_per_ring=6)
    assert (s.graph.num_vertices, s.graph.num_edges) == (30, 29 + (3 * 6 - 1) * 4)  # seam pairs are odometry
    t = torus(rings=5, nodes_per_ring=6)
    assert (t.graph.num_vertices, t.graph.num_edges) == (30, 29 + 3 * 6 * 5 - 4)  # the tube is closed
    g = grid(4, 3, 2)
    neighbour_pairs = 3 * 3 * 2 + 4 * 2 * 2 + 4 * 3 * 1
    assert (g.graph.num_vertices, g.graph.num_edges) == (24, neighbour_pairs)
    c = garage(floors=3, laps_per_floor=2, nodes_per_lap=10, ramp_nodes=4)
    assert c.graph.num_vertices == 3 * 2 * 10 + 2 * 4
    assert c.num_loop_closures == 3 * 1 * (3 * 10 - 1)  # less each lap seam's odometry pair
    for data in (s, t, g, c):
        graph = data.graph
        assert np.array_equal(graph.ids, np.arange(graph.num_vertices))
        assert np.all(graph.edge_from != graph.edge_to)
        pairs = set(zip(graph.edge_from.tolist(), graph.edge_to.tolist()))
        assert len(pairs) == graph.num_edges  # no duplicates without outliers
        # Front-end order: sorted by the newer vertex.
        newer = np.maximum(graph.edge_from, graph.edge_to)
        assert np.all(np.diff(newer) >= 0)
        information = graph.information
        assert np.allclose(information, np.swapaxes(information, 1, 2)) and np.all(np.linalg.eigvalsh(information) > 0)


def test_shapes_have_the_documented_geometry():
    s = sphere(rings=4, nodes_per_ring=8, radius=10.0)
    np.testing.assert_allclose(np.linalg.norm(s.ground_truth[:, :3, 3], axis=1), 10.0)
    g = grid(3, 4, 2, spacing=2.0, noise=NoiseParams(noiseless=True))
    loops = ~g.odometry
    step = g.ground_truth[g.graph.edge_to, :3, 3] - g.ground_truth[g.graph.edge_from, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(step, axis=1), 2.0)  # every edge joins lattice neighbours
    assert loops.any()
    t = torus(rings=6, nodes_per_ring=12, major_radius=10.0, minor_radius=3.0)
    xyz = t.ground_truth[:, :3, 3]
    distance_to_core = np.hypot(np.hypot(xyz[:, 0], xyz[:, 1]) - 10.0, xyz[:, 2])
    np.testing.assert_allclose(distance_to_core, 3.0)
    c = garage(floors=3, laps_per_floor=2, nodes_per_lap=20, floor_height=2.5, ramp_nodes=5)
    heights = np.unique(np.round(c.ground_truth[:, 2, 3], 9))
    assert {0.0, 2.5, 5.0} <= set(heights.tolist())
    assert c.ground_truth[:, 2, 3].max() == pytest.approx(5.0)


def test_generate_by_size_and_bad_parameters():
    assert abs(generate("sphere", 2500).graph.num_vertices - 2500) == 0
    for shape in synthetic.SHAPES:
        n = generate(shape, 1000).graph.num_vertices
        assert 0.85 * 1000 <= n <= 1.15 * 1000, (shape, n)
    with pytest.raises(ValueError, match="unknown shape"):
        generate("cylinder", 100)
    with pytest.raises(ValueError, match="outlier_fraction"):
        NoiseParams(outlier_fraction=1.0)
    with pytest.raises(ValueError, match="odometry_rotation_sigma"):
        NoiseParams(odometry_rotation_sigma=0.0)
    with pytest.raises(ValueError, match="rings"):
        sphere(rings=0)


def test_files_read_back_with_the_ground_truth(tmp_path):
    data = garage(floors=2, laps_per_floor=2, nodes_per_lap=8, ramp_nodes=3, seed=4)
    path, truth_path = synthetic.write_dataset(tmp_path / "g.g2o", data)
    graph, truth = read_g2o(path), read_g2o(truth_path)
    assert (graph.num_vertices, graph.num_edges) == (data.graph.num_vertices, data.graph.num_edges)
    np.testing.assert_allclose(graph.poses, data.graph.poses, atol=1e-12)
    np.testing.assert_allclose(truth.poses, data.ground_truth, atol=1e-12)
    np.testing.assert_allclose(graph.measurements, truth.measurements, atol=0)
    assert cost(truth) == pytest.approx(cost(data.graph, data.ground_truth), rel=1e-9)


def _cli(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "datasets.synthetic", *args], cwd=cwd, capture_output=True, text=True, timeout=120)


def test_cli_writes_graph_and_ground_truth(tmp_path):
    out = tmp_path / "s.g2o"
    done = _cli("grid", "--size", "30", "--outliers", "0.2", "--seed", "1", "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert out.is_file() and (tmp_path / "s_groundtruth.g2o").is_file()
    assert "outliers" in done.stdout
    expected = generate("grid", 30, noise=NoiseParams(outlier_fraction=0.2), seed=1).graph
    assert read_g2o(out).num_edges == expected.num_edges


def test_cli_refuses_bad_input_without_traceback_or_files(tmp_path):
    bad = _cli("sphere", "--outliers", "1.5", "-o", str(tmp_path / "x.g2o"))
    assert bad.returncode == 2 and "outlier_fraction" in bad.stderr and "Traceback" not in bad.stderr
    missing = _cli("sphere", "--size", "20", "-o", str(tmp_path / "no" / "x.g2o"))
    assert missing.returncode == 1 and "does not exist" in missing.stderr and "Traceback" not in missing.stderr
    assert list(tmp_path.iterdir()) == []


def test_bundled_example_is_what_the_documented_command_makes(tmp_path):
    if not EXAMPLE.is_file():
        pytest.fail(f"{EXAMPLE} is missing")
    out = tmp_path / "example_sphere.g2o"
    done = _cli(*EXAMPLE_ARGS, "-o", str(out))
    assert done.returncode == 0, done.stderr
    # Equal to rounding, not byte for byte: a last-bit change in the Lie core moves the last digit.
    for made, bundled in ((out, EXAMPLE), (synthetic.groundtruth_path(out), synthetic.groundtruth_path(EXAMPLE))):
        a, b = read_g2o(made), read_g2o(bundled)
        assert np.array_equal(a.ids, b.ids)
        assert np.array_equal(a.edge_from, b.edge_from) and np.array_equal(a.edge_to, b.edge_to)
        np.testing.assert_allclose(a.poses, b.poses, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.measurements, b.measurements, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(a.information, b.information)
    assert EXAMPLE.stat().st_size < 300_000
    assert 200 <= read_g2o(EXAMPLE).num_vertices <= 400


# ---------------------------------------------------------------------------------------------
# Random outliers injected into any graph, and the outlier-index files


def _pair_codes(graph):
    n = graph.num_vertices
    return np.sort(np.stack([graph.edge_from, graph.edge_to], 1), axis=1) @ np.array([n, 1])


@pytest.mark.parametrize("count", [0, 1, 17])
def test_inject_outliers_adds_random_loop_closures_and_keeps_the_rest(count):
    clean = grid(4, 3, 3, seed=5).graph
    graph, indices = synthetic.inject_outliers(clean, count=count, seed=9)
    assert graph.num_edges == clean.num_edges + count
    assert indices.shape == (count,) and np.all(np.diff(indices) > 0)
    kept = np.setdiff1d(np.arange(graph.num_edges), indices)
    # The original edges, in their order, untouched.
    for name in ("edge_from", "edge_to", "measurements", "information"):
        np.testing.assert_array_equal(getattr(graph, name)[kept], getattr(clean, name))
    # New pairs: not odometry, not an existing edge, not drawn twice.
    assert not np.any(graph.odometry_mask()[indices])
    codes = _pair_codes(graph)
    assert len(np.unique(codes)) == len(codes)
    # Front-end order: the newer vertex never decreases (the clean grid is in that order).
    newer = np.maximum(graph.edge_from, graph.edge_to)
    assert np.all(np.diff(newer) >= 0)
    # Random proper rigid measurements, with a loop closure's information.
    rotations = graph.measurements[indices, :3, :3]
    np.testing.assert_allclose(rotations @ np.swapaxes(rotations, 1, 2), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-12)
    loop_information = clean.information[~clean.odometry_mask()]
    for info in graph.information[indices]:
        assert any(np.array_equal(info, other) for other in loop_information)


def test_injected_outliers_are_wrong_and_reproducible():
    data = sphere(rings=6, nodes_per_ring=8, noise=NoiseParams(noiseless=True), seed=1)
    graph, indices = synthetic.inject_outliers(data.graph, fraction=0.2, seed=3)
    assert len(indices) == round(0.2 * data.num_loop_closures)
    norms = np.linalg.norm(edge_residuals(data.ground_truth, graph), axis=1)
    outlier = np.zeros(graph.num_edges, bool)
    outlier[indices] = True
    assert np.all(norms[~outlier] < 1e-9) and np.all(norms[outlier] > 1e-2)
    again, same = synthetic.inject_outliers(data.graph, fraction=0.2, seed=3)
    np.testing.assert_array_equal(same, indices)
    np.testing.assert_array_equal(again.measurements, graph.measurements)
    other, _ = synthetic.inject_outliers(data.graph, fraction=0.2, seed=4)
    assert not np.array_equal(other.measurements, graph.measurements)


def test_injected_outliers_on_a_planar_graph_are_planar_and_wrong(tmp_path):
    """SE(2) graphs get SE(2) outliers (an angle and a planar translation), written back as EDGE_SE2."""
    data = synthetic.manhattan(steps=300, noise=NoiseParams(noiseless=True), seed=2)
    graph, indices = synthetic.inject_outliers(data.graph, fraction=0.3, seed=1)
    assert graph.group.name == "SE2" and graph.measurements.shape[1:] == (3, 3)
    assert len(indices) == round(0.3 * np.count_nonzero(~data.graph.odometry_mask()))
    rotations = graph.measurements[indices, :2, :2]
    np.testing.assert_allclose(rotations @ np.swapaxes(rotations, 1, 2), np.broadcast_to(np.eye(2), rotations.shape), atol=1e-12)
    norms = np.linalg.norm(edge_residuals(data.ground_truth, graph), axis=1)
    outlier = np.zeros(graph.num_edges, bool)
    outlier[indices] = True
    assert np.all(norms[~outlier] < 1e-9) and np.all(norms[outlier] > 1e-2)
    path, _ = synthetic.write_injected(tmp_path / "m.g2o", graph, indices)
    assert "EDGE_SE2" in path.read_text() and "SE3" not in path.read_text()


@pytest.mark.parametrize("wrong_first", [False, True])
def test_inject_outliers_parallel_to_odometry_and_loop_closures(wrong_first):
    clean = grid(4, 3, 3, seed=5).graph
    graph, indices = synthetic.inject_outliers(clean, count=9, seed=9, on_odometry=3, on_loop_closures=2, wrong_first=wrong_first)
    kept = np.setdiff1d(np.arange(graph.num_edges), indices)
    np.testing.assert_array_equal(graph.measurements[kept], clean.measurements)
    codes, clean_codes = _pair_codes(graph), _pair_codes(clean)
    parallel = indices[np.isin(codes[indices], clean_codes)]
    assert len(parallel) == 5  # the other 4 join free pairs
    rank = np.argsort(np.argsort(clean.ids))
    consecutive = np.abs(rank[graph.edge_from[parallel]] - rank[graph.edge_to[parallel]]) == 1
    assert np.count_nonzero(consecutive) == 3
    for k in parallel:  # each follows (or precedes) the original edge it duplicates
        original = kept[np.flatnonzero(codes[kept] == codes[k])[0]]
        assert (k < original) == wrong_first
    # Who is the odometry of a duplicated pair: the first edge in file order, so the wrong one iff wrong_first.
    assert np.count_nonzero(graph.odometry_mask()[indices]) == (3 if wrong_first else 0)
    with pytest.raises(ValueError, match="exceeds"):
        synthetic.inject_outliers(clean, count=2, on_odometry=2, on_loop_closures=1)


def test_inject_outliers_bad_arguments():
    clean = grid(3, 2, 2, seed=1).graph
    with pytest.raises(ValueError, match="exactly one"):
        synthetic.inject_outliers(clean, count=2, fraction=0.1)
    with pytest.raises(ValueError, match="exactly one"):
        synthetic.inject_outliers(clean)
    with pytest.raises(ValueError, match="vertex pairs are free"):
        synthetic.inject_outliers(clean, count=10_000)
    with pytest.raises(ValueError, match="fraction"):
        synthetic.inject_outliers(clean, fraction=-0.5)


def test_injected_graph_and_indices_round_trip_through_files(tmp_path):
    clean = torus(rings=3, nodes_per_ring=6, seed=2).graph
    graph, indices = synthetic.inject_outliers(clean, count=5, seed=0)
    path, indices_path = synthetic.write_injected(tmp_path / "t.g2o", graph, indices)
    assert indices_path == tmp_path / "t.outliers.txt"
    back = read_g2o(path)
    np.testing.assert_array_equal(synthetic.read_outlier_indices(indices_path), indices)
    np.testing.assert_allclose(back.measurements[indices], graph.measurements[indices], atol=1e-12)
    np.testing.assert_array_equal(back.edge_from, graph.edge_from)


def test_dataset_with_outliers_writes_their_indices(tmp_path):
    data = grid(4, 4, 2, noise=NoiseParams(outlier_fraction=0.25), seed=3)
    synthetic.write_dataset(tmp_path / "g.g2o", data)
    written = synthetic.read_outlier_indices(tmp_path / "g.outliers.txt")
    np.testing.assert_array_equal(written, np.flatnonzero(data.outliers))
    assert len(written) > 0
    # Without outliers, no index file.
    synthetic.write_dataset(tmp_path / "h.g2o", grid(3, 3, 2, seed=3))
    assert not (tmp_path / "h.outliers.txt").exists()


def test_cli_inject(tmp_path):
    source = tmp_path / "in.g2o"
    synthetic.write_dataset(source, sphere(rings=5, nodes_per_ring=6, seed=1))
    before = source.read_bytes()
    out = tmp_path / "out.g2o"
    done = _cli("inject", str(source), "--fraction", "0.2", "--seed", "2", "-o", str(out))
    assert done.returncode == 0, done.stderr
    graph, indices = synthetic.inject_outliers(read_g2o(source), fraction=0.2, seed=2)
    np.testing.assert_array_equal(synthetic.read_outlier_indices(tmp_path / "out.outliers.txt"), indices)
    assert read_g2o(out).num_edges == graph.num_edges
    # Never over the input, no traceback, nothing written.
    refused = _cli("inject", str(source), "--count", "3", "-o", str(source))
    assert refused.returncode == 1 and "overwrite the input" in refused.stderr and "Traceback" not in refused.stderr
    assert source.read_bytes() == before
    too_many = _cli("inject", str(source), "--count", "100000", "-o", str(tmp_path / "x.g2o"))
    assert too_many.returncode == 2 and "free" in too_many.stderr and "Traceback" not in too_many.stderr
    assert not (tmp_path / "x.g2o").exists() and not (tmp_path / "x.outliers.txt").exists()


def test_monocular_graph_drifts_in_scale_and_its_loop_closures_carry_the_true_scale():
    from datasets.synthetic import NoiseParams, monocular
    from posegraph.lie import sim3
    from posegraph.lie.group import SIM3_G2O
    from posegraph.solve.residuals import cost

    dataset = monocular(laps=4, nodes_per_lap=60, seed=3)
    graph, truth = dataset.graph, dataset.ground_truth
    assert graph.group is SIM3_G2O and graph.num_vertices == 240
    truth_scales = sim3.scale(truth)
    assert truth_scales.max() / truth_scales.min() > 1.1  # the map's scale drifts (σ√240 ≈ 0.15)
    np.testing.assert_allclose(sim3.scale(graph.poses), 1.0, atol=1e-12)  # the tracker's poses: no scale
    measured = sim3.scale(graph.measurements)
    np.testing.assert_allclose(measured[dataset.odometry], 1.0, atol=1e-12)  # odometry sees no scale change
    loops = ~dataset.odometry
    true_ratio = truth_scales[graph.edge_to[loops]] / truth_scales[graph.edge_from[loops]]
    np.testing.assert_allclose(np.log(measured[loops] / true_ratio), 0.0, atol=0.005)  # σ_λ = 0.001
    np.testing.assert_array_equal(graph.information[:, 6, 6], np.where(dataset.odometry, 1e4, 1e6))
    exact = monocular(laps=3, nodes_per_lap=40, noise=NoiseParams(noiseless=True))
    odometry_scale_error = np.log(sim3.scale(exact.ground_truth[1:]) / sim3.scale(exact.ground_truth[:-1]))
    assert 2 * cost(exact.graph, exact.ground_truth) == pytest.approx(1e4 * np.sum(odometry_scale_error**2), rel=1e-6)


@pytest.mark.parametrize("group_name,kinds", [("SE2", ("position", "bearing", "bearing_range", "prior")), ("SE3", ("position", "prior"))])
def test_landmark_graph_is_exact_at_its_truth_and_deterministic(group_name, kinds):
    from posegraph.lie.group import SE2, SE3
    from posegraph.solve.landmark_residuals import landmark_residuals

    group = {"SE2": SE2, "SE3": SE3}[group_name]
    graph, truth, points = synthetic.landmark_graph(group, 9, 6, kinds, noise=0.0, seed=2, offsets=True)
    assert graph.group is group and truth.shape == graph.poses.shape and points.shape == (6, group.space_dim)
    assert [f.kind for f in graph.landmarks.observations] == list(kinds)
    assert cost(graph, truth) == pytest.approx(0.0, abs=1e-20)
    for family in graph.landmarks.observations:
        np.testing.assert_allclose(landmark_residuals(group, truth, points, family), 0.0, atol=1e-12)
    again, _, _ = synthetic.landmark_graph(group, 9, 6, kinds, noise=0.0, seed=2, offsets=True)
    np.testing.assert_array_equal(again.landmarks.observations[0].measurements, graph.landmarks.observations[0].measurements)
    noisy, _, _ = synthetic.landmark_graph(group, 9, 6, kinds, noise=0.05, seed=2)
    assert not np.allclose(noisy.landmarks.positions, points)
