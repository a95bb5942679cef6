"""Every Python file of the project compiles with warnings as errors (an invalid escape sequence
in a docstring is a DeprecationWarning, a SyntaxWarning from Python 3.12, shown to a user on the
first run that compiles the module)."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted(
    path for folder in ("posegraph", "datasets", "benchmarks", "tests") for path in (ROOT / folder).rglob("*.py")
) + [ROOT / "cli.py"]


def test_the_project_has_sources():
    assert len(SOURCES) > 100 and ROOT / "posegraph" / "robust" / "active.py" in SOURCES


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_compiles_without_warnings(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        compile(path.read_text(encoding="utf-8"), str(path), "exec")
