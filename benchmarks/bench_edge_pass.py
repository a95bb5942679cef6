"""The per-edge hot path's one-pass forms against the compositions they replace, at 50 to 20,000 edges.

    python benchmarks/bench_edge_pass.py              # SE(2) and SE(3), 50 / 2,512 / 20,000 edges
    python benchmarks/bench_edge_pass.py --edges 50 200 --rounds 9

For each group and edge count: ``edge_errors(Z, Xi, Xj)`` against ``between`` then ``log`` of
``between(Z, ·)``; ``adjoint_of_inverse(T)`` against ``adjoint(inverse(T))``; ``Ω e`` as an ``einsum``
against a batched ``@``. Inputs: random poses, measurements within 0.01 of the relative poses (the
small residuals of a solve), unit information. Each pair alternates over ``--rounds`` rounds; the
table gives the median µs per call (process CPU time) and the ratio. Figures: docs/incremental.md
(*Fixed cost per step*). The fused forms equal the compositions bit for bit (tests/lie/test_fused.py).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from posegraph.lie import se2, se3  # noqa: E402


def _median_us(fn, edges: int, rounds: int) -> float:
    """Median over ``rounds`` of the CPU µs per call of ``fn``, each round ~40,000 edge-calls long."""
    calls = max(10, 40_000 // edges)
    times = []
    fn()
    for _ in range(rounds):
        start = time.process_time()
        for _ in range(calls):
            fn()
        times.append((time.process_time() - start) / calls * 1e6)
    return float(np.median(times))


def _row(module, dim: int, edges: int, rounds: int, rng) -> list[tuple[str, float, float]]:
    """``(what, composed µs, one-pass µs)`` for the three pairs at ``edges`` edges."""
    xi, xj = module.exp(rng.normal(size=(edges, dim))), module.exp(rng.normal(size=(edges, dim)))
    z = module.between(xi, xj) @ module.exp(0.01 * rng.normal(size=(edges, dim)))
    relative = module.between(xi, xj)
    information = np.broadcast_to(np.eye(dim), (edges, dim, dim)).copy()
    residuals = 0.01 * rng.normal(size=(edges, dim))

    def composed():
        r = module.between(xi, xj)
        return r, module.log(module.between(z, r))

    pairs = [("edge_errors", composed, lambda: module.edge_errors(z, xi, xj)),
             ("adjoint_of_inverse", lambda: module.adjoint(module.inverse(relative)), lambda: module.adjoint_of_inverse(relative)),
             ("Ω e", lambda: information @ residuals[..., None], lambda: np.einsum("mij,mj->mi", information, residuals))]
    return [(what, _median_us(a, edges, rounds), _median_us(b, edges, rounds)) for what, a, b in pairs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--edges", type=int, nargs="+", default=[50, 2512, 20000])
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print("| group | edges | what | composed µs | one pass µs | ratio |")
    print("|---|---|---|---|---|---|")
    for name, module, dim in (("SE(2)", se2, 3), ("SE(3)", se3, 6)):
        for edges in args.edges:
            for what, composed, fused in _row(module, dim, edges, args.rounds, rng):
                print(f"| {name} | {edges:,} | {what} | {composed:.0f} | {fused:.0f} | {composed / fused:.2f}× |")


if __name__ == "__main__":
    main()
