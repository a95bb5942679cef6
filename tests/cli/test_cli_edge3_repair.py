"""The command line on gtsam's EDGE3 files (sphere2500.txt) and with ``--repair-information`` (cubicle.g2o)."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from tests.optional import import_or_skip

from tests.cli.conftest import assert_one_error_line, run_cli


def printed(stdout: str, key: str) -> str:
    match = re.search(rf"^{re.escape(key)}:\s+(\S+)", stdout, re.MULTILINE)
    assert match, (key, stdout)
    return match.group(1)


def read_quietly(path, **options):
    from posegraph.errors import InputWarning
    from posegraph.io.g2o import read_g2o

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        return read_g2o(path, **options)


# ----------------------------------------------------------------------------- sphere2500.txt


def test_optimize_gtsams_sphere2500_txt_reaches_gtsams_optimum(tmp_path, gtsam_example_file):
    """No vertex lines: the chordal start (the default) works, and LM ends at gtsam's final cost."""
    from posegraph.crosscheck.gtsam_bridge import run_gtsam
    from posegraph.solve.residuals import cost

    source = gtsam_example_file("sphere2500.txt")
    out = tmp_path / "out.g2o"
    run = run_cli("optimize", source, "-o", out, "--quiet")
    assert run.returncode == 0, run.stderr
    assert run.stdout == ""
    assert run.stderr == ""  # the chordal start does not use the file's (missing) poses: no warning

    written = read_quietly(out)
    ours = cost(written)
    # gtsam's LM from its own chordal start (InitializePose3) on gtsam's reading of the file. gtsam's
    # LM creeps here (~46 iterations): a tighter tolerance than its default 1e-5 lets it finish.
    theirs = run_gtsam(source, graph=written, init="chordal", relative_tolerance=1e-8, absolute_tolerance=0.0)
    assert theirs.initial_cost > 100 * theirs.final_cost  # a real optimisation, not a start at the optimum
    assert ours == pytest.approx(theirs.final_cost, rel=1e-6)


def test_a_trajectory_command_refuses_a_file_without_vertices(tmp_path, gtsam_example_file):
    pytest.importorskip("matplotlib")
    figure = tmp_path / "sphere.png"
    assert_one_error_line(run_cli("plot", gtsam_example_file("sphere2500.txt"), "-o", figure), "gives no poses")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- --repair-information


def test_optimize_cubicle_only_with_repair(tmp_path, shared_dataset):
    from posegraph.crosscheck.gtsam_bridge import run_gtsam
    from posegraph.solve.residuals import cost

    source = shared_dataset("cubicle")
    out = tmp_path / "out.g2o"
    refused = run_cli("optimize", source, "-o", out)
    assert_one_error_line(refused, f"{source}:5753:", "not positive semi-definite", "--repair-information")
    assert list(tmp_path.iterdir()) == []

    run = run_cli("optimize", source, "--repair-information", "-o", out)
    assert run.returncode == 0, run.stderr
    assert printed(run.stdout, "termination") == "converged:"
    assert sum("repaired 5021 information matrices" in line for line in run.stderr_lines) == 1
    final = float(printed(run.stdout, "final cost"))

    # The written file holds the repaired matrices: it reads back without the option.
    written = read_quietly(out)
    assert cost(written) == pytest.approx(final, rel=1e-9)
    repaired = read_quietly(source, repair_information=True)
    np.testing.assert_allclose(written.information, repaired.information, rtol=1e-15, atol=0)

    # gtsam reaches the same optimum on the repaired model from its own chordal start.
    pytest.importorskip("gtsam")
    theirs = run_gtsam(repaired, init="chordal", relative_tolerance=1e-8, absolute_tolerance=0.0)
    assert final == pytest.approx(theirs.final_cost, rel=1e-6)


UPPER = [(r, c) for r in range(6) for c in range(r, 6)]


def indefinite_file(folder):
    """A 4-vertex loop whose last edge's information is indefinite (line 8)."""
    identity = " ".join("1" if r == c else "0" for r, c in UPPER)
    indefinite = " ".join("3" if (r, c) == (0, 1) else ("1" if r == c else "0") for r, c in UPPER)
    lines = [f"VERTEX_SE3:QUAT {i} {i} {i % 2} 0 0 0 0 1" for i in range(4)]
    lines += [f"EDGE_SE3:QUAT {i} {i + 1} 1 0 0 0 0 0 1 {identity}" for i in range(3)]
    lines += [f"EDGE_SE3:QUAT 3 0 -3 0 0 0 0 0 1 {indefinite}"]
    path = folder / "indefinite.g2o"
    path.write_text("\n".join(lines) + "\n")
    return path


def command_lines(path, folder):
    """Each command that reads a g2o file, with what it needs (and the module it needs, if any)."""
    return {
        "info": (["info", path], None),
        "eval": (["eval", path, path], None),
        "verify-jacobians": (["verify-jacobians", path, "--samples", "5", "--no-gtsam"], None),
        "compare": (["compare", path, "--quiet"], "gtsam"),
        "plot": (["plot", path, "-o", folder / "figure.png"], "matplotlib"),
        "export": (["export", path, "--ply", folder / "lines.ply"], "open3d"),
    }


@pytest.mark.parametrize("command", ["info", "eval", "verify-jacobians", "compare", "plot", "export"])
def test_every_reading_command_takes_the_repair_option(tmp_path, command):
    path = indefinite_file(tmp_path)
    args, module = command_lines(path, tmp_path)[command]
    if module:
        import_or_skip(module, command)
    if command == "info":  # an inspection command describes what optimize would refuse
        run = run_cli(*args)
        assert run.returncode == 0, run.stderr
        refusal = [line for line in run.stdout.splitlines() if line.startswith("optimize refuses:")]
        assert len(refusal) == 1 and "1 information matrices are not positive semi-definite" in refusal[0]
        assert "line 8" in refusal[0] and "--repair-information" in refusal[0]
    else:
        assert_one_error_line(run_cli(*args), f"{path}:8:", "--repair-information")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["indefinite.g2o"]

    run = run_cli(*args, "--repair-information")
    assert run.returncode == 0, run.stderr
    assert any(f"{path}:8: repaired 1 information matrices" in line for line in run.stderr_lines), run.stderr
    if command == "info":
        assert "eigenvalues" in run.stdout and "optimize refuses" not in run.stdout


EDGE_ONLY_WARNING = "no vertex lines, so no initial values: created the 225 vertices its edges name at the identity pose"


@pytest.fixture(scope="module")
def edge_only_file(tmp_path_factory):
    """The bundled example without its vertex lines, as gtsam's and iSAM's files come."""
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "datasets" / "example_sphere.g2o"
    path = tmp_path_factory.mktemp("edges") / "edges.g2o"
    path.write_text("".join(line for line in example.read_text().splitlines(True) if not line.startswith("VERTEX")))
    return path


@pytest.mark.parametrize("argv", [["optimize", "-o", "OUT"], ["optimize", "-o", "OUT", "--init", "odometry"],
                                  ["optimize", "-o", "OUT", "--robust", "gnc"], ["certify", "-o", "OUT"],
                                  ["replay", "--batch-size", "50"], ["verify-jacobians", "--no-gtsam", "--samples", "5"]])
def test_an_edge_only_file_gets_no_warning_when_the_start_is_not_the_files(edge_only_file, tmp_path, argv):
    out = tmp_path / "out.g2o"
    run = run_cli(argv[0], edge_only_file, *[str(out) if a == "OUT" else a for a in argv[1:]], "-q")
    assert run.returncode == 0, run.stderr
    assert run.stderr == ""


def test_an_edge_only_file_started_from_its_poses_gets_one_short_warning(edge_only_file, tmp_path):
    run = run_cli("optimize", edge_only_file, "-o", tmp_path / "out.g2o", "-q", "--init", "file", "-i", "3")
    assert run.stderr_lines[0] == f"posegraph: warning: {edge_only_file}: {EDGE_ONLY_WARNING}", run.stderr
    assert sum(EDGE_ONLY_WARNING in line for line in run.stderr_lines) == 1
