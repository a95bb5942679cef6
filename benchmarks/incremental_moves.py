"""How much of the graph a solved incremental update moves: ``python -m benchmarks.incremental_moves intel:800``.

For every update that ran Gauss-Newton on the whole graph (kind ``whole``), the share of the poses already
in whose move ``‖Log(X_before⁻¹ X_after)‖`` is below a fraction of the update's largest move; printed per
fraction as the mean and median share over the updates. A small share means per-step work on the moved
part alone would not pay (docs/incremental.md, *ISAM2 at the same accuracy*). Graphs as
:func:`benchmarks.bench_incremental.load` names them (``NAME:N`` for a prefix).
"""

from __future__ import annotations

import sys

import numpy as np

FRACTIONS = (1e-4, 1e-6, 1e-8)


def still_shares(graph) -> dict:
    """``{fraction: (u,) share of poses moved by less than fraction·max}`` over the ``whole`` updates."""
    from posegraph.incremental import IncrementalOptimizer
    from posegraph.incremental.replay import _stage, replay_batches

    opt = IncrementalOptimizer(graph.group)
    shares = {f: [] for f in FRACTIONS}
    for parts in replay_batches(graph, 1):
        before = opt.poses if opt.num_vertices else None
        _stage(opt, graph, *parts)
        if opt.update().kind != "whole" or before is None:
            continue
        moved = np.linalg.norm(graph.group.log(np.linalg.inv(before) @ opt.poses[: before.shape[0]]), axis=-1)
        for fraction in FRACTIONS:
            shares[fraction].append(float(np.mean(moved < fraction * max(moved.max(), 1e-300))))
    return {f: np.asarray(v) for f, v in shares.items()}


def main(argv=None) -> int:
    from benchmarks.bench_incremental import load

    for name in (sys.argv[1:] if argv is None else argv) or ["intel:800"]:
        for fraction, share in still_shares(load(name)).items():
            print(f"{name}: moved < {fraction:g}·max: mean share {share.mean():.3f}, median {np.median(share):.3f}, "
                  f"over {share.size} whole updates")
    return 0


if __name__ == "__main__":
    sys.exit(main())
