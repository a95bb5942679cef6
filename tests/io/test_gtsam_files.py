"""Files crossing the gtsam seam: gtsam.writeG2o's output read by us (plain and gzip), ours read by gtsam.readG2o."""

from __future__ import annotations

import gzip
import warnings

import numpy as np
import pytest

from posegraph.errors import InputWarning
from posegraph.io.g2o import read_g2o, write_g2o

gtsam = pytest.importorskip("gtsam", reason="gtsam not installed")


def test_gtsam_written_file_reads_plain_and_gzipped(tmp_path, shared_dataset):
    """gtsam.writeG2o writes 6 significant digits (C++'s default stream precision): the graph
    read back is the original to that precision, without warnings, and its gzip reads the same."""
    source = shared_dataset("smallGrid3D")
    factors, values = gtsam.readG2o(str(source), True)
    written = tmp_path / "gtsam.g2o"
    gtsam.writeG2o(factors, values, str(written))
    packed = tmp_path / "gtsam.g2o.gz"
    packed.write_bytes(gzip.compress(written.read_bytes()))
    original = read_g2o(source)
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputWarning)
        plain, compressed = read_g2o(written), read_g2o(packed)
    for graph in (plain, compressed):
        np.testing.assert_array_equal(graph.edge_from, original.edge_from)
        np.testing.assert_array_equal(graph.edge_to, original.edge_to)
        np.testing.assert_array_equal(graph.information, original.information)
        np.testing.assert_allclose(graph.poses, original.poses, atol=1e-5)
    np.testing.assert_array_equal(compressed.poses, plain.poses)
    assert np.abs(plain.poses - original.poses).max() > 1e-7  # the 6 digits are visible: the check can fail


def test_gtsam_reads_our_file_to_the_last_digit(tmp_path, shared_dataset):
    source = shared_dataset("smallGrid3D")
    ours = tmp_path / "ours.g2o"
    write_g2o(ours, read_g2o(source))
    theirs_factors, theirs_values = gtsam.readG2o(str(source), True)
    factors, values = gtsam.readG2o(str(ours), True)
    assert factors.size() == theirs_factors.size() and values.size() == theirs_values.size()
    for key in theirs_values.keys():
        np.testing.assert_allclose(values.atPose3(key).matrix(), theirs_values.atPose3(key).matrix(), atol=1e-15)
    assert factors.error(theirs_values) == pytest.approx(theirs_factors.error(theirs_values), rel=1e-15)
