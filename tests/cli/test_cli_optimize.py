"""`posegraph optimize` end to end: outputs read back by gtsam, report vs printed figures, exit statuses."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.cli.conftest import CLI, Run, assert_one_error_line, default_sigint, run_cli

TINY_GRID_COST = 9.313909433544  # gtsam 4.3 LM on tinyGrid3D (docs/architecture.md, guide)


def printed(stdout: str, key: str) -> str:
    match = re.search(rf"^{re.escape(key)}:\s+(\S+)", stdout, re.MULTILINE)
    assert match, (key, stdout)
    return match.group(1)


def assert_image(path, min_width=300, min_height=200):
    """The file is a real picture: size, many distinct colours, a fair share of non-white pixels."""
    from matplotlib.image import imread

    image = imread(path)
    assert image.ndim == 3 and image.shape[0] >= min_height and image.shape[1] >= min_width
    rgb = (image[..., :3].reshape(-1, 3) * 255).round().astype(int)
    assert len(np.unique(rgb, axis=0)) > 100
    assert np.mean(np.any(rgb < 200, axis=1)) > 0.01  # lines, text and axes, not a blank canvas


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """One full optimize run on tinyGrid3D with every output, shared by the tests below."""
    from tests.conftest import SHARED_DATASETS

    source = SHARED_DATASETS / "tinyGrid3D.g2o"
    if not source.is_file():
        pytest.skip(f"shared dataset {source} is absent (it sits next to the project in CI)")
    folder = tmp_path_factory.mktemp("optimize")
    out, report, figure = folder / "out.g2o", folder / "report.json", folder / "fig.png"
    run = run_cli("optimize", source, "-o", out, "--report", report, "--plot", figure)
    return source, out, report, figure, run


def test_optimize_writes_a_result_gtsam_reads_at_the_reported_cost(tiny_run):
    gtsam = pytest.importorskip("gtsam")
    source, out, report_path, _, run = tiny_run
    assert run.returncode == 0, run.stderr
    report = json.loads(report_path.read_text())
    factors, values = gtsam.readG2o(str(out), True)
    assert factors.size() == 11 and values.size() == 9
    assert factors.error(values) == pytest.approx(report["final_cost"], rel=1e-9)
    assert report["final_cost"] == pytest.approx(TINY_GRID_COST, rel=1e-9)
    # Same edges as the input, so gtsam's graph of the input scores the output identically.
    factors_in, values_in = gtsam.readG2o(str(source), True)
    assert factors_in.error(values) == pytest.approx(report["final_cost"], rel=1e-9)
    assert factors_in.error(values_in) == pytest.approx(report["file_cost"], rel=1e-9)


def test_report_matches_the_printed_figures(tiny_run):
    _, out, report_path, figure, run = tiny_run
    report = json.loads(report_path.read_text())
    for key in ("initial_cost", "final_cost", "iterations", "converged", "termination", "linear_solver",
                "seconds", "records"):
        assert key in report
    assert float(printed(run.stdout, "final cost")) == pytest.approx(report["final_cost"], rel=1e-11)
    assert float(printed(run.stdout, "initial cost")) == pytest.approx(report["initial_cost"], rel=1e-11)
    assert float(printed(run.stdout, "file cost")) == pytest.approx(report["file_cost"], rel=1e-11)
    assert int(printed(run.stdout, "iterations")) == report["iterations"] == len(report["records"])
    assert report["converged"] is True and report["termination"].startswith("converged")
    assert report["termination"] in run.stdout
    costs = [r["cost"] for r in report["records"]]
    assert costs[-1] == pytest.approx(report["final_cost"], rel=1e-12)
    assert all(b <= a * (1 + 1e-12) for a, b in zip([report["initial_cost"], *costs], costs))
    assert set(report["seconds"]) >= {"read", "initialise", "optimise", "write", "total"}
    # One progress line per iteration on stderr, with its cost.
    progress = [line for line in run.stderr_lines if line.strip().startswith("iter")]
    assert len(progress) == report["iterations"]
    for line, record in zip(progress, report["records"]):
        assert float(re.search(r"cost (\S+)", line).group(1)) == pytest.approx(record["cost"], rel=1e-9)


def test_plot_option_draws_a_picture(tiny_run):
    pytest.importorskip("matplotlib")
    *_, figure, run = tiny_run
    assert run.returncode == 0
    assert_image(figure)


def test_fix_lines_and_edges_are_kept(tmp_path, shared_dataset):
    from posegraph.io.g2o import read_g2o

    text = shared_dataset("tinyGrid3D").read_text() + "FIX 4\n"
    source = tmp_path / "fixed.g2o"
    source.write_text(text)
    out = tmp_path / "out.g2o"
    run = run_cli("optimize", source, "-o", out, "--quiet")
    assert run.returncode == 0, run.stderr
    assert run.stdout == "" and run.stderr == ""  # --quiet
    before, after = read_g2o(source), read_g2o(out)
    np.testing.assert_array_equal(after.fixed, before.fixed)
    assert after.fixed.sum() == 1
    np.testing.assert_array_equal(after.ids[after.edge_from], before.ids[before.edge_from])
    np.testing.assert_array_equal(after.ids[after.edge_to], before.ids[before.edge_to])
    np.testing.assert_allclose(after.measurements, before.measurements, atol=1e-15)
    np.testing.assert_allclose(after.information, before.information, rtol=1e-15)
    k = int(np.flatnonzero(before.fixed)[0])
    np.testing.assert_allclose(after.poses[k], before.poses[k], atol=1e-15)  # FIX vertex untouched
    assert np.abs(after.poses - before.poses).max() > 1e-3  # the others moved


def test_iteration_cap_exits_1_with_the_result_written(tmp_path, shared_dataset):
    out, report = tmp_path / "out.g2o", tmp_path / "r.json"
    run = run_cli("optimize", shared_dataset("tinyGrid3D"), "-o", out, "--report", report,
                  "--init", "file", "--max-iterations", "1", "--linear-solver", "scipy")
    assert run.returncode == 1, run.stderr
    assert any(line.startswith("posegraph: warning:") and "before converging" in line for line in run.stderr_lines)
    data = json.loads(report.read_text())
    assert data["converged"] is False and data["iterations"] == 1 and data["termination"] == "maximum iterations"
    assert out.is_file() and data["final_cost"] < data["initial_cost"]
    assert data["linear_solver"].startswith("scipy") and data["settings"]["linear_solver_requested"] == "scipy"


MALFORMED = {
    "field count": ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0\n", 2),
    "not a number": ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 zero 0 0 0 1\n", 2),
    "missing vertex": (
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
        "EDGE_SE3:QUAT 0 7 1 0 0 0 0 0 1 " + " ".join("1" if k in (0, 6, 11, 15, 18, 20) else "0" for k in range(21))
        + "\n",
        3,
    ),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_input_exits_2_with_one_line_and_writes_nothing(tmp_path, case):
    text, line = MALFORMED[case]
    source = tmp_path / "bad.g2o"
    source.write_text(text)
    out, report, figure = tmp_path / "out.g2o", tmp_path / "r.json", tmp_path / "f.png"
    run = run_cli("optimize", source, "-o", out, "--report", report, "--plot", figure)
    assert_one_error_line(run, f"{source}:{line}:")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.g2o"]


def test_missing_file_and_folder_are_one_line_errors(tmp_path, shared_dataset):
    run = run_cli("optimize", tmp_path / "nope.g2o", "-o", tmp_path / "out.g2o")
    assert_one_error_line(run, "nope.g2o")
    run = run_cli("optimize", shared_dataset("tinyGrid3D"), "-o", tmp_path / "no" / "such" / "out.g2o")
    assert_one_error_line(run, "does not exist")
    assert list(tmp_path.iterdir()) == []


def test_usage_errors_are_one_line(tmp_path):
    assert_one_error_line(run_cli("optimize", tmp_path / "x.g2o"), "-o")
    assert_one_error_line(run_cli("optimize", "x.g2o", "-o", "y.g2o", "--method", "newton"), "newton")
    assert_one_error_line(run_cli("optimize", "x.g2o", "-o", "y.g2o", "--max-iterations", "-3"), "-3")
    for beyond_int64 in ("1000000000000000000000", str(2**63)):  # an OverflowError (exit 3) deep inside before
        assert_one_error_line(run_cli("optimize", "x.g2o", "-o", "y.g2o", "--fix", "0", beyond_int64),
                              f"argument --fix: too large: {beyond_int64} (at most 2^63 - 1")
    assert_one_error_line(run_cli("frobnicate"), "frobnicate")
    assert_one_error_line(run_cli("optimize", "x.g2o", "-o", tmp_path / "a.g2o", "--report", tmp_path / "a.g2o"),
                          "same file")
    assert list(tmp_path.iterdir()) == []


def test_input_is_never_overwritten_without_force(tmp_path, shared_dataset):
    source = tmp_path / "in.g2o"
    original = shared_dataset("tinyGrid3D").read_bytes()
    source.write_bytes(original)
    run = run_cli("optimize", source, "-o", source)
    assert_one_error_line(run, "--force")
    assert source.read_bytes() == original
    run = run_cli("optimize", source, "-o", tmp_path / "out.g2o", "--report", source)
    assert_one_error_line(run, "overwrite the input")
    assert source.read_bytes() == original
    run = run_cli("optimize", source, "-o", source, "--force", "--quiet")
    assert run.returncode == 0, run.stderr
    assert source.read_bytes() != original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.g2o"]


def test_ctrl_c_exits_130_and_leaves_no_output(tmp_path, shared_dataset):
    # torus3D from the file's poses takes hundreds of Gauss-Newton iterations with zero tolerances
    # (sphere2500 from odometry converged within a fraction of a second, sometimes before the signal).
    source = shared_dataset("torus3D")
    out, report = tmp_path / "out.g2o", tmp_path / "r.json"
    proc = subprocess.Popen(
        [sys.executable, str(CLI), "optimize", str(source), "-o", str(out), "--report", str(report),
         "--init", "file", "--method", "gn", "--relative-tolerance", "0", "--absolute-tolerance", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint,
    )
    try:
        # Interrupt once the solver is iterating (the first progress line), as a user would.
        deadline = time.monotonic() + 120
        seen = []
        for line in proc.stderr:
            seen.append(line)
            if line.strip().startswith("iter") or time.monotonic() > deadline:
                break
        proc.send_signal(signal.SIGINT)
        _, rest = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, "".join(seen) + rest
    assert "Traceback" not in rest
    assert list(tmp_path.iterdir()) == []  # no result, no report, no temporary file


def test_pcg_reaches_the_default_solvers_cost(tmp_path, shared_dataset):
    pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")
    reports = {}
    for solver in ("auto", "pcg"):
        reports[solver] = tmp_path / f"{solver}.json"
        run = run_cli("optimize", shared_dataset("sphere2500"), "-o", tmp_path / f"{solver}.g2o",
                      "--report", reports[solver], "-q", "--linear-solver", solver)  # fmt: skip
        assert run.returncode == 0, run.stderr
    default, pcg = (json.loads(reports[s].read_text()) for s in ("auto", "pcg"))
    assert pcg["linear_solver"].startswith("pcg (aggregation multigrid")
    assert pcg["settings"]["linear_solver_requested"] == "pcg"
    assert pcg["final_cost"] == pytest.approx(default["final_cost"], rel=1e-9)


def test_pcg_without_pyamg_is_one_line_saying_what_to_install(tmp_path, shared_dataset):
    # pyamg hidden from the process (a None entry in sys.modules makes its import fail)
    code = ("import sys; sys.modules['pyamg'] = None; from posegraph.cli import main; "
            f"sys.exit(main(['optimize', {str(shared_dataset('tinyGrid3D'))!r}, '-o', {str(tmp_path / 'o.g2o')!r}, "
            "'--linear-solver', 'pcg', '-q']))")  # fmt: skip
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=CLI.parent, timeout=120)
    run = Run([], proc.returncode, proc.stdout, proc.stderr)
    assert_one_error_line(run, "pcg", 'pip install "posegraph[large]"')
    assert not (tmp_path / "o.g2o").exists()


# The process sees 1 kB of free memory, so that no Cholesky factor fits.
NO_MEMORY = ("import sys; import posegraph.linalg.heap as heap; heap.available_bytes = lambda: 1000; {hide}"
             "from posegraph.cli import main; sys.exit(main(['optimize', {source!r}, '-o', {output!r}, '--report', {report!r}, '-q']))")  # fmt: skip


def test_auto_solves_by_pcg_when_the_factor_would_not_fit(tmp_path, shared_dataset):
    pytest.importorskip("pyamg", reason="pyamg (posegraph[large]) is not installed")
    from posegraph.linalg import cholmod

    if cholmod.load() is None:
        pytest.skip(f"CHOLMOD is not available: {cholmod.unavailable_reason()}")
    source, output, report = shared_dataset("sphere2500"), tmp_path / "o.g2o", tmp_path / "r.json"
    code = NO_MEMORY.format(hide="", source=str(source), output=str(output), report=str(report))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=CLI.parent, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert [line for line in proc.stderr.splitlines() if "would take" in line and "solving by multigrid" in line]
    assert json.loads(report.read_text())["linear_solver"].startswith("pcg")
    default = run_cli("optimize", source, "-o", tmp_path / "d.g2o", "--report", tmp_path / "d.json", "-q")
    assert default.returncode == 0, default.stderr
    costs = [json.loads(path.read_text())["final_cost"] for path in (report, tmp_path / "d.json")]
    assert costs[0] == pytest.approx(costs[1], rel=1e-9)


def test_auto_without_pyamg_when_the_factor_would_not_fit_is_one_line_and_no_output(tmp_path, shared_dataset):
    from posegraph.linalg import cholmod

    if cholmod.load() is None:
        pytest.skip(f"CHOLMOD is not available: {cholmod.unavailable_reason()}")
    output = tmp_path / "o.g2o"
    code = NO_MEMORY.format(hide="sys.modules['pyamg'] = None; ", source=str(shared_dataset("tinyGrid3D")),
                            output=str(output), report=str(tmp_path / "r.json"))  # fmt: skip
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=CLI.parent, timeout=120)
    assert_one_error_line(Run([], proc.returncode, proc.stdout, proc.stderr), "would take", "kiB", 'pip install "posegraph[large]"')
    assert list(tmp_path.iterdir()) == []
