"""``python -m benchmarks.bench_batch``: ``posegraph batch`` on a local Dask cluster against a shell loop
of ``posegraph optimize``, one file at a time, over the same graphs; rounds alternate the two.

Both write each file's result and report; the loop is ``for f in FILES; do posegraph optimize "$f"
-o loop/NAME.g2o --report loop/NAME.report.json OPTIONS; done`` in bash, the batch ``posegraph
batch FILES -o batch/ --workers N --force OPTIONS`` (``--force``: every round redoes every file).
Wall seconds of the whole command each; after each round every result of the batch must equal
the loop's byte for byte (a mismatch stops the run). Prints one JSON object: per round the two
times, their medians and the ratio batch / loop.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "datasets"
GRAPHS = ("tinyGrid3D", "smallGrid3D", "cubicle", "parking-garage", "sphere2500", "torus3D",
          "sphere_bignoise_vertex3", "intel", "manhattan")
OPTIONS = ["--repair-information"]  # cubicle holds information matrices that are not PSD


def _timed(argv: list, check_status=(0,)) -> float:
    start = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode not in check_status:
        raise SystemExit(f"{shlex.join(argv)} exited {proc.returncode}: {proc.stderr[-2000:]}")
    return seconds


def _loop_command(files: list, folder: Path) -> list:
    cli = shlex.quote(str(ROOT / "cli.py"))
    body = "; ".join(
        f"{shlex.quote(sys.executable)} {cli} optimize {shlex.quote(str(f))} -o {shlex.quote(str(folder / (f.stem + '.g2o')))}"
        f" --report {shlex.quote(str(folder / (f.stem + '.report.json')))} {shlex.join(OPTIONS)} --quiet || exit 1"
        for f in files)
    return ["bash", "-c", body]


def _compare(files: list, loop: Path, batch: Path) -> None:
    for f in files:
        if (loop / (f.stem + ".g2o")).read_bytes() != (batch / (f.stem + ".g2o")).read_bytes():
            raise SystemExit(f"{f.stem}: the batch's result differs from optimize's")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_batch", description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--graphs", nargs="+", default=list(GRAPHS))
    args = parser.parse_args(argv)
    files = [SHARED / f"{name}.g2o" for name in args.graphs]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise SystemExit(f"absent: {', '.join(missing)}")
    rounds = []
    with tempfile.TemporaryDirectory() as tmp:
        loop, batch = Path(tmp) / "loop", Path(tmp) / "batch"
        loop.mkdir()
        batch_argv = [sys.executable, str(ROOT / "cli.py"), "batch", *map(str, files), "-o", str(batch),
                      "--workers", str(args.workers), "--force", *OPTIONS, "--quiet"]
        for k in range(args.rounds):
            order = [("loop", _loop_command(files, loop)), ("batch", batch_argv)]
            times = dict((name, _timed(command)) for name, command in (order if k % 2 == 0 else order[::-1]))
            _compare(files, loop, batch)
            rounds.append(times)
            print(json.dumps(times), file=sys.stderr, flush=True)
    loop_median = statistics.median(r["loop"] for r in rounds)
    batch_median = statistics.median(r["batch"] for r in rounds)
    print(json.dumps({"graphs": args.graphs, "workers": args.workers, "rounds": rounds, "loop_median": loop_median,
                      "batch_median": batch_median, "ratio": batch_median / loop_median, "outputs_equal": True},
                     indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
