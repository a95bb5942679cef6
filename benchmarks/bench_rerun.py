"""What a Rerun recording costs: ``python -m benchmarks.bench_rerun [--rounds R]`` (``docs/rerun.md``).

Two cases, sphere2500 ``optimize`` and intel ``replay``, each measured side by side in one run,
alternating without and with the recording, medians of ``R`` rounds:

* ``process``: the whole command (``python cli.py …``) without and with ``--rerun OUT.rrd``, and the
  ``.rrd``'s size;
* ``in process``: the run (``posegraph.solve.optimize``; ``incremental.replay``) without logging, and the
  seconds spent in the logging calls of a run with it (``IterationRecorder``, ``log_result``, the
  blueprint; ``ReplayRecorder`` and its ``finish``) and the final flush, Rerun already imported: what
  logging adds beyond the fixed cost of importing Rerun;
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


class _Timed:
    """A hook that sums the seconds spent in ``hook``."""

    def __init__(self, hook) -> None:
        self.hook, self.seconds = hook, 0.0

    def __call__(self, *args) -> None:
        start = time.perf_counter()
        self.hook(*args)
        self.seconds += time.perf_counter() - start


def _stream(folder: str):
    import rerun as rr

    rec = rr.RecordingStream("bench", recording_id=os.urandom(8).hex())
    rec.set_sinks(rr.FileSink(os.path.join(folder, "in-process.rrd")))
    return rec


def _timed(run, record: bool, folder: str, recorder_of, finish) -> tuple[float, float]:
    """``(seconds of run(hook), seconds of the logging calls and the final flush)``: ``run(None)`` without
    logging; with it, ``run(recorder)`` for ``recorder_of(rec)``, then ``finish(rec, recorder, result)``."""
    if not record:
        start = time.perf_counter()
        run(None)
        return time.perf_counter() - start, 0.0
    rec = _stream(folder)
    recorder = _Timed(recorder_of(rec))
    start = time.perf_counter()
    result = run(recorder)
    done = time.perf_counter()
    finish(rec, recorder.hook, result)
    rec.flush()
    rec.disconnect()
    return done - start - recorder.seconds, recorder.seconds + time.perf_counter() - done


def _optimize_once(graph, record: bool, folder: str) -> tuple[float, float]:
    """``(seconds of the solve, seconds of the logging calls and the final flush)``."""
    from posegraph.analysis.rerun_log import IterationRecorder, log_result, optimize_blueprint
    from posegraph.solve import SolverParams, optimize

    def finish(rec, recorder, result):
        recorder.finish(result.poses, result.points)
        log_result(rec, graph, result)
        rec.send_blueprint(optimize_blueprint(graph, result.poses))

    return _timed(lambda hook: optimize(graph, params=SolverParams(estimate_callback=hook)), record, folder,
                  lambda rec: IterationRecorder(rec, graph), finish)


def _replay_once(graph, record: bool, folder: str) -> tuple[float, float]:
    """``(seconds of the replay, seconds of the logging calls and the final flush)``."""
    from posegraph.incremental.replay import replay, time_statistics
    from posegraph.incremental.rerun_replay import ReplayRecorder

    def finish(rec, recorder, result):
        cost = result.optimizer.cost()
        recorder.finish(result, (cost, cost, 0.0), time_statistics(result.seconds))

    return _timed(lambda hook: replay(graph, progress=hook), record, folder, lambda rec: ReplayRecorder(rec, graph), finish)


def in_process_case(command: str, rounds: int, folder: str) -> dict:
    """The run's seconds without logging, and the seconds of the logging calls of a run with it
    (Rerun imported and warmed up first), runs alternating."""
    import numpy as np
    import rerun as rr

    from posegraph.io.g2o import read_g2o

    rr.LineStrips3D(np.zeros((1, 2, 3), np.float32))  # the first conversion's imports, outside the timing
    graph = read_g2o(DATASETS / CASES[command][0])
    once = _optimize_once if command == "optimize" else _replay_once
    once(graph, True, folder)  # warm-up
    plain, logging = [], []
    for _ in range(rounds):
        plain.append(once(graph, False, folder)[0])
        logging.append(once(graph, True, folder)[1])
    return {"run": statistics.median(plain), "logging": statistics.median(logging)}


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
            print(f"{command} {CASES[command][0]} in process: run {q['run']:.3f} s, logging {q['logging']:.3f} s "
                  f"(+{100 * q['logging'] / q['run']:.1f} %)")


if __name__ == "__main__":
    main()
