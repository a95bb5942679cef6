"""``python -m benchmarks``: posegraph and gtsam side by side on the same graphs (whole processes).

Default datasets: every 3D or 2D ``.g2o`` in ``../shared/datasets``, gtsam's bundled ``sphere2500.txt``
and ``pose3example.txt``, and the synthetic sets of :data:`benchmarks.harness.SYNTHETIC_SETS`.
``--datasets`` replaces them with the given files and folders (every 3D or 2D ``.g2o``/``.txt`` in a folder).
Writes ``benchmark_results.json`` and ``benchmark_results.md`` into ``--out`` and prints the summary.
``--landmarks`` adds the landmark files (issue 35): after the pose graphs, posegraph, g2opy and gtsam
on them (:mod:`benchmarks.bench_landmarks`, the same ``--repeats``, ``--only`` and ``--timeout``), written
to ``landmark_results.json``/``.md`` in ``--out``; ``--landmarks-only`` runs just those.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from benchmarks import harness


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", nargs="+", metavar="PATH", help="g2o files or folders to run instead of the default set")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="keep only datasets whose name contains one of these")
    parser.add_argument("--no-synthetic", action="store_true", help="default set without the synthetic graphs")
    parser.add_argument("--repeats", type=int, default=5, help="measured rounds per dataset (default 5)")
    parser.add_argument("--warmup", type=int, default=1, help="discarded rounds first (default 1)")
    parser.add_argument("--tools", nargs="+", choices=harness.TOOLS, default=list(harness.TOOLS), help="default: all")
    parser.add_argument("--timeout", type=float, default=900, help="seconds before one process is killed (default 900)")
    parser.add_argument("--startup-runs", type=int, default=10, help="runs of each start-up measurement (0: skip)")
    parser.add_argument("--out", default="docs", help="folder for benchmark_results.json/.md (default docs/)")
    parser.add_argument("--fresh-venv", metavar="DIR", default=None,
                        help="make a new virtual environment in DIR by the README's `pip install .` (plus gtsam) and run both tools from it")
    parser.add_argument("--synthetic-dir", default=None, help="where synthetic sets are generated (default: a temporary folder)")
    parser.add_argument("--landmarks", action="store_true",
                        help="also run the landmark files (posegraph, g2opy, gtsam; benchmarks.bench_landmarks)")
    parser.add_argument("--landmarks-only", action="store_true", help="only the landmark files")
    parser.add_argument("--landmark-data", default=None, metavar="DIR", help="folder of the landmark files (default /work/data-landmarks)")
    return parser


def landmark_argv(args) -> list[str]:
    """``benchmarks.bench_landmarks``'s command line for ``--landmarks``."""
    from benchmarks import bench_landmarks

    argv = ["--data", args.landmark_data or str(bench_landmarks.DATA_DIR), "--repeats", str(args.repeats),
            "--out", args.out, "--timeout", str(args.timeout)]  # fmt: skip
    return argv + (["--only", *args.only] if args.only else [])


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.warmup < 0:
        parser.error("--repeats must be >= 1 and --warmup >= 0")
    if args.landmarks_only:
        from benchmarks import bench_landmarks

        return bench_landmarks.main(landmark_argv(args))
    with tempfile.TemporaryDirectory(prefix="posegraph-synthetic-") as tmp:
        try:
            if args.datasets:
                datasets = harness.user_datasets(args.datasets)
            else:
                datasets = harness.shared_datasets() + harness.gtsam_datasets()
                if not args.no_synthetic:
                    datasets += harness.synthetic_datasets(Path(args.synthetic_dir or tmp))
        except FileNotFoundError as error:
            parser.error(str(error))
        if args.only:
            datasets = [d for d in datasets if any(word in d.name for word in args.only)]
        if not datasets:
            parser.error("no datasets to run")
        if args.fresh_venv:
            harness.use_environment(harness.fresh_environment(Path(args.fresh_venv)))
        result = harness.run_benchmark(
            datasets, tools=args.tools, repeats=args.repeats, warmup=args.warmup, timeout=args.timeout, startup_runs=args.startup_runs
        )
    json_path, md_path = harness.write_outputs(result, Path(args.out))
    print()
    print(harness.to_markdown(result))
    print(f"wrote {json_path} and {md_path}")
    if args.landmarks:
        from benchmarks import bench_landmarks

        return bench_landmarks.main(landmark_argv(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
