"""read_g2o agrees with gtsam.readG2o(path, is3D=True): ids, poses, measurements, information.

For each ``BetweenFactorPose3`` f, gtsam's information is ``RᵀR`` with ``R = f.noiseModel().R()``
(a Gaussian, Diagonal or Isotropic model); ours is compared with it to 1e-9 relative. The cost for
the initial values is compared with gtsam by the solver's tests (posegraph/solve/residuals.py).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from posegraph.errors import G2oFormatError, GraphError, InputWarning
from posegraph.io.g2o import PSD_TOLERANCE, read_g2o

gtsam = pytest.importorskip("gtsam")

# 3D pose-graph files bundled with gtsam (gtsam/Data), some with landmark lines we skip.
GTSAM_EXAMPLES = [
    "pose3example.txt",
    "pose3example-grid.txt",
    "pose3example-offdiagonal.txt",
    "pose3Localizationexample.txt",
    "simpleGraph10gradIter.txt",
    "toyExample.g2o",
    "Klaus3.g2o",
    "known_landmark_localization_3.g2o",
]

# Shared datasets we refuse, with the line of the first bad information matrix.
REJECTED = {"cubicle.g2o": 5753}
# ... and how many of their information matrices are indefinite (the reader repairs as many).
REJECTED_COUNT = {"cubicle.g2o": 5021}


def compare_with_gtsam(path, repair=False):
    """Our graph of ``path`` against gtsam's. With ``repair`` (a file with indefinite information)
    the information matrices are compared where the file's are positive semi-definite, the only
    ones both sides take as written (gtsam replaces the others by RᵀR of a partial factor)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        graph = read_g2o(path, repair_information=repair, poses_only=True)  # the pose part is compared
    factors, values = gtsam.readG2o(str(path), True)

    # Vertices: the same ids, the same poses.
    pose_keys = [key for key in values.keys() if _is_pose3(values, key)]
    assert sorted(pose_keys) == sorted(graph.ids.tolist())
    expected = np.stack([values.atPose3(int(i)).matrix() for i in graph.ids])
    np.testing.assert_allclose(graph.poses, expected, rtol=1e-12, atol=1e-12)

    # Edges: the between factors, in file order.
    between = [factors.at(k) for k in range(factors.size()) if isinstance(factors.at(k), gtsam.BetweenFactorPose3)]
    assert len(between) == graph.num_edges
    keys = np.array([f.keys() for f in between], dtype=np.int64).reshape(-1, 2)
    np.testing.assert_array_equal(graph.ids[graph.edge_from], keys[:, 0])
    np.testing.assert_array_equal(graph.ids[graph.edge_to], keys[:, 1])
    measured = np.stack([f.measured().matrix() for f in between])
    np.testing.assert_allclose(graph.measurements, measured, rtol=1e-12, atol=1e-12)
    information = np.stack([_information(f) for f in between])
    as_written = _file_information_is_psd(path) if repair else np.ones(graph.num_edges, bool)
    scale = np.abs(information).max(axis=(1, 2), keepdims=True)[as_written]
    np.testing.assert_allclose(graph.information[as_written] / scale, information[as_written] / scale,
                               rtol=0, atol=1e-9)
    assert np.linalg.eigvalsh(graph.information[~as_written]).min(initial=1.0) > 0  # repaired: definite
    return graph


def _file_information_is_psd(path) -> np.ndarray:
    """``(m,)`` bool per ``EDGE_SE3:QUAT`` line: its 21 information entries (the last fields) make a
    positive semi-definite matrix, read from the text independently of our reader."""
    rows = [line.split()[-21:] for line in open(path) if line.startswith("EDGE_SE3:QUAT")]
    upper = np.array(rows, dtype=np.float64)
    rows_index, cols_index = np.triu_indices(6)
    matrices = np.zeros((len(upper), 6, 6))
    matrices[:, rows_index, cols_index] = upper
    matrices[:, cols_index, rows_index] = upper
    eigenvalues = np.linalg.eigvalsh(matrices)
    return eigenvalues[:, 0] >= -PSD_TOLERANCE * np.abs(eigenvalues).max(axis=1)


def _is_pose3(values, key):
    try:
        values.atPose3(key)
    except RuntimeError:
        return False
    return True


def _information(factor):
    r = factor.noiseModel().R()
    return r.T @ r


def test_shared_dataset_matches_gtsam(shared_g2o_file):
    # A file refused by default (test_rejected_dataset_has_indefinite_information) is read repaired.
    graph = compare_with_gtsam(shared_g2o_file, repair=shared_g2o_file.name in REJECTED)
    if shared_g2o_file.name in REJECTED:
        assert np.count_nonzero(~_file_information_is_psd(shared_g2o_file)) == REJECTED_COUNT[shared_g2o_file.name]
        assert graph.num_edges > REJECTED_COUNT[shared_g2o_file.name]


@pytest.mark.parametrize("name", GTSAM_EXAMPLES)
def test_gtsam_example_matches_gtsam(gtsam_example_file, name):
    compare_with_gtsam(gtsam_example_file(name))


@pytest.mark.parametrize("name", sorted(REJECTED))
def test_rejected_dataset_has_indefinite_information(shared_dataset, name):
    """cubicle.g2o holds indefinite information matrices: we refuse it; gtsam silently changes them.

    Eigen's LLT stops at the first non-positive pivot, so gtsam's noise model for such an edge is
    RᵀR of a partial factor, not the matrix in the file.
    """
    path = shared_dataset(name)
    line = REJECTED[name]
    with pytest.raises(G2oFormatError, match="not positive semi-definite") as info:
        read_g2o(path)
    assert info.value.line == line

    # An independent look at that line: its matrix (g2o order) has a clearly negative eigenvalue.
    text = path.read_text().split("\n")[line - 1].split()
    assert text[0] == "EDGE_SE3:QUAT"
    upper = np.array(text[10:31], dtype=float)
    matrix = np.zeros((6, 6))
    matrix[np.triu_indices(6)] = upper
    matrix = matrix + np.triu(matrix, 1).T
    eigenvalues = np.linalg.eigvalsh(matrix)
    assert eigenvalues[0] < -1e-3 * eigenvalues[-1]  # far beyond rounding (PSD_TOLERANCE is 1e-5)

    factors, _ = gtsam.readG2o(str(path), True)
    first_edge_line = 1 + next(k for k, row in enumerate(path.read_text().split("\n")) if row.startswith("EDGE"))
    factor = factors.at(line - first_edge_line)
    assert list(factor.keys()) == [int(text[1]), int(text[2])]
    permutation = [3, 4, 5, 0, 1, 2]
    assert not np.allclose(_information(factor), matrix[np.ix_(permutation, permutation)])


# gtsam's EDGE3 files (sphere2500.txt, with no vertex lines): see test_g2o_edge3.py.
