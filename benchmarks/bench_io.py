"""Reading and writing g2o files: posegraph against gtsam, side by side in one run.

    python benchmarks/bench_io.py                      # the shared benchmark files
    python benchmarks/bench_io.py --repeat 15 torus3D.g2o my.g2o   # shared names or paths

For each file the two readers (and writers) run alternately, ``--repeat`` times each, so that
both see the same machine load; the table gives the best and the median time of each and the
ratios posegraph / gtsam of the bests and of the medians (below 1: posegraph is faster). Figures
are recorded in docs/g2o.md.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

from posegraph.errors import InputWarning
from posegraph.io.g2o import read_g2o, write_g2o

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "datasets"
DEFAULT_FILES = ["torus3D.g2o", "cubicle.g2o", "sphere_bignoise_vertex3.g2o", "parking-garage.g2o", "sphere2500.g2o"]


def _read_quietly(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        return read_g2o(path)


def _time(function, *args):
    start = time.perf_counter()
    function(*args)
    return time.perf_counter() - start


def bench_file(path: Path, repeat: int, gtsam) -> list[tuple[str, list[float], list[float]]]:
    """Alternating timings ``(what, ours, gtsam's)`` for reading and writing ``path``."""
    rows = []
    ours, theirs = [], []
    for _ in range(repeat):
        ours.append(_time(_read_quietly, path))
        theirs.append(_time(gtsam.readG2o, str(path), True))
    rows.append(("read", ours, theirs))

    graph = _read_quietly(path)
    factors, values = gtsam.readG2o(str(path), True)
    with tempfile.TemporaryDirectory() as folder:
        ours_out = os.path.join(folder, "ours.g2o")
        theirs_out = os.path.join(folder, "gtsam.g2o")
        ours, theirs = [], []
        for _ in range(repeat):
            ours.append(_time(write_g2o, ours_out, graph))
            theirs.append(_time(gtsam.writeG2o, factors, values, theirs_out))
        rows.append(("write", ours, theirs))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="*", help=f"g2o files (default: {', '.join(DEFAULT_FILES)} from {SHARED})")
    parser.add_argument("--repeat", type=int, default=9, help="timed runs of each reader and writer per file")
    args = parser.parse_args(argv)
    try:
        import gtsam
    except ImportError:
        print("gtsam is not installed: nothing to compare with (pip install gtsam)", file=sys.stderr)
        return 1
    # A bare name that is not a file here is looked up in the shared folder ("torus3D.g2o").
    files = [Path(f) if Path(f).exists() else SHARED / f for f in args.files]
    files = files or [SHARED / name for name in DEFAULT_FILES if (SHARED / name).is_file()]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        print(f"no such file: {', '.join(missing)}", file=sys.stderr)
        return 1
    if not files:
        print(f"no files given and {SHARED} holds none of {DEFAULT_FILES}", file=sys.stderr)
        return 1

    version = importlib.metadata.version("gtsam")
    print(f"gtsam {version}; {args.repeat} alternating runs each; times in ms (best / median)")
    header = f"{'file':<30} {'MB':>5} {'op':<6} {'posegraph':>17} {'gtsam':>17} {'ratio best / median':>20}"
    print(header)
    print("-" * len(header))
    for path in files:
        size = path.stat().st_size / 1e6
        try:
            rows = bench_file(path, args.repeat, gtsam)
        except ValueError as err:  # e.g. a file posegraph refuses (cubicle.g2o: indefinite information)
            print(f"{path.name:<30} {size:5.2f} refused by posegraph: {str(err).splitlines()[0][:80]}")
            continue
        for what, ours, theirs in rows:
            best = min(ours) / min(theirs)
            median = statistics.median(ours) / statistics.median(theirs)
            print(
                f"{path.name:<30} {size:5.2f} {what:<6} "
                f"{1e3 * min(ours):7.1f} / {1e3 * statistics.median(ours):7.1f} "
                f"{1e3 * min(theirs):7.1f} / {1e3 * statistics.median(theirs):7.1f} {best:11.2f} / {median:6.2f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
