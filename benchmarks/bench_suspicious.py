"""The broken-map check (:func:`posegraph.analysis.suspicious.suspicious_edges`) on clean and corrupted graphs.

    python -m benchmarks.bench_suspicious                 # every case, a Markdown table on stdout
    python -m benchmarks.bench_suspicious --only intel    # the cases whose name holds "intel"

Each case is optimised by least squares (``posegraph.solve.optimize``, chordal start, defaults), then
judged. Clean cases: every file of ``../shared/datasets`` (cubicle with its information repaired, as
``--repair-information`` reads it), the bundled ``datasets/example_sphere.g2o`` and it with Ω ×0.01 and
×100, and the generator's shapes (``datasets.synthetic``: sphere, grid, manhattan, torus, garage, half their
loop closures, seed 1), sphere and manhattan again at ×100. Corrupted: the generator's shapes with 5, 10
and 20 % look-alike wrong loop closures (``NoiseParams.outlier_fraction``), and intel, manhattan,
sphere2500 and smallGrid3D with 5 and 20 % random wrong loop closures (``inject_outliers``, seed 1;
measurement translations anywhere in the graph, or within 3 m), and intel with 15 wrong loop closures
within 3 m (seeds 0–2).

Columns: the wrong-closure fraction (of the loop closures), whether the map is judged broken (the
command's warning), the agreement gain, the edges named, the precision and recall of the named edges
against the wrong ones, and the seconds of the least-squares solve and of the check.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "datasets"
SHARED_FILES = ("tinyGrid3D", "smallGrid3D", "sphere2500", "torus3D", "parking-garage", "cubicle",
                "sphere_bignoise_vertex3", "intel", "manhattan")
SHAPES = (("sphere", 400), ("grid", 1000), ("manhattan", 1000), ("torus", 1000), ("garage", 1000))
INJECTED = ("intel", "manhattan", "sphere2500", "smallGrid3D")


def _scaled(graph, factor: float):
    return dataclasses.replace(graph, information=graph.information * factor)


def _mask(m: int, indices) -> np.ndarray:
    wrong = np.zeros(m, bool)
    wrong[np.asarray(indices, dtype=np.int64)] = True
    return wrong


def _clean_cases():
    """``(name, fraction, graph, wrong mask or None)`` of the clean graphs."""
    from posegraph.io.g2o import read_g2o

    for name in SHARED_FILES:
        if (SHARED / f"{name}.g2o").is_file():
            yield name, 0.0, read_g2o(SHARED / f"{name}.g2o", repair_information=name == "cubicle"), None
    example = read_g2o(ROOT / "datasets" / "example_sphere.g2o")
    yield "example_sphere", 0.0, example, None
    yield "example_sphere Ω×0.01", 0.0, _scaled(example, 0.01), None
    yield "example_sphere Ω×100", 0.0, _scaled(example, 100.0), None


def _synthetic_cases():
    from datasets.synthetic import NoiseParams, generate

    for shape, size in SHAPES:
        for fraction in (0.0, 0.05, 0.1, 0.2):
            data = generate(shape, size, noise=NoiseParams(loop_closure_density=0.5, outlier_fraction=fraction), seed=1)
            yield f"synthetic {shape}", fraction, data.graph, data.outliers
            if fraction == 0.0 and shape in ("sphere", "manhattan"):
                yield f"synthetic {shape} Ω×100", 0.0, _scaled(data.graph, 100.0), None


def _injected_cases():
    from datasets.synthetic import inject_outliers
    from posegraph.io.g2o import read_g2o

    for name in INJECTED:
        if not (SHARED / f"{name}.g2o").is_file():
            continue
        graph = read_g2o(SHARED / f"{name}.g2o")
        loops = int(np.count_nonzero(~graph.odometry_mask()))
        for fraction in (0.05, 0.2):
            for reach in (None, 3.0):
                corrupted, wrong = inject_outliers(graph, fraction=fraction, seed=1, translation_range=reach)
                label = f"{name} + random" + ("" if reach is None else " within 3 m")
                yield label, len(wrong) / loops, corrupted, _mask(corrupted.num_edges, wrong)
        if name == "intel":
            for seed in range(3):
                corrupted, wrong = inject_outliers(graph, count=15, seed=seed, translation_range=3.0)
                yield f"intel + 15 within 3 m (seed {seed})", 15 / loops, corrupted, _mask(corrupted.num_edges, wrong)


def judge(graph, wrong) -> dict:
    """Least squares, then the check: the table's cells of one case."""
    from posegraph.analysis.suspicious import suspicious_edges
    from posegraph.solve import optimize

    start = time.perf_counter()
    result = optimize(graph)
    solved = time.perf_counter()
    verdict = suspicious_edges(graph, result.poses)
    checked = time.perf_counter()
    named = verdict.edges if verdict.broken else np.zeros(0, np.int64)
    hits = int(np.count_nonzero(wrong[named])) if wrong is not None else 0
    total = int(np.count_nonzero(wrong)) if wrong is not None else 0
    return {"broken": verdict.broken, "gain": verdict.gain, "named": len(named),
            "precision": hits / len(named) if len(named) and total else float("nan"),
            "recall": hits / total if total else float("nan"),
            "seconds_solve": solved - start, "seconds_check": checked - solved}


def _row(name: str, fraction: float, cells: dict) -> str:
    def number(x: float) -> str:
        return "–" if x != x else f"{x:.2f}"

    return (f"| {name} | {100 * fraction:.1f} % | {'**yes**' if cells['broken'] else 'no'} | {cells['gain']:.3g} | "
            f"{cells['named']} | {number(cells['precision'])} | {number(cells['recall'])} | "
            f"{cells['seconds_solve']:.2f} | {cells['seconds_check']:.2f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_suspicious", description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", metavar="TEXT", help="keep only the cases whose name holds one of these")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")  # the readers' notes on the shared files (cubicle's repairs, manhattan's vertices)
    print("| graph | wrong closures | warned | agreement gain | edges named | precision | recall | LS s | check s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for cases in (_clean_cases, _synthetic_cases, _injected_cases):
        for name, fraction, graph, wrong in cases():
            if args.only and not any(text in name for text in args.only):
                continue
            print(_row(name, fraction, judge(graph, wrong)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
