"""Prior lines as g2o itself writes them (g2opy, ``datasets/prior_graphs.py``): read back, and the
position priors' χ² equal to g2o's own (its error ``t(X) − z`` is ours; its pose priors' error is a
quaternion difference, not a Log, so those are checked against gtsam in ``tests/solve/test_unary.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.io.g2o import read_g2o
from posegraph.solve.unary import prior_errors, prior_squared_norms

g2o = pytest.importorskip("g2opy")


@pytest.mark.parametrize("name, planar", [("tinyGrid3D", False), ("intel", True)])
def test_position_prior_chi2_equals_g2o(shared_dataset, tmp_path, name, planar):
    from datasets.prior_graphs import add_2d_priors, add_3d_priors

    rng = np.random.default_rng(0)
    source = shared_dataset(name)
    optimizer = g2o.SparseOptimizer()
    assert optimizer.load(str(source))
    graph = read_g2o(source)
    poses = graph.poses @ graph.group.exp(rng.normal(scale=0.1, size=(graph.num_vertices, graph.group.dim)))
    (add_2d_priors if planar else add_3d_priors)(g2o, optimizer, graph.ids, poses, rng, every=(2, 3))
    path = tmp_path / "with-priors.g2o"
    assert optimizer.save(str(path))

    priors = read_g2o(path).priors
    assert priors.num_position == np.count_nonzero(graph.ids % 2 == 0)
    assert priors.num_pose == np.count_nonzero(graph.ids % 3 == 0)
    if not planar:
        assert set(priors.offsets) == {0, 1} and not np.allclose(priors.offsets[1], np.eye(4))
    kind = g2o.EdgeSE2XYPrior if planar else g2o.EdgeSE3XYZPrior
    reloaded = g2o.SparseOptimizer()  # g2o's reading of the text it wrote, as ours
    assert reloaded.load(str(path))
    theirs = {}
    for edge in reloaded.edges():
        if isinstance(edge, kind):
            edge.compute_error()
            theirs[edge.vertices()[0].id()] = edge.chi2()
    written = read_g2o(path)
    ours = prior_squared_norms(prior_errors(written.poses, written), priors)[priors.num_pose:]
    ids = written.ids[priors.position_vertex].tolist()
    assert sorted(theirs) == sorted(ids)
    np.testing.assert_allclose(ours, [theirs[i] for i in ids], rtol=1e-10, atol=1e-12)
    # the optimum of the graph as written reaches gtsam's best on the same factors (no vertex held)
    from posegraph.crosscheck.gtsam_bridge import graph_to_gtsam, poses_to_values
    from posegraph.init import initialize
    from posegraph.solve.optimizer import optimize

    gtsam = pytest.importorskip("gtsam")
    result = optimize(written, "chordal")
    factors, params = graph_to_gtsam(written), gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    best = min(
        factors.error(gtsam.LevenbergMarquardtOptimizer(factors, poses_to_values(written.ids, start), params).optimize())
        for start in (initialize(written, "chordal"), result.poses)
    )
    assert result.final_cost <= best * (1 + 1e-6)
    assert result.final_cost == pytest.approx(factors.error(poses_to_values(written.ids, result.poses)), rel=1e-12)
