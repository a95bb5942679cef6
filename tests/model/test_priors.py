"""posegraph.model.priors.prior_poses: the pose each prior gives its vertex, with a non-identity offset.

g2o's ``EDGE_SE3_PRIOR`` measures ``Z ≈ X·O`` (its error is ``Log(Z⁻¹·X·O)``, ``O`` the
``PARAMS_SE3OFFSET``: a sensor mounted off the body), so the pose it gives is ``X = Z·O⁻¹``; with
the offset on the wrong side (``Z·O``) the answer differs unless ``O² = I``. Checked against
gtsam's ``Pose3`` algebra and against matrices built here from the file's numbers.
"""

from __future__ import annotations

import numpy as np

from posegraph.io.g2o import read_g2o
from posegraph.model.priors import prior_poses
from tests.io.test_g2o_priors import CHAIN, INFO6, OFFSET
from tests.io.test_g2o_read import rotation_from_xyzw
from tests.optional import import_or_skip

MEASURED = (1.0, 2.0, 3.0, 0.1, 0.1, 0.1, 0.98)  # x y z qx qy qz qw
PRIORS = "\n".join([
    "PARAMS_SE3OFFSET 7 " + " ".join(map(str, OFFSET)),
    "EDGE_SE3_PRIOR 1 7 " + " ".join(map(str, MEASURED)) + " " + " ".join(map(repr, INFO6)),
    "EDGE_SE3_XYZ_PRIOR 2 7 4 5 6 2 0.1 0 3 0.2 4",
])


def matrix(fields) -> np.ndarray:
    """The 4×4 pose of g2o's ``x y z qx qy qz qw``, built here (not by posegraph)."""
    pose = np.eye(4)
    pose[:3, :3] = rotation_from_xyzw(fields[3:])
    pose[:3, 3] = fields[:3]
    return pose


def test_a_pose_prior_through_an_offset_gives_the_measurement_times_the_offset_inverse(text_file):
    graph = read_g2o(text_file(CHAIN + "\n" + PRIORS + "\n"))
    vertex, poses = prior_poses(graph)
    assert vertex.tolist() == [1, 2]
    Z, O = matrix(MEASURED), matrix(OFFSET)
    assert not np.allclose(Z @ O, Z @ np.linalg.inv(O), atol=1e-3)  # the offset's side matters here
    np.testing.assert_allclose(poses[0] @ O, Z, atol=1e-12)  # X·O = Z: the prior's error is zero at X
    # The position prior: its point as the translation, the rotation of the vertex's current pose.
    np.testing.assert_array_equal(poses[1][:3, 3], [4, 5, 6])
    np.testing.assert_array_equal(poses[1][:3, :3], graph.poses[2][:3, :3])


def test_the_pose_agrees_with_gtsam_pose3_algebra(text_file):
    gtsam = import_or_skip("gtsam", "the check against gtsam's Pose3")

    def pose3(fields):
        x, y, z, qx, qy, qz, qw = fields
        norm = np.linalg.norm([qx, qy, qz, qw])  # g2o normalises the offset's and the measurement's quaternions
        return gtsam.Pose3(gtsam.Rot3.Quaternion(qw / norm, qx / norm, qy / norm, qz / norm), gtsam.Point3(x, y, z))

    graph = read_g2o(text_file(CHAIN + "\n" + PRIORS + "\n"))
    _, poses = prior_poses(graph)
    expected = pose3(MEASURED).compose(pose3(OFFSET).inverse())
    np.testing.assert_allclose(poses[0], expected.matrix(), atol=1e-12)
    assert gtsam.Pose3(poses[0]).compose(pose3(OFFSET)).equals(pose3(MEASURED), 1e-12)
