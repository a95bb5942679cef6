"""TUM and KITTI trajectories: known lines, round trips, 2D embedding, bad lines, timestamp matching."""

from __future__ import annotations

import gzip
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from posegraph.errors import InputError, InputWarning
from posegraph.io import trajectory
from posegraph.lie import se2


def random_poses(n, seed=0):
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    poses[:, :3, 3] = rng.normal(scale=10.0, size=(n, 3))
    return poses


def test_tum_line_known_answer():
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()
    pose[:3, 3] = [1.0, 2.0, 3.0]
    text = trajectory.format_tum(np.array([7]), pose[None])
    assert text.splitlines()[0] == "# timestamp tx ty tz qx qy qz qw"
    fields = text.splitlines()[1].split()
    assert fields[0] == "7"
    np.testing.assert_allclose([float(x) for x in fields[1:]], [1, 2, 3, 0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-15)


def test_tum_quaternion_is_scipys_xyzw_with_non_negative_w():
    poses = random_poses(50, seed=3)
    rows = np.loadtxt(trajectory.format_tum(np.arange(50), poses).splitlines(), comments="#")
    q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()  # (x, y, z, w)
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    np.testing.assert_allclose(rows[:, 4:], q, atol=1e-15)
    assert np.all(rows[:, 7] >= 0)


def test_kitti_line_is_the_3x4_matrix_row_by_row():
    poses = random_poses(4, seed=1)
    rows = np.loadtxt(trajectory.format_kitti(poses).splitlines())
    np.testing.assert_array_equal(rows, poses[:, :3, :].reshape(4, 12))


@pytest.mark.parametrize("stamps", ["ids", "seconds"])
def test_tum_round_trip(stamps):
    poses = random_poses(40)
    times = np.arange(40) * 3 + 5 if stamps == "ids" else 1305031102.175304 + np.arange(40) / 30.0
    stamps_back, poses_back = trajectory.parse_tum(trajectory.format_tum(times, poses), "t.txt")
    np.testing.assert_array_equal(stamps_back, times)
    np.testing.assert_allclose(poses_back, poses, atol=1e-14, rtol=1e-15)


def test_tum_rows_are_sorted_by_timestamp():
    poses = random_poses(5)
    lines = trajectory.format_tum(np.arange(5), poses).splitlines()
    shuffled = "\n".join([lines[0], lines[3], lines[1], lines[5], lines[2], lines[4]])
    stamps, back = trajectory.parse_tum(shuffled, "t.txt")
    np.testing.assert_array_equal(stamps, np.arange(5))
    np.testing.assert_allclose(back, poses, atol=1e-13)


def test_kitti_round_trip():
    poses = random_poses(30, seed=2)
    frames, back = trajectory.parse_kitti(trajectory.format_kitti(poses), "k.txt")
    np.testing.assert_array_equal(frames, np.arange(30))
    np.testing.assert_allclose(back, poses, atol=1e-14)


def test_kitti_rotation_with_few_digits_is_projected():
    poses = random_poses(3, seed=4)
    text = "\n".join(" ".join(f"{x:.6e}" for x in row) for row in poses[:, :3, :].reshape(3, 12))
    _, back = trajectory.parse_kitti(text, "k.txt")
    R = back[:, :3, :3]
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ R, np.tile(np.eye(3), (3, 1, 1)), atol=1e-14)
    np.testing.assert_allclose(back, poses, atol=1e-5)


def test_2d_poses_are_written_at_z0(tmp_path):
    rng = np.random.default_rng(5)
    planar = se2.from_xytheta(np.c_[rng.normal(size=(6, 2)), rng.uniform(-np.pi, np.pi, 6)])
    trajectory.write_tum(tmp_path / "t.txt", np.arange(6), planar)
    trajectory.write_kitti(tmp_path / "k.txt", planar)
    rows = np.loadtxt(tmp_path / "t.txt", comments="#")
    assert np.all(rows[:, 3] == 0) and np.all(rows[:, 4:6] == 0)  # tz, qx, qy
    for read in (trajectory.read_tum(tmp_path / "t.txt")[1], trajectory.read_kitti(tmp_path / "k.txt")[1]):
        np.testing.assert_allclose(read, se2.to_se3(planar), atol=1e-15)


def test_compressed_tum_reads(tmp_path):
    poses = random_poses(4)
    path = tmp_path / "t.txt.gz"
    path.write_bytes(gzip.compress(trajectory.format_tum(np.arange(4), poses).encode()))
    np.testing.assert_allclose(trajectory.read_tum(path)[1], poses, atol=1e-14)
    assert trajectory.file_format(path) == "tum"


GOOD = "0 0 0 0 0 0 0 1\n"
BAD_TUM = {
    "seven fields": (GOOD + "1 0 0 0 0 0 1\n", 2, "7 fields, expected 8"),
    "a word": ("# header\n" + GOOD + "\n1 0 0 x 0 0 0 1\n", 4, "field 'x' is not a finite number"),
    "nan": (GOOD + "1 0 0 nan 0 0 0 1\n", 2, "field 'nan' is not a finite number"),
    "zero quaternion": (GOOD + "1 0 0 0 0 0 0 0\n", 2, "quaternion (qx qy qz qw) is zero"),
    "repeated stamp": (GOOD + "2 0 0 0 0 0 0 1\n0.0 1 0 0 0 0 0 1\n", 3, "repeats the one on line 1"),
    "empty": ("# only a comment\n\n", None, "no data lines"),
}


@pytest.mark.parametrize("case", sorted(BAD_TUM))
def test_bad_tum_line(case):
    text, line, reason = BAD_TUM[case]
    with pytest.raises(InputError) as info:
        trajectory.parse_tum(text, "t.txt")
    assert info.value.line == line and info.value.path == "t.txt"
    assert reason in info.value.reason, info.value.reason


def test_far_from_unit_quaternion_warns_once():
    text = GOOD + "1 0 0 0 0 0 0 2\n2 0 0 0 0 0 0 3\n3 0 0 0 0 0 0 1.0001\n"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, poses = trajectory.parse_tum(text, "t.txt")
    messages = [str(w.message) for w in caught if issubclass(w.category, InputWarning)]
    assert messages == ["t.txt:2: 2 quaternion(s) of norm far from 1 (first 2) normalised"]
    np.testing.assert_array_equal(poses[:, :3, :3], np.tile(np.eye(3), (4, 1, 1)))


def test_bad_kitti_lines():
    row = " ".join(["1 0 0 0", "0 1 0 0", "0 0 1 0"])
    with pytest.raises(InputError) as info:
        trajectory.parse_kitti(row + "\n" + row.replace("1 0 0 0", "2 0 0 0", 1) + "\n", "k.txt")
    assert info.value.line == 2 and "not a rotation" in info.value.reason
    mirror = " ".join(["1 0 0 0", "0 1 0 0", "0 0 -1 0"])
    with pytest.raises(InputError, match="det -1"):
        trajectory.parse_kitti(mirror, "k.txt")
    with pytest.raises(InputError, match="11 fields, expected 12"):
        trajectory.parse_kitti(row + "\n" + row[:-2], "k.txt")


@pytest.mark.parametrize(("text", "expected"), [
    ("# c\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", "g2o"),
    ("EDGE3 0 1 0 0 0 0 0 0\n", "g2o"),
    ("", "g2o"),
    ("# timestamp tx ty tz qx qy qz qw\n1.5 0 0 0 0 0 0 1\n", "tum"),
    ("1 0 0 0 0 1 0 0 0 0 1 0\n", "kitti"),
])
def test_sniff_format(text, expected):
    assert trajectory.sniff_format(text, "f") == expected


def test_sniff_format_refuses_other_numbers():
    with pytest.raises(InputError) as info:
        trajectory.sniff_format("\n1 2 3 4 5\n", "f")
    assert info.value.line == 2 and "5 numbers" in info.value.reason


def test_timestamp_table_one_column_is_in_id_order(tmp_path):
    path = tmp_path / "times.txt"
    path.write_text("0.5\n0.6\n0.7\n")
    ids = np.array([20, 10, 30])  # file order
    np.testing.assert_array_equal(trajectory.read_timestamp_table(path, ids), [0.6, 0.5, 0.7])


def test_timestamp_table_two_columns(tmp_path):
    path = tmp_path / "times.txt"
    path.write_text("# id stamp\n30 3.5\n10 1.5\n99 9.0\n20 2.5\n")
    np.testing.assert_array_equal(trajectory.read_timestamp_table(path, np.array([20, 10, 30])), [2.5, 1.5, 3.5])


@pytest.mark.parametrize(("text", "line", "reason"), [
    ("0.5\n0.6\n", None, "2 timestamps for 3 vertices"),
    ("10 1\n20 2\n", None, "no timestamp for vertex 30"),
    ("10 1\n20 2\n10 3\n30 4\n", 3, "vertex id 10 is listed twice"),
    ("10 1\n20 2.5\n30 2.5\n", 3, "the same timestamp 2.5"),
    ("10.5 1\n", 1, "not an integer"),
    ("1 2 3\n", 1, "3 fields, expected 1"),
])
def test_bad_timestamp_table(tmp_path, text, line, reason):
    path = tmp_path / "times.txt"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        trajectory.read_timestamp_table(path, np.array([10, 20, 30]))
    assert info.value.line == line and reason in info.value.reason, info.value


def test_integer_stamps_match_exactly():
    a, b = trajectory.matching_keys(np.array([0.0, 1, 2, 5]), np.array([5, 2, 1, 7]))
    np.testing.assert_array_equal(a, [0, 1, 2, 5])
    np.testing.assert_array_equal(b, [5, 2, 1, 7])


def matched_pairs(keys_a, keys_b):
    common, ia, ib = np.intersect1d(keys_a, keys_b, return_indices=True)
    return sorted(zip(ia.tolist(), ib.tolist()))


def test_nearest_time_matching_known_answer():
    a = np.array([0.004, 1.0, 1.996, 3.5])
    b = np.array([3.0, 2.0, 0.0, 1.011])  # unsorted; 1.011 is 0.011 away from 1.0: no match
    keys_a, keys_b = trajectory.matching_keys(a, b, 0.01)
    assert matched_pairs(keys_a, keys_b) == [(0, 2), (2, 1)]
    np.testing.assert_array_equal(keys_b, [3, 2, 0, 1])  # ranks in time order
    assert len(set(keys_a.tolist())) == 4


def test_a_stamp_claimed_twice_goes_to_the_nearer():
    keys_a, keys_b = trajectory.matching_keys(np.array([0.999, 1.002, 5.0]), np.array([1.0, 2.0, 3.0, 4.0]), 0.01)
    assert matched_pairs(keys_a, keys_b) == [(0, 0)]
    keys_a, keys_b = trajectory.matching_keys(np.array([1.002, 0.999]), np.array([1.0, 2.0, 3.0]), 0.01)
    assert matched_pairs(keys_a, keys_b) == [(1, 0)]


def test_matching_is_symmetric_in_its_arguments():
    rng = np.random.default_rng(7)
    a = np.sort(rng.uniform(0, 10, 40))
    b = np.sort(rng.uniform(0, 10, 25))
    ka, kb = trajectory.matching_keys(a, b, 0.05)
    kb2, ka2 = trajectory.matching_keys(b, a, 0.05)
    assert matched_pairs(ka, kb) == matched_pairs(ka2, kb2) and matched_pairs(ka, kb)


def test_matching_agrees_with_evo():
    sync = pytest.importorskip("evo.core.sync", reason="evo not installed (pip install evo)")
    rng = np.random.default_rng(8)
    reference = np.arange(200) * 0.033 + 100.0 + rng.uniform(-0.002, 0.002, 200)
    estimate = np.sort(rng.choice(reference, 120, replace=False) + rng.uniform(-0.015, 0.015, 120))
    keys_est, keys_ref = trajectory.matching_keys(estimate, reference, 0.01)
    evo_est, evo_ref = sync.matching_time_indices(estimate, reference, 0.01)
    assert 30 < len(evo_est) < 120
    assert matched_pairs(keys_est, keys_ref) == sorted(zip(evo_est, evo_ref))
