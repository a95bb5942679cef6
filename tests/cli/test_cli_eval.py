"""`posegraph eval`: known answers on synthetic files, and gtsam's sphere2500 ground truth."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.cli.conftest import assert_one_error_line, run_cli


def table_row(stdout: str, label: str) -> list[float]:
    match = re.search(rf"^{re.escape(label)}\s+(.*)$", stdout, re.MULTILINE)
    assert match, (label, stdout)
    return [float(x) for x in match.group(1).split()]


def test_rigidly_moved_ground_truth_has_zero_ate(tmp_path, shared_dataset):
    """Known answers: a rigid motion gives ATE = RPE = 0, a shift of 0.5 without alignment ATE = 0.5."""
    from posegraph.io.g2o import read_g2o, write_g2o

    graph = read_g2o(shared_dataset("smallGrid3D"))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    T[:3, 3] = [10.0, -4.0, 2.5]
    moved = tmp_path / "moved.g2o"
    write_g2o(moved, graph, T @ graph.poses)
    # A trajectory is enough: keep the vertices only.
    moved.write_text("".join(line for line in moved.read_text().splitlines(True) if line.startswith("VERTEX")))
    shifted = tmp_path / "shifted.g2o"
    poses = graph.poses.copy()
    poses[:, :3, 3] += [0.3, 0.4, 0.0]  # no alignment: ATE is exactly 0.5 everywhere
    write_g2o(shifted, graph, poses)

    run = run_cli("eval", moved, shared_dataset("smallGrid3D"), "--json")
    assert run.returncode == 0, run.stderr
    data = json.loads(run.stdout)
    assert data["num_matched"] == graph.num_vertices
    assert data["ate_translation"]["max"] < 1e-9 and data["rpe_translation"]["max"] < 1e-9
    assert data["ate_rotation_deg"]["max"] < 1e-6
    np.testing.assert_allclose(np.array(data["alignment"]) @ T, np.eye(4), atol=1e-9)

    run = run_cli("eval", shifted, shared_dataset("smallGrid3D"), "--no-align")
    assert run.returncode == 0, run.stderr
    rmse, mean, median, std, low, high = table_row(run.stdout, "ATE translation (m)")
    assert rmse == pytest.approx(0.5, rel=1e-5) and low == pytest.approx(0.5, rel=1e-5)
    assert table_row(run.stdout, "RPE translation (m)")[0] < 1e-9


def test_sphere2500_against_gtsams_ground_truth(tmp_path, shared_dataset, gtsam_example_file):
    """The optimised sphere is far closer to the ground truth than the file's (odometry) poses."""
    from posegraph.analysis.evaluate import evaluate, read_trajectory
    from posegraph.io.g2o import read_g2o, write_g2o
    from posegraph.solve import optimize

    truth = gtsam_example_file("sphere2500_groundtruth.txt")
    source = shared_dataset("sphere2500")
    graph = read_g2o(source)
    optimised = tmp_path / "optimised.g2o"
    write_g2o(optimised, graph, optimize(graph).poses)

    before = json.loads(run_cli("eval", source, truth, "--json").stdout)
    run = run_cli("eval", optimised, truth)
    assert run.returncode == 0, run.stderr
    after = table_row(run.stdout, "ATE translation (m)")
    assert after[0] < 0.2 * before["ate_translation"]["rmse"]
    # The printed table is the library's evaluation of the same files.
    ids, poses = read_trajectory(optimised)
    ref_ids, ref_poses = read_trajectory(truth)
    expected = evaluate(ids, poses, ref_ids, ref_poses)
    assert expected.num_matched == 2500
    for label, stats in (("ATE translation (m)", expected.ate_translation), ("RPE rotation (deg)", expected.rpe_rotation)):
        printed = table_row(run.stdout, label)
        # Printed with six decimals, one format for every number: equal to half a unit of the last digit.
        np.testing.assert_allclose(printed, [stats.rmse, stats.mean, stats.median, stats.std, stats.min, stats.max],
                                   rtol=0, atol=5e-7 * (1 + 1e-9))


def test_eval_errors(tmp_path, shared_dataset):
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 nan 0 0 0 0 0 1\n")
    assert_one_error_line(run_cli("eval", bad, shared_dataset("tinyGrid3D")), f"{bad}:2:")
    assert_one_error_line(run_cli("eval", shared_dataset("tinyGrid3D")), "give a reference file GT", "--priors")


def _planar_files(tmp_path):
    """A 2D g2o file, and the same four poses as a 3D g2o file and as a TUM file in the plane z = 0."""
    poses = [(0, 0, 0), (1, 0, 0.5), (2, 1, 1.0), (2, 2, 2.0)]
    flat, solid, tum = tmp_path / "flat.g2o", tmp_path / "solid.g2o", tmp_path / "flat.tum"
    flat.write_text("".join(f"VERTEX_SE2 {i} {x} {y} {t}\n" for i, (x, y, t) in enumerate(poses)))
    quaternions = [Rotation.from_euler("z", t).as_quat().tolist() for _, _, t in poses]
    tum.write_text("".join(f"{i} {x} {y} 0 " + " ".join(map(repr, q)) + "\n"
                           for i, ((x, y, _), q) in enumerate(zip(poses, quaternions))))
    solid.write_text("".join(f"VERTEX_SE3:QUAT {i} {x} {y} {0.1 * i} " + " ".join(map(repr, q)) + "\n"
                             for i, ((x, y, _), q) in enumerate(zip(poses, quaternions))))
    return flat, solid, tum


def test_a_2d_and_a_3d_trajectory_off_the_plane_are_refused_naming_both(tmp_path):
    flat, solid, _ = _planar_files(tmp_path)
    for estimate, reference in ((flat, solid), (solid, flat)):
        line = assert_one_error_line(run_cli("eval", estimate, reference), "cannot compare a 2D with a 3D trajectory",
                                     f"{flat} is a 2D g2o file" if estimate == flat else f"{flat} a 2D g2o file",
                                     "3D g2o file (SE(3) poses)", f"{solid} leaves the plane z = 0")
        assert run_cli("eval", estimate, reference, "--json").returncode == 2, line


def test_a_2d_trajectory_against_its_3d_copy_in_the_plane_has_zero_errors(tmp_path):
    flat, _, tum = _planar_files(tmp_path)
    run = run_cli("eval", flat, tum)
    assert run.returncode == 0, run.stderr
    assert max(table_row(run.stdout, "ATE translation (m)")) < 1e-9
    assert max(table_row(run.stdout, "RPE rotation (deg)")) < 1e-6
