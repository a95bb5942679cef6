"""gtsam's older 3D tags, ``VERTEX3`` and ``EDGE3``, read as ``gtsam.readG2o(path, is3D=True)`` reads them.

gtsam (dataset.cpp) reads ``VERTEX3 id x y z roll pitch yaw`` and ``EDGE3 i j x y z roll pitch yaw``
followed by 21 information entries; the rotation is ``Rot3::Ypr(yaw, pitch, roll)`` = Rz·Ry·Rx and
the 21 entries are the upper triangle of the information in gtsam's own ``[ω; v]`` order (not
permuted, unlike ``EDGE_SE3:QUAT``'s). Every comparison here is against gtsam's reader, never against
those conventions re-implemented: measured poses to 1e-12, information to 1e-12 relative (gtsam's
``RᵀR`` of the noise model), and the cost ``½ Σ eᵀ Ω e`` against ``NonlinearFactorGraph.error``.

gtsam's ``sphere2500.txt`` and ``sphere2500_groundtruth.txt`` have ``EDGE3`` lines and no vertex
line at all: our reader creates the vertices the edges name, at the identity, with one warning.
"""

from __future__ import annotations


import numpy as np
import pytest

from posegraph.errors import G2oFormatError, GraphError
from tests.io.helpers import read_with_warnings
from posegraph.io.g2o import read_g2o, rotations_from_roll_pitch_yaw
from posegraph.solve.residuals import cost

gtsam = pytest.importorskip("gtsam")

# gtsam's bundled files with EDGE3 lines and 21 information entries (and no vertex lines).
EDGE3_EXAMPLES = ["sphere2500.txt", "sphere2500_groundtruth.txt"]

UPPER_ROWS, UPPER_COLS = np.triu_indices(6)


def gtsam_between_factors(factors):
    return [factors.at(k) for k in range(factors.size()) if isinstance(factors.at(k), gtsam.BetweenFactorPose3)]


def gtsam_information(factor):
    r = factor.noiseModel().R()
    return r.T @ r


def values_of(ids, poses):
    values = gtsam.Values()
    for key, pose in zip(np.asarray(ids).tolist(), poses):
        values.insert(int(key), gtsam.Pose3(pose))
    return values


def random_poses(rng, n):
    from scipy.spatial.transform import Rotation

    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    poses[:, :3, 3] = rng.normal(scale=3.0, size=(n, 3))
    return poses


def assert_edges_match_gtsam(graph, factors):
    """Same keys, measured poses and information as gtsam's between factors, in file order."""
    between = gtsam_between_factors(factors)
    assert len(between) == graph.num_edges
    keys = np.array([f.keys() for f in between], dtype=np.int64).reshape(-1, 2)
    np.testing.assert_array_equal(graph.ids[graph.edge_from], keys[:, 0])
    np.testing.assert_array_equal(graph.ids[graph.edge_to], keys[:, 1])
    measured = np.stack([f.measured().matrix() for f in between])
    np.testing.assert_allclose(graph.measurements, measured, rtol=0, atol=1e-12)
    information = np.stack([gtsam_information(f) for f in between])
    scale = np.abs(information).max(axis=(1, 2), keepdims=True)
    np.testing.assert_allclose(graph.information / scale, information / scale, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- the Euler convention


@pytest.mark.parametrize("batch", [(), (1,), (3, 1, 2)])
def test_roll_pitch_yaw_is_gtsams_ypr(batch):
    rng = np.random.default_rng(len(batch))
    # Angles well beyond ±π and the gimbal-lock pitches ±π/2 included.
    angles = rng.uniform(-7.0, 7.0, size=batch + (3,))
    angles.reshape(-1, 3)[0, 1] = np.pi / 2
    rotations = rotations_from_roll_pitch_yaw(angles)
    assert rotations.shape == batch + (3, 3)
    flat = rotations.reshape(-1, 3, 3)
    for (roll, pitch, yaw), rotation in zip(angles.reshape(-1, 3), flat):
        expected = gtsam.Rot3.Ypr(yaw, pitch, roll).matrix()
        np.testing.assert_allclose(rotation, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(flat @ np.swapaxes(flat, -1, -2), np.broadcast_to(np.eye(3), flat.shape), atol=1e-15)


# ----------------------------------------------------------------------------- gtsam's bundled files


@pytest.mark.parametrize("name", EDGE3_EXAMPLES)
def test_bundled_edge3_file_matches_gtsam(gtsam_example_file, name):
    path = gtsam_example_file(name)
    graph, messages = read_with_warnings(path)
    factors, values = gtsam.readG2o(str(path), True)
    assert values.size() == 0  # gtsam reads no initial values from these files
    assert_edges_match_gtsam(graph, factors)

    # The vertices are those the edges name, sorted, at the identity, with one warning saying so.
    edge_ids = np.array([f.keys() for f in gtsam_between_factors(factors)], dtype=np.int64)
    np.testing.assert_array_equal(graph.ids, np.unique(edge_ids))
    np.testing.assert_array_equal(graph.poses, np.broadcast_to(np.eye(4), graph.poses.shape))
    assert not graph.fixed.any()
    assert len(messages) == 1, messages
    (message,) = messages
    assert message.startswith(f"{path}: ")
    for fragment in ("no vertex lines, so no initial values", f"{graph.num_vertices} vertices", "identity"):
        assert fragment in message, (fragment, message)

    # The cost agrees with gtsam's at the identity start and at random poses.
    rng = np.random.default_rng(7)
    for poses in (graph.poses, random_poses(rng, graph.num_vertices)):
        expected = factors.error(values_of(graph.ids, poses))
        assert cost(graph, poses) == pytest.approx(expected, rel=1e-11)


def test_edge3_information_is_read_unpermuted(gtsam_example_file):
    """sphere2500.txt holds 10 10 10 100 100 25 on the diagonal: gtsam's [ω; v] order, as is."""
    graph, _ = read_with_warnings(gtsam_example_file("sphere2500.txt"))
    np.testing.assert_array_equal(np.diagonal(graph.information[0]), [10, 10, 10, 100, 100, 25])


def test_edge3_ground_truth_chains_like_the_gtsam_path_of_evaluate(gtsam_example_file):
    """Chaining our reader's odometry edges gives the trajectory ``read_trajectory`` builds with gtsam."""
    from posegraph.analysis.evaluate import chain_odometry, read_trajectory

    path = gtsam_example_file("sphere2500_groundtruth.txt")
    graph, _ = read_with_warnings(path)
    ids, poses = chain_odometry(graph.ids[graph.edge_from], graph.ids[graph.edge_to], graph.measurements)
    expected_ids, expected_poses = read_trajectory(path)
    np.testing.assert_array_equal(ids, expected_ids)
    np.testing.assert_allclose(poses, expected_poses, rtol=0, atol=1e-9)


# ----------------------------------------------------------------------------- VERTEX3 and mixed files


def euler_line(tag, ids, translation, angles, upper=None):
    numbers = [*translation, *angles] + ([] if upper is None else list(upper))
    return " ".join([tag, *map(str, ids), *(repr(float(x)) for x in numbers)])


def quaternion_line(tag, ids, pose, upper=None):
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(pose[:3, :3]).as_quat()  # x y z w
    numbers = [*pose[:3, 3], *q] + ([] if upper is None else list(upper))
    return " ".join([tag, *map(str, ids), *(repr(float(x)) for x in numbers)])


def random_information(rng):
    """A random symmetric positive-definite 6×6 with rotation–translation coupling; its upper triangle."""
    a = rng.normal(size=(6, 6))
    matrix = a @ a.T + 0.5 * np.eye(6)
    return matrix[UPPER_ROWS, UPPER_COLS]


def test_mixed_vertex3_edge3_and_quaternion_lines_match_gtsam(text_file):
    """VERTEX3/EDGE3 interleaved with VERTEX_SE3:QUAT/EDGE_SE3:QUAT, sparse unordered ids, full information."""
    rng = np.random.default_rng(3)
    ids = [40, 3, 17, 8, 25, 11]
    poses = random_poses(rng, len(ids))
    text = []
    for k, (i, pose) in enumerate(zip(ids, poses)):
        if k % 2:
            angles = rng.uniform(-4.0, 4.0, size=3)  # the pose's rotation is replaced by these angles
            poses[k, :3, :3] = gtsam.Rot3.Ypr(angles[2], angles[1], angles[0]).matrix()
            text.append(euler_line("VERTEX3", [i], pose[:3, 3], angles))
        else:
            text.append(quaternion_line("VERTEX_SE3:QUAT", [i], pose))
    pairs = [(40, 3), (3, 17), (17, 8), (8, 25), (25, 11), (11, 40), (3, 25), (8, 40)]
    for k, (i, j) in enumerate(pairs):
        measurement = random_poses(rng, 1)[0]
        if k % 2 == 0:
            text.append(euler_line("EDGE3", [i, j], measurement[:3, 3], rng.uniform(-4, 4, 3), random_information(rng)))
        else:
            text.append(quaternion_line("EDGE_SE3:QUAT", [i, j], measurement, random_information(rng)))
    path = text_file("\n".join(text) + "\n")

    graph, messages = read_with_warnings(path)
    assert messages == []
    factors, values = gtsam.readG2o(str(path), True)
    assert graph.ids.tolist() == ids  # file order, whatever the tag
    expected = np.stack([values.atPose3(i).matrix() for i in ids])
    np.testing.assert_allclose(graph.poses, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(graph.poses, poses, rtol=0, atol=1e-12)
    assert_edges_match_gtsam(graph, factors)
    assert cost(graph) == pytest.approx(factors.error(values), rel=1e-11)


def test_vertex3_lines_of_gtsams_sphere_smallnoise_match_gtsam(gtsam_example_file, text_file):
    """sphere_smallnoise.graph has 2200 VERTEX3 lines (its EDGE3 lines lack the information)."""
    source = gtsam_example_file("sphere_smallnoise.graph")
    vertex_lines = [line for line in source.read_text().splitlines() if line.startswith("VERTEX3")]
    assert len(vertex_lines) == 2200
    path = text_file("\n".join(vertex_lines) + "\n")
    graph = read_g2o(path, require_edges=False)
    _, values = gtsam.readG2o(str(path), True)
    assert values.size() == graph.num_vertices == 2200
    expected = np.stack([values.atPose3(int(i)).matrix() for i in graph.ids])
    np.testing.assert_allclose(graph.poses, expected, rtol=0, atol=1e-12)


def test_edge3_without_information_is_refused_clearly(gtsam_example_file):
    """sphere_smallnoise.graph's EDGE3 lines have 8 fields; gtsam misreads them (one factor), we refuse."""
    path = gtsam_example_file("sphere_smallnoise.graph")
    first_edge = 1 + next(k for k, line in enumerate(path.read_text().splitlines()) if line.startswith("EDGE3"))
    with pytest.raises(G2oFormatError, match="EDGE3 needs 29 fields.*roll pitch yaw.*found 8") as info:
        read_g2o(path)
    assert info.value.line == first_edge
    factors, _ = gtsam.readG2o(str(path), True)
    assert factors.size() == 1  # gtsam's stream stops at the first short line


# ----------------------------------------------------------------------------- files without vertex lines


IDENTITY_UPPER = " ".join("1" if r == c else "0" for r, c in zip(UPPER_ROWS, UPPER_COLS))


def edge3(i, j, rest="1 0 0 0 0 0"):
    return f"EDGE3 {i} {j} {rest} {IDENTITY_UPPER}"


def test_vertices_are_created_sorted_and_fix_applies_to_them(text_file):
    path = text_file("\n".join([edge3(9, 2), edge3(2, 5), "FIX 5", edge3(5, 9)]) + "\n")
    graph, messages = read_with_warnings(path)
    assert graph.ids.tolist() == [2, 5, 9]
    assert graph.fixed.tolist() == [False, True, False]
    assert (graph.ids[graph.edge_from].tolist(), graph.ids[graph.edge_to].tolist()) == ([9, 2, 5], [2, 5, 9])
    assert len(messages) == 1 and "created the 3 vertices" in messages[0]


def test_a_trajectory_needs_vertex_lines(text_file):
    """require_edges=False reads poses: a file of edges alone has none to give."""
    path = text_file("\n".join([edge3(0, 1), edge3(1, 2)]) + "\n")
    with pytest.raises(GraphError, match="no VERTEX_SE3:QUAT lines.*gives no poses") as info:
        read_g2o(path, require_edges=False)
    assert info.value.line is None


def test_created_vertices_need_non_negative_ids(text_file):
    path = text_file("\n".join([edge3(0, 1), edge3(1, -2)]) + "\n")
    with pytest.raises(G2oFormatError, match="EDGE3 names vertex id -2; vertex ids must be non-negative") as info:
        read_g2o(path)
    assert info.value.line == 2


def test_vertex_lines_present_but_incomplete_is_still_an_error(text_file):
    """Vertices are created only when the file has no vertex line at all."""
    path = text_file("\n".join(["VERTEX3 0 0 0 0 0 0 0", edge3(0, 1)]) + "\n")
    with pytest.raises(GraphError, match="names vertex 1, which has no VERTEX_SE3:QUAT line") as info:
        read_g2o(path)
    assert info.value.line == 2


@pytest.mark.parametrize(
    "line, field",
    [
        ("VERTEX3 0 0 0 0 0 nan 0", "field 6 (pitch)"),
        ("EDGE3 0 1 0 0 0 0 0 inf " + IDENTITY_UPPER, "field 8 (yaw)"),
    ],
)
def test_non_finite_euler_fields_are_named(text_file, line, field):
    path = text_file("\n".join(["VERTEX3 0 0 0 0 0 0 0", "VERTEX3 1 0 0 0 0 0 0", line]) + "\n")
    with pytest.raises(G2oFormatError, match=f"{field.replace('(', '[(]').replace(')', '[)]')}.*finite") as info:
        read_g2o(path, require_edges=False)
    assert info.value.line == 3


def test_indefinite_edge3_information_names_the_tag(text_file):
    upper = np.array(IDENTITY_UPPER.split(), dtype=float)
    upper[1] = 3.0  # (1,2) = 3 with unit diagonal: eigenvalues -2 and 4
    line = "EDGE3 0 1 0 0 0 0 0 0 " + " ".join(map(str, upper))
    path = text_file("\n".join([edge3(1, 2), line]) + "\n")
    with pytest.raises(G2oFormatError, match="EDGE3: the information matrix is not positive semi-definite") as info:
        read_g2o(path)
    assert info.value.line == 2 and "--repair-information" in info.value.reason
