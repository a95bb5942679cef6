"""Which replay updates a Rerun recording logs (plain numpy: no Rerun needed)."""

from __future__ import annotations

import numpy as np

from posegraph.analysis.rerun_scene import BYTES_PER_POINT
from posegraph.incremental.rerun_replay import plan_frames, update_of_edges


def _bytes(poses_after, closures, chosen) -> int:
    return int((BYTES_PER_POINT * (poses_after + 2 * np.cumsum(closures)))[chosen].sum())


def test_every_loop_closure_update_and_the_last_are_logged_when_they_fit():
    poses_after = np.arange(1, 1001)
    closures = np.zeros(1000, np.int64)
    closures[[10, 400, 401, 777]] = 1
    chosen = plan_frames(poses_after, closures, budget=10**9, limit=100)
    assert chosen[[10, 400, 401, 777, 999]].all()
    assert 90 <= chosen.sum() <= 100  # the rest: every N-th odometry update within the frame limit


def test_a_10000_pose_replay_stays_within_the_budget_and_the_limit():
    rng = np.random.default_rng(0)
    poses_after = np.arange(1, 10_001)
    closures = (rng.random(10_000) < 0.3).astype(np.int64) * rng.integers(1, 4, 10_000)
    chosen = plan_frames(poses_after, closures, budget=60_000_000, limit=400)
    assert chosen[-1] and chosen.sum() <= 400
    assert _bytes(poses_after, closures, chosen) <= 60_000_000
    logged = np.flatnonzero(chosen & (closures > 0))
    assert len(logged) >= 150 and np.all(np.diff(logged) > 0)  # thinned evenly, still half the frames


def test_a_small_byte_budget_thins_the_loop_closure_updates():
    poses_after = np.arange(1, 2001)
    closures = np.ones(2000, np.int64)
    chosen = plan_frames(poses_after, closures, budget=2_000_000, limit=10**6)
    assert _bytes(poses_after, closures, chosen) <= 2_000_000 + BYTES_PER_POINT * 3 * 2000  # + the last frame
    assert 0 < chosen.sum() < 2000


def test_edges_enter_with_their_later_vertex_in_id_order():
    from posegraph.model.graph import PoseGraph

    ids = np.array([5, 1, 3, 2])  # file order is not id order
    graph = PoseGraph(ids=ids, poses=np.broadcast_to(np.eye(4), (4, 4, 4)).copy(), edge_from=np.array([1, 3, 0]),
                      edge_to=np.array([3, 2, 1]), measurements=np.broadcast_to(np.eye(4), (3, 4, 4)).copy(),
                      information=np.broadcast_to(np.eye(6), (3, 6, 6)).copy())
    rank, update = update_of_edges(graph, batch_size=2)
    assert rank.tolist() == [3, 0, 2, 1]
    assert update.tolist() == [1, 2, 2]  # ids 1-2 in update 1; 2-3 and 5-1 in update 2
