"""Landmark measurements left out of the held analysis (``HeldPoints.max_left_out``) side by side.

    python -m benchmarks.bench_left_out_sightings /work/data-landmarks/victoriaPark-full.g2o.gz --bounds 0,8,16
    python -m benchmarks.bench_left_out_sightings gtsam:victoria_park.txt --poses 3000 --rounds 2 --main /work/main

A measurement whose pose–point block is outside the held pattern (a landmark seen again after a gap) is
a low-rank term of the held factor, up to the bound, instead of a new analysis
(:mod:`posegraph.incremental.held_points`); bound 0 makes every such measurement re-analyse. Each variant
replays the file one pose per update (:func:`posegraph.incremental.replay.replay`) in a process of its own
(``OPENBLAS_NUM_THREADS=1``, as the command line sets), the variants alternating within each round. Per
run: the replay's CPU seconds (``time.process_time``, the checks' batch solves excluded), the analyses,
the numeric factorisations, the measurements left out, the final cost and the largest excess over the
prefix's batch optimum at every ``--check-every``-th pose and at the end
(:func:`benchmarks.bench_incremental_landmarks.landmark_excess`). ``FILE``: as
:mod:`benchmarks.bench_incremental_landmarks` reads it (``gtsam:NAME``: gtsam's reading of its bundled
file); ``--poses N``: its first ``N`` poses (``landmark_prefix``); ``--main PATH``: another checkout's code
as one more variant (its ``posegraph`` and ``benchmarks`` on ``PYTHONPATH``, this script run by path).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

from benchmarks.bench_incremental_landmarks import ROOT, landmark_excess, landmark_prefix, load


def run(name: str, poses: int, bound: int, check_every: int) -> dict:
    """One replay of ``name`` (its first ``poses``, 0: all) with ``max_left_out = bound``."""
    from posegraph.incremental.held_points import HeldPoints
    from posegraph.incremental.replay import replay, replay_batches

    HeldPoints.max_left_out = bound  # a worker process of its own: the class default is not restored
    graph = load(name)
    if poses:
        graph = landmark_prefix(graph, list(replay_batches(graph, 1)), poses)[0]
    total, excess, checking = graph.num_vertices, [], [0.0]

    def check(result, number):
        if number % check_every == 0 or number == total:
            start = time.process_time()
            opt = result.optimizer
            excess.append(landmark_excess(opt.graph(), opt.poses, opt.landmark_positions)[1])
            checking[0] += time.process_time() - start

    start = time.process_time()
    result = replay(graph, 1, progress=check)
    whole = result.optimizer._whole
    return {"bound": bound, "cpu": time.process_time() - start - checking[0], "analyses": whole.analyses,
            "factorizations": whole.factorizations, "left_out": getattr(whole.points, "left_out_taken", 0),
            "final_cost": result.optimizer.cost(), "excess_max": max(excess), "excess_end": excess[-1],
            "kinds": {k: result.kinds.count(k) for k in sorted(set(result.kinds))}}


def spawn(name: str, poses: int, bound: int, check_every: int, code: str | None = None) -> dict:
    """One worker process; ``code``: a checkout whose ``posegraph`` and ``benchmarks`` it runs (``PYTHONPATH``)
    instead of this one's (another branch side by side; ``bound`` is then set but may mean nothing there)."""
    argv = [sys.executable, __file__, name, "--poses", str(poses), "--check-every", str(check_every), "--worker", str(bound)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": code or str(ROOT)}
    done = subprocess.run(argv, cwd=code or ROOT, env=env, capture_output=True, text=True, check=True)
    return {**json.loads(done.stdout.strip().splitlines()[-1]), "code": code or "this"}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", help="landmark file (gtsam:NAME: gtsam's bundled data)")
    parser.add_argument("--poses", type=int, default=0, help="replay the first N poses only (0: all)")
    parser.add_argument("--bounds", default="0,8", help="comma-separated max_left_out values")
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--check-every", type=int, default=500)
    parser.add_argument("--json", metavar="PATH")
    parser.add_argument("--main", metavar="PATH", help="also run the code of this checkout (e.g. /work/main) as a variant")
    parser.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker is not None:
        print(json.dumps(run(args.file, args.poses, args.worker, args.check_every)))
        return 0
    variants = [(None, int(b)) for b in args.bounds.split(",")] + ([(args.main, 0)] if args.main else [])
    rows = []
    for round_ in range(args.rounds):
        for code, bound in variants if round_ % 2 == 0 else variants[::-1]:
            rows.append(spawn(args.file, args.poses, bound, args.check_every, code))
            r = rows[-1]
            print(f"{code or 'bound ' + str(bound):>10}: cpu {r['cpu']:7.1f} s  analyses {r['analyses']:4d}  factorizations "
                  f"{r['factorizations']:4d}  left out {r['left_out']:5d}  final cost {r['final_cost']:.10f}  "
                  f"excess max {r['excess_max']:.1e} end {r['excess_end']:.1e}  {r['kinds']}", flush=True)
    if args.json:
        from pathlib import Path

        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
