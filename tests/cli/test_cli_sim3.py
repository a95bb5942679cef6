"""`posegraph` on Sim(3) graphs written by g2o itself (both variants): optimize, info, eval, export."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.cli.conftest import run_cli

g2o = pytest.importorskip("g2opy", reason="the g2opy wheel is not installed: no g2o-written Sim(3) file")

from datasets.g2opy_sim3 import g2o_chi2  # noqa: E402  (after the skip: it needs g2opy)


def printed(stdout: str, key: str) -> float:
    match = re.search(rf"^{re.escape(key)}:\s+(\S+)", stdout, re.MULTILINE)
    assert match, (key, stdout)
    return float(match.group(1))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from datasets.g2opy_sim3 import main

    folder = tmp_path_factory.mktemp("sim3")
    assert main(["--size", "400", "-o", str(folder / "mono.g2o")]) == 0
    return folder


def test_optimize_reaches_g2os_best_and_reports_g2os_chi2(files):
    out = files / "out.g2o"
    run = run_cli("optimize", files / "mono.g2o", "-o", out)
    assert run.returncode == 0, run.stderr
    reported = printed(run.stdout, "final χ²")
    at_output = g2o_chi2(out)
    assert abs(reported - at_output) <= 1e-9 * at_output  # the χ² printed is the one g2o computes
    assert at_output <= g2o_chi2(files / "mono.g2o", iterations=200) * (1 + 1e-6)
    assert len(out.read_text().splitlines()[0].split()) == 10  # written back in the current variant


def test_the_classic_variant_gives_the_same_poses_written_back_classic(files):
    from posegraph.io.g2o import read_g2o

    current, classic = files / "out_current.g2o", files / "out_classic.g2o"
    assert run_cli("optimize", files / "mono.g2o", "-o", current).returncode == 0
    run = run_cli("optimize", files / "mono_classic.g2o", "-o", classic)
    assert run.returncode == 0, run.stderr
    assert len(classic.read_text().splitlines()[0].split()) == 13  # id, 7-vector, 4 camera numbers
    a, b = read_g2o(current), read_g2o(classic)
    assert b.file_format.variant == "classic"
    np.testing.assert_allclose(b.poses, a.poses, rtol=0, atol=1e-7)


def test_eval_aligns_by_a_similarity_and_export_applies_scales(files):
    out = files / "eval_out.g2o"
    assert run_cli("optimize", files / "mono.g2o", "-o", out).returncode == 0
    optimised = run_cli("eval", out, files / "mono_groundtruth.g2o")
    drifted = run_cli("eval", files / "mono.g2o", files / "mono_groundtruth.g2o")
    assert optimised.returncode == drifted.returncode == 0, optimised.stderr
    assert "Sim(3) alignment (Umeyama with scale" in optimised.stdout
    ate = lambda run: float(re.search(r"^ATE translation \(m\)\s+(\S+)", run.stdout, re.MULTILINE).group(1))  # noqa: E731
    assert ate(optimised) < 0.1 * ate(drifted)
    tum = files / "out.tum"
    assert run_cli("export", out, "--tum", tum).returncode == 0
    rows = np.loadtxt(tum)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:8], axis=1), 1.0, atol=1e-12)  # unit quaternions
    from posegraph.io.g2o import read_g2o

    np.testing.assert_allclose(rows[:, 1:4], read_g2o(out).poses[:, :3, 3], rtol=1e-9, atol=1e-9)  # positions kept


def test_info_names_the_group(files):
    run = run_cli("info", files / "mono.g2o")
    assert run.returncode == 0, run.stderr
    assert "(Sim(3) poses: rotation, translation, scale)" in run.stdout and "information, 7x7" in run.stdout


def test_verify_jacobians_checks_the_files_edges_and_bad_input_is_one_line(files, tmp_path):
    run = run_cli("verify-jacobians", files / "mono.g2o")
    assert run.returncode == 0, run.stdout
    assert "gtsam BetweenFactorSimilarity3  edges of mono.g2o" in run.stdout
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SIM3:EXPMAP 0 0 0 0 1 0 0 0 1\nVERTEX_SIM3:EXPMAP 1 0 0 0 1 1 0 0 -1\n")
    run = run_cli("optimize", bad, "-o", tmp_path / "out.g2o")
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1 and "Traceback" not in run.stderr
    assert f"{bad}:2: VERTEX_SIM3:EXPMAP scale is -1.0" in run.stderr
    assert not (tmp_path / "out.g2o").exists()


def test_compare_on_a_sim3_file_says_why_gtsam_stops_above(files):
    """gtsam's Similarity3 factors have an identity Logmap derivative: its LM ends above our optimum,
    and compare says so rather than leave a bare disagreement."""
    pytest.importorskip("gtsam")
    run = run_cli("compare", files / "mono.g2o")
    ours, theirs = (float(v) for v in re.search(r"^final cost\s+(\S+)\s+(\S+)", run.stdout, re.MULTILINE).groups())
    if run.returncode == 0:  # they agreed within the tolerance: nothing to explain
        assert "identity Logmap" not in run.stdout
    else:
        assert ours < theirs and "identity Logmap derivative" in run.stdout, run.stdout
