"""Batched Lie-core calls against a Python loop over gtsam's, side by side in one run.

    python benchmarks/bench_lie.py                    # 100,000 elements, gtsam loop over 10,000
    python benchmarks/bench_lie.py --n 20000 --gtsam-n 20000 --repeat 7

Times ``se3.exp``, ``se3.log``, ``se3.right_jacobian_inverse`` (and the SO(3) counterparts) on
``--n`` random tangents/poses (angles uniform in [0, π), translations ~ N(0, 3²)) in one batched
call each, against a Python loop calling ``gtsam.Pose3.Expmap`` / ``Logmap`` / ``LogmapDerivative``
(``Rot3`` likewise) on prebuilt inputs, and ``se2.exp``, ``se2.log``, ``se2.right_jacobian_inverse``
against ``Pose2`` (angles uniform in (−π, π)).  The gtsam loop runs over the first ``--gtsam-n`` inputs and
its time is scaled linearly to ``--n`` (a loop's cost is linear in its length; the table says when
it was scaled).  Both sides alternate over ``--repeat`` rounds so a slow spell of a shared machine
hits both; the table gives the best round of each (process CPU time) and the ratio.  Also times the Lie part of one
linearisation of a 9,048-edge graph (two ``between``, ``log``, ``right_jacobian_inverse``,
``inverse``, ``adjoint``).  Figures are recorded in docs/lie.md.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from posegraph.lie import se2, se3, so3  # noqa: E402


def _best(fn, rounds: list[float]) -> None:
    # CPU time of this process: both sides are single-threaded, and on a shared machine it is far
    # steadier than wall time (which also counts the time other jobs hold the cores).
    start = time.process_time()
    fn()
    rounds.append(time.process_time() - start)


def _inputs(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    w = axes * rng.uniform(0.0, np.pi, size=(n, 1))
    return np.concatenate([w, 3.0 * rng.normal(size=(n, 3))], axis=1)


def _se2_cases(n: int, gtsam_n: int) -> list[tuple]:
    """``se2`` against ``Pose2``: angles uniform in (−π, π), translations ~ N(0, 3²)."""
    import gtsam

    rng = np.random.default_rng(4)
    xi = np.c_[3.0 * rng.normal(size=(n, 2)), rng.uniform(-np.pi, np.pi, n)]
    T = se2.exp(xi)
    sub = xi[:gtsam_n]
    poses = [gtsam.Pose2(*x) for x in se2.to_xytheta(T[:gtsam_n])]
    return [
        ("se2.exp", lambda: se2.exp(xi), lambda: [gtsam.Pose2.Expmap(x) for x in sub], "Pose2.Expmap"),
        ("se2.log", lambda: se2.log(T), lambda: [gtsam.Pose2.Logmap(p) for p in poses], "Pose2.Logmap"),
        (
            "se2.right_jacobian_inverse",
            lambda: se2.right_jacobian_inverse(xi),
            lambda: [gtsam.Pose2.LogmapDerivative(x) for x in sub],
            "Pose2.LogmapDerivative",
        ),
    ]


def run(n: int, gtsam_n: int, repeat: int) -> list[dict]:
    import gtsam

    xi = _inputs(n)
    T = se3.exp(xi)
    R = T[:, :3, :3].copy()
    sub = xi[:gtsam_n]
    poses = [gtsam.Pose3(m) for m in T[:gtsam_n]]
    rots = [gtsam.Rot3(m) for m in R[:gtsam_n]]
    cases = [
        ("se3.exp", lambda: se3.exp(xi), lambda: [gtsam.Pose3.Expmap(x) for x in sub], "Pose3.Expmap"),
        ("se3.log", lambda: se3.log(T), lambda: [gtsam.Pose3.Logmap(p) for p in poses], "Pose3.Logmap"),
        (
            "se3.right_jacobian_inverse",
            lambda: se3.right_jacobian_inverse(xi),
            lambda: [gtsam.Pose3.LogmapDerivative(x) for x in sub],
            "Pose3.LogmapDerivative",
        ),
        ("se3.right_jacobian", lambda: se3.right_jacobian(xi), lambda: [gtsam.Pose3.ExpmapDerivative(x) for x in sub], "Pose3.ExpmapDerivative"),
        ("so3.exp", lambda: so3.exp(xi[:, :3]), lambda: [gtsam.Rot3.Expmap(x[:3]) for x in sub], "Rot3.Expmap"),
        ("so3.log", lambda: so3.log(R), lambda: [gtsam.Rot3.Logmap(r) for r in rots], "Rot3.Logmap"),
        (
            "so3.right_jacobian_inverse",
            lambda: so3.right_jacobian_inverse(xi[:, :3]),
            lambda: [gtsam.Rot3.LogmapDerivative(x[:3]) for x in sub],
            "Rot3.LogmapDerivative",
        ),
    ] + _se2_cases(n, gtsam_n)
    rows = []
    for name, ours, theirs, gtsam_name in cases:
        ours()  # warm-up (imports, first allocations)
        theirs()
        t_ours: list[float] = []
        t_theirs: list[float] = []
        for r in range(repeat):
            order = [(ours, t_ours), (theirs, t_theirs)]
            for fn, sink in order if r % 2 == 0 else order[::-1]:
                _best(fn, sink)
        best_ours = min(t_ours)
        best_theirs = min(t_theirs) * n / gtsam_n
        rows.append(
            dict(name=name, gtsam=gtsam_name, ours=best_ours, theirs=best_theirs, ratio=best_theirs / best_ours, scaled=gtsam_n != n)
        )
    return rows


def linearisation_lie_part(m: int = 9048, repeat: int = 20) -> float:
    """Best time of the Lie calls one linearisation of ``m`` edges makes (residuals and both blocks)."""
    rng = np.random.default_rng(1)
    Z = se3.exp(_inputs(m, 2) * 0.1)
    Xi = se3.exp(_inputs(m, 3))
    Xj = se3.compose(Xi, se3.compose(Z, se3.exp(0.01 * rng.normal(size=(m, 6)))))

    def step():
        relative = se3.between(Xi, Xj)
        e = se3.log(se3.between(Z, relative))
        se3.right_jacobian_inverse(e)
        se3.adjoint(se3.inverse(relative))

    step()
    times: list[float] = []
    for _ in range(repeat):
        _best(step, times)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000, help="elements per batched call (default 100000)")
    parser.add_argument("--gtsam-n", type=int, default=10_000, help="length of the gtsam loop, scaled to --n (default 10000)")
    parser.add_argument("--repeat", type=int, default=5, help="rounds per case (default 5)")
    args = parser.parse_args(argv)
    if args.n < 1 or not 1 <= args.gtsam_n <= args.n or args.repeat < 1:
        parser.error("need n >= 1, 1 <= gtsam-n <= n and repeat >= 1")
    try:
        import gtsam  # noqa: F401
    except ImportError:
        parser.error("gtsam is not installed (pip install 'posegraph[gtsam]')")
    rows = run(args.n, args.gtsam_n, args.repeat)
    print(f"# Lie core, {args.n:,} elements per call ({platform.processor() or platform.machine()}, numpy {np.__version__})")
    scaled = f"; gtsam loop over {args.gtsam_n:,}, scaled ×{args.n / args.gtsam_n:g}" if args.gtsam_n != args.n else ""
    print(f"best of {args.repeat} rounds, process CPU time{scaled}\n")
    print("| ours (one batched call) | gtsam (Python loop) | ours | gtsam | gtsam / ours |")
    print("|---|---|---:|---:|---:|")
    for row in rows:
        print(
            f"| `{row['name']}` | `{row['gtsam']}` | {row['ours'] * 1e3:.1f} ms | {row['theirs'] * 1e3:.0f} ms | {row['ratio']:.0f}× |"
        )
    t = linearisation_lie_part()
    print(f"\nLie part of one linearisation, 9,048 edges (2 between, log, Jr⁻¹, inverse, adjoint): {t * 1e3:.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
