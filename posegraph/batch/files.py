"""Where each input's outputs go in OUT_DIR, and whether an earlier run already made them.

For an input ``NAME.g2o`` (or ``NAME.g2o.gz``, ``NAME.txt`` …: compression suffix and extension
dropped) OUT_DIR gets ``NAME.g2o`` (the result), ``NAME.report.json`` (``optimize``'s report),
``NAME.log`` (what ``optimize`` printed, after the command line it ran, and its exit status),
and with the options asking for them ``NAME.png`` and ``NAME.cov.npz``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

__all__ = ["FileJob", "plan_jobs", "outputs_complete", "COMPRESSION_SUFFIXES"]

COMPRESSION_SUFFIXES = (".gz", ".bz2", ".xz")
"""Suffixes the reader undoes (:func:`posegraph.io.text_input.read_text`); dropped from output names."""

COMMAND_PREFIX = "$ posegraph "
"""The log's first line: this, then the ``optimize`` command line the file was run with."""


@dataclass(frozen=True)
class FileJob:
    """One input file and the command that optimises it."""

    given: str
    """The input path as given (the summary's ``file``)."""
    input: str
    """The input path made absolute, so a worker with another working folder finds it."""
    output: str
    """The result, ``OUT_DIR/NAME.g2o``."""
    report: str
    """``optimize``'s JSON report, ``OUT_DIR/NAME.report.json``."""
    log: str
    """``OUT_DIR/NAME.log``: the command line, everything ``optimize`` printed, its exit status."""
    extra_outputs: tuple = ()
    """The figure and covariances, when asked for."""
    argv: list = field(default_factory=list)
    """The ``posegraph`` arguments, from ``optimize`` on."""

    @property
    def command(self) -> str:
        """The command line as the log's first line writes it."""
        import shlex

        return COMMAND_PREFIX + shlex.join(self.argv)

    @property
    def outputs(self) -> tuple:
        return (self.output, self.report, *self.extra_outputs, self.log)


def output_stem(path: str) -> str:
    """``NAME`` of ``folder/NAME.g2o.gz``: the base name without compression suffix and extension."""
    name = os.path.basename(path)
    for suffix in COMPRESSION_SUFFIXES:
        if name.endswith(suffix) and len(name) > len(suffix):
            name = name[: -len(suffix)]
    stem, _ = os.path.splitext(name)
    return stem or name


def plan_jobs(paths, out_dir: str, option_argv: list, *, plot: bool = False, covariances: bool = False) -> list:
    """A :class:`FileJob` per input; a :class:`~posegraph.batch.options.BatchError` when two inputs
    would share outputs or an output would be an input (nothing is run then)."""
    from posegraph.batch.options import BatchError

    out_dir = os.path.abspath(out_dir)
    jobs, by_stem = [], {}
    for path in paths:
        source = os.path.abspath(os.fspath(path))
        stem = output_stem(source)
        if stem in by_stem:
            raise BatchError(f"{by_stem[stem]} and {path} would write the same outputs ({stem}.g2o …) in {out_dir}: "
                             "rename one, or run them into different folders")
        by_stem[stem] = path
        base = os.path.join(out_dir, stem)
        extra = {flag: base + suffix for flag, suffix, asked in (("--plot", ".png", plot),
                                                                 ("--covariances", ".cov.npz", covariances)) if asked}
        output, report = base + ".g2o", base + ".report.json"
        argv = ["optimize", source, "-o", output, "--report", report, *option_argv]
        argv += [word for item in extra.items() for word in item]
        jobs.append(FileJob(path, source, output, report, base + ".log", tuple(extra.values()), argv))
    inputs = {os.path.realpath(job.input) for job in jobs}
    for job in jobs:
        clash = next((p for p in job.outputs if os.path.realpath(p) in inputs), None)
        if clash:
            raise BatchError(f"the output {clash} would overwrite an input: choose another OUT_DIR")
    return jobs


def outputs_complete(job: FileJob) -> bool:
    """Whether an earlier run made every output of ``job`` with the same command, succeeded (exit
    status 0), and wrote them after the input was last changed."""
    try:
        newest_input = os.stat(job.input).st_mtime_ns
        if any(os.stat(p).st_mtime_ns < newest_input for p in job.outputs):
            return False
        with open(job.log, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except (OSError, UnicodeDecodeError):
        return False
    return len(lines) >= 2 and lines[0] == job.command and lines[-1] == exit_line(0)


def exit_line(status: int) -> str:
    """The log's last line."""
    return f"exit status {status}"
