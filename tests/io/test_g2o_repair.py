"""``read_g2o(path, repair_information=True)``: information that is not PSD replaced by the nearest PD matrix.

By default such a matrix is refused (issue 3's rule; see test_g2o_errors and test_against_gtsam).
With the repair, each one becomes the nearest symmetric matrix in Frobenius norm whose eigenvalues
are at least ``REPAIR_EIGENVALUE_FLOOR`` times its largest. The checks here use another algorithm
for the nearest positive semi-definite matrix, Higham's ``(A + H) / 2`` with ``H`` the symmetric
polar factor of ``A`` (scipy.linalg.polar), and an independent parse of the file's numbers.
"""

from __future__ import annotations


import numpy as np
import pytest
from scipy.linalg import polar

from posegraph.errors import G2oFormatError
from tests.io.helpers import read_with_warnings
from posegraph.io.g2o import REPAIR_EIGENVALUE_FLOOR, read_g2o

CUBICLE_REFUSED_LINE = 5753
CUBICLE_INDEFINITE_EDGES = 5021
PERMUTATION = [3, 4, 5, 0, 1, 2]  # g2o's [t; R] to [ω; v]
UPPER_ROWS, UPPER_COLS = np.triu_indices(6)


def file_information(path):
    """The EDGE_SE3:QUAT information matrices of a file, in [ω; v] order, parsed without the project."""
    rows = [line.split() for line in path.read_text().splitlines() if line.startswith("EDGE_SE3:QUAT")]
    upper = np.array([row[10:31] for row in rows], dtype=float)
    matrices = np.zeros((len(rows), 6, 6))
    matrices[:, UPPER_ROWS, UPPER_COLS] = upper
    matrices[:, UPPER_COLS, UPPER_ROWS] = upper
    return matrices[:, PERMUTATION][:, :, PERMUTATION]


def nearest_psd(matrix):
    """Higham (1988): the nearest symmetric PSD matrix in Frobenius norm is (A + H) / 2, A = U H."""
    _, h = polar(matrix)
    return 0.5 * (matrix + h)


def test_cubicle_is_refused_by_default_with_a_pointer_to_the_repair(shared_dataset):
    with pytest.raises(G2oFormatError) as info:
        read_g2o(shared_dataset("cubicle"))
    assert info.value.line == CUBICLE_REFUSED_LINE
    assert "not positive semi-definite" in info.value.reason
    assert "--repair-information" in info.value.reason
    assert "nearest positive semi-definite matrix" in info.value.reason


def test_cubicle_repaired(shared_dataset):
    path = shared_dataset("cubicle")
    graph, messages = read_with_warnings(path, repair_information=True)
    original = file_information(path)
    assert graph.information.shape == original.shape == (16869, 6, 6)

    # One warning counts the repaired edges and names the first line.
    repair = [m for m in messages if "repaired" in m]
    assert len(repair) == 1, messages
    assert repair[0].startswith(f"{path}:{CUBICLE_REFUSED_LINE}: repaired {CUBICLE_INDEFINITE_EDGES} ")
    assert not any("singular" in m for m in messages)

    eigenvalues = np.linalg.eigvalsh(original)
    indefinite = eigenvalues[:, 0] < -1e-5 * np.abs(eigenvalues).max(axis=1)
    assert np.count_nonzero(indefinite) == CUBICLE_INDEFINITE_EDGES

    # Where the file's matrix was PSD, it is kept exactly.
    np.testing.assert_array_equal(graph.information[~indefinite], original[~indefinite])

    # Repaired: symmetric, positive definite with the documented floor.
    repaired = graph.information[indefinite]
    np.testing.assert_array_equal(repaired, np.swapaxes(repaired, -1, -2))
    np.linalg.cholesky(repaired)  # raises if any is not positive definite
    new_eigenvalues = np.linalg.eigvalsh(repaired)
    assert np.all(new_eigenvalues[:, 0] >= REPAIR_EIGENVALUE_FLOOR * new_eigenvalues[:, -1] * (1 - 1e-6))

    # And nearest: within the floor's reach of the nearest PSD matrix (Higham's polar formula).
    for k in np.flatnonzero(indefinite)[:: CUBICLE_INDEFINITE_EDGES // 300]:
        matrix = original[k]
        target = nearest_psd(matrix)
        largest = np.linalg.eigvalsh(matrix)[-1]
        distance = np.linalg.norm(graph.information[k] - target)
        assert distance <= np.sqrt(6) * REPAIR_EIGENVALUE_FLOOR * largest + 1e-12 * np.linalg.norm(matrix), k
        # Any PSD matrix is at least ‖negative eigenvalues‖ away (Hoffman–Wielandt); the repair is
        # no further than that plus the floor's reach.
        eigenvalues_k = np.linalg.eigvalsh(matrix)
        least = np.linalg.norm(eigenvalues_k[eigenvalues_k < 0])
        moved = np.linalg.norm(graph.information[k] - matrix)
        assert least * (1 - 1e-9) <= moved <= least + np.sqrt(6) * REPAIR_EIGENVALUE_FLOOR * largest * (1 + 1e-6)


# ----------------------------------------------------------------------------- small files


IDENTITY_UPPER = ["1" if r == c else "0" for r, c in zip(UPPER_ROWS, UPPER_COLS)]
VERTICES = ["VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1", "VERTEX_SE3:QUAT 1 1 0 0 0 0 0 1", "VERTEX_SE3:QUAT 2 2 0 0 0 0 0 1"]


def edge(i, j, upper):
    return f"EDGE_SE3:QUAT {i} {j} 1 0 0 0 0 0 1 " + " ".join(upper)


def upper_with(entries):
    upper = list(IDENTITY_UPPER)
    for (r, c), value in entries.items():
        upper[next(k for k, rc in enumerate(zip(UPPER_ROWS, UPPER_COLS)) if rc == (r, c))] = value
    return upper


def test_only_matrices_beyond_the_tolerance_are_repaired(text_file):
    indefinite = upper_with({(0, 1): "3"})  # eigenvalues -2 and 4 in the (x, y) block
    rounding = upper_with({(0, 0): "0", (0, 1): "1e-7"})  # λ_min ≈ -1e-14: within PSD_TOLERANCE, kept as is
    path = text_file("\n".join([*VERTICES, edge(0, 1, IDENTITY_UPPER), edge(1, 2, indefinite), edge(0, 2, rounding)]))
    graph, messages = read_with_warnings(path, repair_information=True)
    assert len([m for m in messages if "repaired 1 information matrices" in m and ":5:" in m]) == 1, messages
    assert len([m for m in messages if "singular" in m]) == 1  # the kept near-singular one
    np.testing.assert_array_equal(graph.information[0], np.eye(6))
    # In [ω; v] order the g2o (x, y) block sits at rows/columns 3, 4: [[1, 3], [3, 1]] -> [[2, 2], [2, 2]] + floor.
    block = graph.information[1][3:5, 3:5]
    np.testing.assert_allclose(block, [[2, 2], [2, 2]], rtol=0, atol=1e-8)
    assert np.linalg.eigvalsh(block)[0] == pytest.approx(REPAIR_EIGENVALUE_FLOOR * 4, rel=1e-6)
    expected = np.eye(6)
    expected[3, 3], expected[3, 4], expected[4, 3], expected[4, 4] = 0, 1e-7, 1e-7, 1
    np.testing.assert_array_equal(graph.information[2], expected)


@pytest.mark.parametrize(
    "upper, reason",
    [
        (["0"] * 21, "all zero"),
        ([("-1" if r == c else "0") for r, c in zip(UPPER_ROWS, UPPER_COLS)], "no positive eigenvalue"),
    ],
)
def test_what_clipping_cannot_save_is_still_refused(text_file, upper, reason):
    path = text_file("\n".join([*VERTICES, edge(0, 1, IDENTITY_UPPER), edge(1, 2, upper)]))
    with pytest.raises(G2oFormatError, match=reason) as info:
        read_g2o(path, repair_information=True)
    assert info.value.line == 5


def test_without_indefinite_matrices_the_repair_changes_nothing(shared_dataset):
    path = shared_dataset("smallGrid3D")
    repaired, messages = read_with_warnings(path, repair_information=True)
    assert messages == []
    np.testing.assert_array_equal(repaired.information, read_g2o(path).information)
