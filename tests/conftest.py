"""Shared fixtures: the benchmark datasets next to the project and gtsam's example data.

* ``shared_datasets`` — the folder ``../shared/datasets`` (relative to the
  project root) as a :class:`~pathlib.Path`; the test is skipped, with the
  reason, when the folder is absent. CI has it, so there the tests run.
* ``shared_dataset(name)`` — a fixture returning a function: the path of one
  file in that folder (``"sphere2500"`` or ``"sphere2500.g2o"``), skipping if
  the folder or the file is absent.
* ``shared_g2o_file`` — parametrised over every 3D g2o file of that folder
  (``VERTEX_SE3:QUAT`` in its first lines); the parameter is the file name, so
  test ids read ``test_x[torus3D.g2o]``.
* ``gtsam_example_file(name)`` — a fixture returning a function: the path of a
  file bundled with the gtsam wheel (``gtsam.findExampleDataFile``), skipping
  if gtsam is not installed or does not bundle it.
* ``cholmod_backend`` — the way to CHOLMOD (``"cvxopt"``, :mod:`posegraph.linalg.cholmod`); skips, with
  the reason, when cvxopt is not installed.
* ``text_file(text, name="input.g2o")`` — a fixture returning a function that
  writes ``text`` byte for byte (no newline translation) into the test's
  ``tmp_path`` and returns the path: for malformed fixtures written by tests.
"""

from __future__ import annotations

from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATASETS = PROJECT_ROOT.parent / "shared" / "datasets"
# The files CI holds, used as test ids when the folder is absent here (each test then skips).
KNOWN_3D_DATASETS = (
    "cubicle.g2o",
    "parking-garage.g2o",
    "smallGrid3D.g2o",
    "sphere2500.g2o",
    "sphere_bignoise_vertex3.g2o",
    "tinyGrid3D.g2o",
    "torus3D.g2o",
)


INDEFINITE_INFORMATION = frozenset({"cubicle.g2o"})
"""Shared files holding information matrices that are not positive semi-definite: the reader refuses
them by default, so the tests that run over every shared file read these with
``repair_information=True``."""


def _absent_reason() -> str:
    return f"shared datasets folder {SHARED_DATASETS} is absent (it sits next to the project in CI)"


def shared_3d_dataset_names() -> list[str]:
    """Names of the 3D g2o files in the shared folder (the known list if the folder is absent)."""
    if not SHARED_DATASETS.is_dir():
        return list(KNOWN_3D_DATASETS)
    names = []
    for path in sorted(SHARED_DATASETS.glob("*.g2o")):
        with open(path, "rb") as handle:
            head = handle.read(4096)
        if b"VERTEX_SE3:QUAT" in head or b"EDGE_SE3:QUAT" in head:
            names.append(path.name)
    return names


def pytest_generate_tests(metafunc):
    if "shared_g2o_name" in metafunc.fixturenames:
        metafunc.parametrize("shared_g2o_name", shared_3d_dataset_names())


@pytest.fixture
def shared_datasets() -> Path:
    """The shared benchmark-datasets folder (skips when absent)."""
    if not SHARED_DATASETS.is_dir():
        pytest.skip(_absent_reason())
    return SHARED_DATASETS


@pytest.fixture
def shared_dataset():
    """``shared_dataset(name) -> Path`` of one shared dataset (skips when absent)."""

    def find(name: str) -> Path:
        if not SHARED_DATASETS.is_dir():
            pytest.skip(_absent_reason())
        path = SHARED_DATASETS / name
        if not path.suffix:
            path = path.with_suffix(".g2o")
        if not path.is_file():
            pytest.skip(f"shared dataset {path.name} is absent from {SHARED_DATASETS}")
        return path

    return find


@pytest.fixture
def shared_g2o_file(shared_g2o_name, shared_dataset) -> Path:
    """Each 3D g2o file of the shared folder in turn (see ``pytest_generate_tests``)."""
    return shared_dataset(shared_g2o_name)


@pytest.fixture
def gtsam_example_file():
    """``gtsam_example_file(name) -> Path`` of a file bundled with gtsam (skips without gtsam)."""

    def find(name: str) -> Path:
        gtsam = pytest.importorskip("gtsam")
        try:
            return Path(gtsam.findExampleDataFile(name))
        except (OSError, RuntimeError, ValueError) as err:
            pytest.skip(f"gtsam does not bundle {name}: {err}")

    return find


@pytest.fixture
def text_file(tmp_path):
    """``text_file(text, name="input.g2o") -> Path``: ``text`` written as is into ``tmp_path``."""

    def write(text: str | bytes, name: str = "input.g2o") -> Path:
        path = tmp_path / name
        path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
        return path

    return write


@pytest.fixture(params=["cvxopt"])
def cholmod_backend(request):
    """Which CHOLMOD binding the test runs on (see the module docstring)."""
    from posegraph.linalg import cholmod

    reason = cholmod.unavailable_reason()
    if reason is not None:
        pytest.skip(reason)
    return request.param
