"""The last step of the benchmarks' child processes (``g2opy_pipeline``, ``gtsam_landmarks``): their
report, with seconds per phase and the process's own seconds, written as JSON."""

from __future__ import annotations

import json
import time


def write_report(path: str, report: dict, seconds: dict, started: float) -> int:
    """``report`` with ``seconds`` (per phase) and ``in_process_seconds`` (since ``started``, a
    ``time.perf_counter()`` taken when the child's module was loaded) written to ``path``; returns 0."""
    report["seconds"] = seconds
    report["in_process_seconds"] = time.perf_counter() - started
    with open(path, "w") as stream:
        json.dump(report, stream, indent=1)
    return 0
