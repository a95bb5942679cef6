"""`posegraph export --tum/--kitti`, `posegraph eval` on TUM/KITTI/compressed inputs, checked against evo.

The evo checks run evo's own commands (``evo_ape``, ``evo_rpe``, ``evo_traj``) on the files we wrote
and skip when evo is not installed (``pip install evo``).
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from tests.optional import import_or_skip

from tests.cli.conftest import PROJECT_ROOT, assert_one_error_line, run_cli

EXAMPLE = PROJECT_ROOT / "datasets" / "example_sphere.g2o"
EXAMPLE_TRUTH = PROJECT_ROOT / "datasets" / "example_sphere_groundtruth.g2o"
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def eval_json(*args) -> dict:
    run = run_cli("eval", *args, "--json")
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def export(*args) -> None:
    run = run_cli("export", *args)
    assert run.returncode == 0, run.stderr


def assert_same_figures(a: dict, b: dict, rtol=1e-12) -> None:
    assert a["num_matched"] == b["num_matched"]
    for key in ("ate_translation", "ate_rotation_deg", "rpe_translation", "rpe_rotation_deg"):
        np.testing.assert_allclose([a[key][s] for s in STATS], [b[key][s] for s in STATS], rtol=rtol, atol=1e-12,
                                   err_msg=key)


def test_tum_and_kitti_hold_the_g2o_poses_in_id_order(tmp_path):
    from posegraph.io.g2o import read_g2o
    from posegraph.io.trajectory import read_kitti, read_tum

    shuffled = tmp_path / "shuffled.g2o"
    lines = EXAMPLE.read_text().splitlines(True)
    vertices = [line for line in lines if line.startswith("VERTEX")]
    shuffled.write_text("".join(vertices[::-1] + [line for line in lines if not line.startswith("VERTEX")]))
    export(shuffled, "--tum", tmp_path / "t.txt", "--kitti", tmp_path / "k.txt")
    graph = read_g2o(EXAMPLE)
    assert np.array_equal(graph.ids, np.arange(graph.num_vertices))
    stamps, tum = read_tum(tmp_path / "t.txt")
    frames, kitti = read_kitti(tmp_path / "k.txt")
    np.testing.assert_array_equal(stamps, graph.ids)
    np.testing.assert_array_equal(frames, graph.ids)
    np.testing.assert_allclose(tum, graph.poses, atol=1e-13)
    np.testing.assert_allclose(kitti, graph.poses, atol=1e-13)
    assert (tmp_path / "t.txt").read_text().splitlines()[1].split()[0] == "0"


def test_round_trip_through_tum_and_kitti_gives_the_g2o_figures(tmp_path):
    export(EXAMPLE, "--tum", tmp_path / "est.txt", "--kitti", tmp_path / "est.kitti")
    export(EXAMPLE_TRUTH, "--tum", tmp_path / "gt.txt")
    g2o = eval_json(EXAMPLE, EXAMPLE_TRUTH)
    assert g2o["num_matched"] == 225 and g2o["ate_translation"]["rmse"] > 0.1
    assert_same_figures(eval_json(tmp_path / "est.txt", EXAMPLE_TRUTH), g2o)
    assert_same_figures(eval_json(EXAMPLE, tmp_path / "gt.txt"), g2o)
    assert_same_figures(eval_json(tmp_path / "est.txt", tmp_path / "gt.txt"), g2o)
    assert_same_figures(eval_json(tmp_path / "est.kitti", tmp_path / "gt.txt"), g2o)
    tables = [run_cli("eval", *pair).stdout.splitlines()[3:] for pair in
              ((EXAMPLE, EXAMPLE_TRUTH), (tmp_path / "est.txt", tmp_path / "gt.txt"))]
    assert tables[0] == tables[1] and len(tables[0]) == 5  # the printed table, digit for digit


def test_timestamps_table_and_nearest_time_matching(tmp_path):
    """Timestamps in seconds: the reference's clock is 4 ms off, within evo's default 10 ms."""
    (tmp_path / "times.txt").write_text("".join(f"{1305031102.175 + k / 30:.6f}\n" for k in range(225)))
    (tmp_path / "gt_times.txt").write_text("".join(f"{k} {1305031102.179 + k / 30:.6f}\n" for k in range(225)))
    export(EXAMPLE, "--tum", tmp_path / "est.txt", "--timestamps", tmp_path / "times.txt")
    export(EXAMPLE_TRUTH, "--tum", tmp_path / "gt.txt", "--timestamps", tmp_path / "gt_times.txt")
    assert (tmp_path / "est.txt").read_text().splitlines()[2].split()[0] == "1305031102.208333"
    assert_same_figures(eval_json(tmp_path / "est.txt", tmp_path / "gt.txt"), eval_json(EXAMPLE, EXAMPLE_TRUTH))
    run = run_cli("eval", tmp_path / "est.txt", tmp_path / "gt.txt", "--max-time-diff", "0.003")
    assert_one_error_line(run, "only 0 vertex id(s) in common")


def test_compressed_inputs(tmp_path):
    export(EXAMPLE_TRUTH, "--tum", tmp_path / "gt.txt")
    for path in (EXAMPLE, tmp_path / "gt.txt"):
        (tmp_path / (path.name + ".gz")).write_bytes(gzip.compress(path.read_bytes()))
    assert_same_figures(eval_json(tmp_path / "example_sphere.g2o.gz", tmp_path / "gt.txt.gz"),
                        eval_json(EXAMPLE, EXAMPLE_TRUTH))
    run = run_cli("info", tmp_path / "example_sphere.g2o.gz")
    assert run.returncode == 0 and "225" in run.stdout, run.stderr


def test_binary_input_gets_one_clear_line(tmp_path):
    binary = tmp_path / "graph.g2o.gz"
    binary.write_bytes(gzip.compress(bytes(range(256)) * 8))
    for command in (("info", binary), ("optimize", binary, "-o", tmp_path / "out.g2o"), ("eval", binary, EXAMPLE)):
        line = assert_one_error_line(run_cli(*command), f"{binary}: not a text")
        assert line.isprintable()
    assert not (tmp_path / "out.g2o").exists()


def test_bad_tum_line_names_file_and_line(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("# timestamp tx ty tz qx qy qz qw\n0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n")
    assert_one_error_line(run_cli("eval", bad, EXAMPLE_TRUTH), f"{bad}:3: 7 fields, expected 8")
    assert_one_error_line(run_cli("eval", EXAMPLE, bad), f"{bad}:3:")
    odd = tmp_path / "odd.txt"
    odd.write_text("1 2 3 4 5\n")
    assert_one_error_line(run_cli("eval", odd, EXAMPLE), f"{odd}:1: 5 numbers on the first line")


def test_export_usage_and_nothing_written_on_error(tmp_path):
    assert_one_error_line(run_cli("export", EXAMPLE), "nothing to export")
    assert_one_error_line(run_cli("export", EXAMPLE, "--kitti", tmp_path / "k.txt", "--timestamps", EXAMPLE),
                          "--timestamps applies to --tum only")
    assert_one_error_line(run_cli("export", EXAMPLE, "--tum", tmp_path / "t.txt", "--uncertain-loop-closures"),
                          "--open3d only")
    assert_one_error_line(run_cli("export", EXAMPLE, "--tum", EXAMPLE), "would overwrite the input")
    short = tmp_path / "times.txt"
    short.write_text("0.0\n0.1\n")
    run = run_cli("export", EXAMPLE, "--kitti", tmp_path / "k.txt", "--tum", tmp_path / "t.txt", "--timestamps", short)
    assert_one_error_line(run, f"{short}: 2 timestamps for 225 vertices")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["times.txt"]


def test_kitti_export_warns_when_ids_are_not_frames(tmp_path):
    sparse = tmp_path / "sparse.g2o"
    sparse.write_text("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 5 1 0 0 0 0 0 1\n")
    run = run_cli("export", sparse, "--kitti", tmp_path / "k.txt", "--tum", tmp_path / "t.txt")
    assert run.returncode == 0 and "KITTI has no ids" in run.stderr, run.stderr
    assert len((tmp_path / "k.txt").read_text().splitlines()) == 2
    assert [line.split()[0] for line in (tmp_path / "t.txt").read_text().splitlines()[1:]] == ["0", "5"]


@pytest.mark.parametrize("uncertain", [False, True])
def test_open3d_export_marks_edges_as_asked(tmp_path, uncertain):
    o3d = import_or_skip("open3d", "export --open3d")
    from posegraph.io.g2o import read_g2o

    path = tmp_path / "graph.json"
    export(EXAMPLE, "--open3d", path, *(["--uncertain-loop-closures"] if uncertain else []))
    flags = np.array([edge.uncertain for edge in o3d.io.read_pose_graph(str(path)).edges])
    loop_closures = ~read_g2o(EXAMPLE).odometry_mask()
    assert loop_closures.sum() > 100
    np.testing.assert_array_equal(flags, loop_closures if uncertain else np.zeros_like(flags))


# ---------------------------------------------------------------------------------------------
# evo, on the files we wrote


def evo_command(name: str) -> str:
    found = shutil.which(name) or shutil.which(name, path=os.path.dirname(sys.executable))
    if found is None:
        pytest.skip(f"{name} not found (pip install evo)")
    return found


def evo_stats(tmp_path: Path, command: str, *args) -> dict:
    """The statistics evo saves for one run (full precision, unlike its printed table)."""
    results = tmp_path / f"{command}-{len(list(tmp_path.glob('*.zip')))}.zip"
    argv = [evo_command(command), "tum", *map(str, args), "--save_results", str(results), "--no_warnings"]
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path, timeout=300, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    with zipfile.ZipFile(results) as z:
        return json.loads(z.read("stats.json"))


@pytest.mark.parametrize("times", ["ids", "seconds"])
def test_evo_ape_and_rpe_agree_with_eval(tmp_path, times):
    estimate, truth = tmp_path / "est.txt", tmp_path / "gt.txt"
    if times == "ids":
        export(EXAMPLE, "--tum", estimate)
        export(EXAMPLE_TRUTH, "--tum", truth)
    else:  # nearest-time matching, with the reference's clock 4 ms off
        (tmp_path / "t_est").write_text("".join(f"{1305031102.175 + k / 30:.6f}\n" for k in range(225)))
        (tmp_path / "t_gt").write_text("".join(f"{1305031102.179 + k / 30:.6f}\n" for k in range(225)))
        export(EXAMPLE, "--tum", estimate, "--timestamps", tmp_path / "t_est")
        export(EXAMPLE_TRUTH, "--tum", truth, "--timestamps", tmp_path / "t_gt")
    ours = eval_json(estimate, truth)
    assert ours["num_matched"] == 225
    checks = {
        "ate_translation": ("evo_ape", truth, estimate, "-a"),
        "ate_rotation_deg": ("evo_ape", truth, estimate, "-a", "-r", "angle_deg"),
        "rpe_translation": ("evo_rpe", truth, estimate),
        "rpe_rotation_deg": ("evo_rpe", truth, estimate, "-r", "angle_deg"),
    }
    for key, (command, *args) in checks.items():
        theirs = evo_stats(tmp_path, command, *args)
        np.testing.assert_allclose([ours[key][s] for s in STATS], [theirs[s] for s in STATS], rtol=1e-9,
                                   err_msg=key)


def test_evo_traj_reads_our_kitti_file(tmp_path):
    from posegraph.io.g2o import read_g2o
    from posegraph.io.trajectory import read_kitti

    export(EXAMPLE, "--kitti", tmp_path / "poses.txt")
    argv = [evo_command("evo_traj"), "kitti", "poses.txt", "--full_check", "--save_as_kitti", "--no_warnings"]
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path, timeout=300,
                          env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "nr. of poses\t225" in proc.stdout and "SE(3) conform\tyes" in proc.stdout, proc.stdout
    _, rewritten = read_kitti(tmp_path / "poses.kitti")  # evo's own rewrite of what it read
    np.testing.assert_allclose(rewritten, read_g2o(EXAMPLE).poses, atol=1e-13)
