"""What a Rerun recording costs: ``python -m benchmarks.bench_rerun [--rounds R]`` (``docs/rerun.md``).

Two cases, sphere2500 ``optimize`` and intel ``replay``, each measured side by side in one run,
alternating without and with the recording, medians of ``R`` rounds:

* ``process``: the whole command (``python cli.py …``) without and with ``--rerun OUT.rrd``, and the
  ``.rrd``'s size;
* ``in process``: the run's work (``posegraph.solve.optimize`` and ``analysis.rerun_log.log_result``;
  ``incremental.replay`` with its ``ReplayRecorder``) with Rerun already imported, without and with the
  logging and the final flush: what logging adds beyond the fixed cost of importing Rerun;
* ``import``: ``import rerun`` and its first conversion (which imports pandas where it is installed)
  in a fresh process.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATASETS = ROOT.parent / "shared" / "datasets"
CASES = {"optimize": ("sphere2500.g2o", []), "replay": ("intel.g2o", [])}


def _process_seconds(argv: list) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, str(ROOT / "cli.py"), *argv], check=True, capture_output=True)
    return time.perf_counter() - start


def process_case(command: str, rounds: int, folder: str) -> dict:
    """Whole-command seconds without and with ``--rerun`` (alternating), and the recording's bytes."""
    name, extra = CASES[command]
    base = [command, str(DATASETS / name), "-o", os.path.join(folder, "out.g2o"), "-q", *extra]
    rrd = os.path.join(folder, f"{command}.rrd")
    plain, recorded = [], []
    for _ in range(rounds):
        plain.append(_process_seconds(base))
        recorded.append(_process_seconds(base + ["--rerun", rrd]))
    return {"without": statistics.median(plain), "with": statistics.median(recorded), "bytes": os.path.getsize(rrd)}


def import_seconds(rounds: int) -> float:
    """``import rerun`` plus its first line-strip conversion, in a fresh process (numpy imported before)."""
    code = ("import time, numpy as np; t = time.perf_counter(); import rerun as rr; "
            "rr.LineStrips3D(np.zeros((1, 2, 3), np.float32)); print(time.perf_counter() - t)")
    return statistics.median(float(subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                                                  text=True).stdout) for _ in range(rounds))


def _optimize_once(graph, record: bool, folder: str) -> float:
    import rerun as rr

    from posegraph.analysis.rerun_log import IterationRecorder, log_result
    from posegraph.solve import SolverParams, optimize

    start = time.perf_counter()
    if not record:
        optimize(graph)
        return time.perf_counter() - start
    rec = rr.RecordingStream("bench", recording_id=os.urandom(8).hex())
    rec.set_sinks(rr.FileSink(os.path.join(folder, "in-process.rrd")))
    recorder = IterationRecorder(rec, graph)
    result = optimize(graph, params=SolverParams(estimate_callback=recorder))
    recorder.finish(result.poses, result.points)
    log_result(rec, graph, result)
    rec.flush()
    rec.disconnect()
    return time.perf_counter() - start


def _replay_once(graph, record: bool, folder: str) -> float:
    import rerun as rr

    from posegraph.incremental.replay import replay, time_statistics
    from posegraph.incremental.rerun_replay import ReplayRecorder

    start = time.perf_counter()
    if not record:
        replay(graph)
        return time.perf_counter() - start
    rec = rr.RecordingStream("bench", recording_id=os.urandom(8).hex())
    rec.set_sinks(rr.FileSink(os.path.join(folder, "in-process.rrd")))
    recorder = ReplayRecorder(rec, graph)
    result = replay(graph, progress=recorder)
    cost = result.optimizer.cost()
    recorder.finish(result, (cost, cost, 0.0), time_statistics(result.seconds))
    rec.flush()
    rec.disconnect()
    return time.perf_counter() - start


def in_process_case(command: str, rounds: int, folder: str) -> dict:
    """The run's seconds without and with logging (Rerun imported and warmed up first), alternating."""
    import numpy as np
    import rerun as rr

    from posegraph.io.g2o import read_g2o

    rr.LineStrips3D(np.zeros((1, 2, 3), np.float32))  # the first conversion's imports, outside the timing
    graph = read_g2o(DATASETS / CASES[command][0])
    once = _optimize_once if command == "optimize" else _replay_once
    once(graph, True, folder)  # warm-up
    plain, recorded = [], []
    for _ in range(rounds):
        plain.append(once(graph, False, folder))
        recorded.append(once(graph, True, folder))
    return {"without": statistics.median(plain), "with": statistics.median(recorded)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        print(f"import rerun + first conversion: {import_seconds(args.rounds):.3f} s")
        for command in CASES:
            p = process_case(command, args.rounds, folder)
            print(f"{command} {CASES[command][0]} process: {p['without']:.3f} s -> {p['with']:.3f} s "
                  f"({p['with'] / p['without']:.2f}x), recording {p['bytes'] / 1e6:.2f} MB")
            q = in_process_case(command, args.rounds, folder)
            print(f"{command} {CASES[command][0]} in process: {q['without']:.3f} s -> {q['with']:.3f} s "
                  f"(+{100 * (q['with'] / q['without'] - 1):.1f} %)")


if __name__ == "__main__":
    main()
