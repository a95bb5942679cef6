"""The figure of a replay: time per update and cost excess over the batch optimum against the number of poses."""

from __future__ import annotations

import numpy as np

__all__ = ["replay_figure"]


def replay_figure(path, result, title: str | None = None) -> None:
    """Draw ``result`` (:class:`~posegraph.incremental.replay.ReplayResult`) into ``path`` (needs matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    top.semilogy(result.poses_after, 1e3 * np.maximum(result.seconds, 1e-6), ".", markersize=2)
    top.set_ylabel("update time (ms)")
    if title:
        top.set_title(title)
    if result.checks:
        checks = np.array([(c[0], max(c[3], 1e-17)) for c in result.checks])
        bottom.semilogy(checks[:, 0], checks[:, 1], "o-", markersize=3)
        bottom.axhline(1e-6, color="r", linestyle="--", linewidth=1, label="1e-6")
        bottom.legend()
    bottom.set_ylabel("relative cost excess")
    bottom.set_xlabel("poses")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
