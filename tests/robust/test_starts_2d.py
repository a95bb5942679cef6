"""The robust starts on a planar (SE(2)) graph: the same code, χ² thresholds of a 3-dimensional residual."""

from __future__ import annotations

import numpy as np
import pytest

from datasets.synthetic import NoiseParams, generate
from posegraph.robust.starts import robust_chordal_start


@pytest.mark.parametrize("seed", [1, 2])
def test_robust_chordal_start_rejects_planar_outliers_and_keeps_the_inliers(seed):
    dataset = generate("manhattan", 500, noise=NoiseParams(outlier_fraction=0.2), seed=seed)
    assert dataset.graph.group.dim == 3 and dataset.outliers.sum() > 50
    result = robust_chordal_start(dataset.graph)
    inlier_loops = ~dataset.odometry & ~dataset.outliers
    assert np.all(result.weights[dataset.outliers] < 0.5)  # measured: every one at 0
    assert np.mean(result.weights[inlier_loops] > 0.5) > 0.95  # measured: 98 %
    assert result.poses.shape == (dataset.graph.num_vertices, 3, 3)
