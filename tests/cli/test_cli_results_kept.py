"""Nothing a user can get wrong costs a finished optimisation, and nothing ends in a traceback.

What can be checked before solving is (figure format, matplotlib, output folder), with the user's
path in the one-line error and no work done; the result is written before the figure is drawn,
and a figure that fails is a warning.
"""

from __future__ import annotations

import numpy as np
import pytest

from posegraph import cli
from tests.cli.conftest import assert_one_error_line, run_cli


def stderr_lines(capsys) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def test_unsupported_figure_format_is_refused_before_reading(tmp_path, shared_dataset):
    pytest.importorskip("matplotlib")
    source = shared_dataset("smallGrid3D")
    out, figure = tmp_path / "out.g2o", tmp_path / "out.xyz"
    # One line and nothing else on stderr: no "read …" phase line, so nothing was read or solved.
    assert_one_error_line(run_cli("optimize", source, "-o", out, "--plot", figure), str(figure), "'xyz'", "png")
    assert_one_error_line(run_cli("plot", source, "-o", tmp_path / "s.xyz"), "s.xyz", "'xyz'")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_unwritable_output_folder_is_found_before_solving_and_named_as_given(shared_dataset):
    run = run_cli("optimize", shared_dataset("smallGrid3D"), "-o", "/proc/x.g2o")
    line = assert_one_error_line(run, "/proc/x.g2o", "cannot write the result")
    assert ".x.g2o." not in line  # not the temporary file's name


def test_staged_outputs_name_the_destination_not_the_temporary_file(tmp_path):
    from posegraph.io.atomic import StagedOutputs
    from posegraph.errors import OutputError

    with StagedOutputs() as outputs, pytest.raises(OutputError) as missing_folder:
        outputs.stage(tmp_path / "no" / "out.g2o")
    assert str(missing_folder.value).startswith(f"{tmp_path / 'no' / 'out.g2o'}: cannot write the file")
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "entry").write_text("")
    with StagedOutputs() as outputs, pytest.raises(OutputError) as replace_failed:
        with open(outputs.stage(tmp_path / "taken"), "w") as f:
            f.write("x")
        outputs.commit()  # os.replace of a file onto a non-empty folder fails
    assert str(replace_failed.value).startswith(f"{tmp_path / 'taken'}: cannot write the file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]  # the temporary file is gone


def test_a_failing_figure_is_a_warning_and_the_result_is_kept(monkeypatch, capsys, tmp_path, shared_dataset):
    pytest.importorskip("matplotlib")
    import posegraph.analysis.plot as plot
    from posegraph.io.g2o import read_g2o

    def broken(*args, **kwargs):
        raise ValueError("the canvas fell over")

    monkeypatch.setattr(plot, "plot_trajectories", broken)
    out, report, figure = tmp_path / "out.g2o", tmp_path / "r.json", tmp_path / "fig.png"
    status = cli.main(["optimize", str(shared_dataset("tinyGrid3D")), "-o", str(out), "--report", str(report),
                       "--plot", str(figure), "--quiet"])
    assert status == 1  # finished, but without everything asked for
    lines = stderr_lines(capsys)
    assert len(lines) == 1 and lines[0].startswith("posegraph: warning: the figure")
    assert "the canvas fell over" in lines[0] and str(out) in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.g2o", "r.json"]
    source, result = read_g2o(shared_dataset("tinyGrid3D")), read_g2o(out)
    assert np.abs(result.poses - source.poses).max() > 1e-3  # the optimised poses, not a copy


def test_non_g2o_input_is_one_short_line_naming_its_first_line(tmp_path):
    text = "# Notes\n\nThe quick brown fox jumps over the lazy dog, " + "again and again " * 40 + "\nmore words\n"
    notes = tmp_path / "notes.md"
    notes.write_text(text)
    line = assert_one_error_line(run_cli("optimize", notes, "-o", tmp_path / "o.g2o"), str(notes),
                                 "first line with data, line 3, begins with 'The'")
    assert len(line) < len(str(notes)) + 250 and "again" not in line and "lazy" not in line
