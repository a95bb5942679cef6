"""The summary: one row per file (from ``optimize``'s report and exit status), written as JSON and CSV."""

from __future__ import annotations

import os

__all__ = ["ROW_FIELDS", "file_row", "skipped_row", "failed_row", "tally", "write_summary", "csv_path_for", "summary_paths"]

ROW_FIELDS = ("file", "vertices", "edges", "final_cost", "chi2_per_dof", "iterations", "seconds", "outliers",
              "status", "reason", "output", "report", "log")
"""The summary's columns. ``status``: ``ok``, ``not converged`` (the iteration cap or another solver
stop came first; the result is written), ``failed`` (``reason``: ``optimize``'s one-line error or
warning), ``skipped`` (complete outputs of an earlier run kept; ``seconds`` then from its report).
``seconds``: the file's wall time on its worker, from the command line to its exit status (the first
file of each worker also pays the imports of the modules its options use); ``outliers``: edges judged outliers (``--robust`` only, else empty)."""

STATUSES = ("ok", "not converged", "failed", "skipped")

SKIPPED_REASON = "outputs of an earlier run complete and newer than the input (--force redoes it)"

_PREFIX = {"error": "posegraph: error: ", "warning": "posegraph: warning: "}


def file_row(job, status: int, printed: str, seconds: float) -> dict:
    """The row of a file ``optimize`` ran on with exit status ``status``, having printed ``printed``."""
    report = _read_report(job.report) if status in (0, 1) else None  # otherwise nothing was written
    if status == 0:
        state, reason = "ok", ""
    elif status == 1:
        state = "not converged" if report is not None and not report.get("converged") else "failed"
        reason = _last_message(printed, "warning")
    else:
        state, reason = "failed", _last_message(printed, "error") or f"exit status {status}"
    return _row(job, report, state, reason, round(seconds, 3))


def skipped_row(job) -> dict:
    """The row of a file whose outputs an earlier run made (:func:`posegraph.batch.files.outputs_complete`)."""
    report = _read_report(job.report)
    seconds = report.get("seconds", {}) if report else {}
    total = sum(v for v in seconds.values() if isinstance(v, (int, float)))
    return _row(job, report, "skipped", SKIPPED_REASON, round(total, 3) if seconds else None)


def failed_row(job, reason: str) -> dict:
    """The row of a file whose task did not return (its worker died, the cluster lost it)."""
    return _row(job, None, "failed", reason, None)


def _row(job, report: dict | None, status: str, reason: str, seconds) -> dict:
    report = report or {}
    outliers = report.get("outlier_edges")
    return {
        "file": job.given, "vertices": report.get("num_vertices"), "edges": report.get("num_edges"),
        "final_cost": report.get("final_cost"), "chi2_per_dof": report.get("chi2_per_dof"),
        "iterations": report.get("iterations"), "seconds": seconds,
        "outliers": len(outliers) if outliers is not None else None, "status": status, "reason": reason,
        "output": job.output if report else None, "report": job.report if report else None, "log": job.log,
    }


def _read_report(path: str) -> dict | None:
    import json

    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def _last_message(printed: str, kind: str) -> str:
    """The last ``posegraph: error:`` (or ``warning:``) line of ``printed``, without that prefix."""
    prefix = _PREFIX[kind]
    lines = [line[len(prefix):] for line in printed.splitlines() if line.startswith(prefix)]
    return lines[-1] if lines else ""


def tally(rows) -> dict:
    """``{status: count}`` over the rows that are set, every status present."""
    counts = dict.fromkeys(STATUSES, 0)
    for row in rows:
        if row is not None:
            counts[row["status"]] += 1
    return counts


def csv_path_for(summary_path: str) -> str:
    """The CSV written beside the JSON summary: ``S.json`` -> ``S.csv``."""
    return os.path.splitext(summary_path)[0] + ".csv"


def summary_paths(summary_path: str) -> tuple[str, ...]:
    """The files a summary is written to: the JSON and its CSV (:func:`csv_path_for`), or only the JSON when
    ``summary_path`` is written into rather than replaced (a character device or a FIFO:
    :func:`~posegraph.io.atomic.output_target`): ``--report /dev/null`` discards the summary and must not
    leave a ``/dev/null.csv`` beside it, nor a second stream be interleaved into a pipe. A path that
    cannot be written keeps its CSV here: :func:`~posegraph.cli.common.check_output` refuses it."""
    from posegraph.errors import OutputError
    from posegraph.io.atomic import output_target

    try:
        node = output_target(summary_path).kind == "node"
    except OutputError:
        node = False
    return (summary_path,) if node else (summary_path, csv_path_for(summary_path))


def write_summary(rows: list, path: str, command: list | None = None) -> None:
    """The summary as JSON at ``path`` (``counts`` by status, ``files``: the rows in input order,
    ``command`` if given) and as CSV beside it (:func:`summary_paths`), written together."""
    import csv
    import io

    from posegraph.io.atomic import StagedOutputs, json_text

    summary = {"counts": tally(rows), "files": rows}
    if command is not None:
        summary["command"] = command
    table = io.StringIO()
    writer = csv.DictWriter(table, fieldnames=ROW_FIELDS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: ("" if v is None else v) for k, v in row.items()} for row in rows)
    with StagedOutputs() as outputs:
        for target, text in zip(summary_paths(path), (json_text(summary), table.getvalue())):
            outputs.write_text(target, text)
        outputs.commit()
