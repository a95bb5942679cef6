"""Optional packages in tests: skip, with the reason, when one cannot be used here.

``pytest.importorskip`` skips only when the module is missing (pytest 9 re-raises any other
``ImportError``), but an installed package can fail to load: Open3D's wheel needs the system's
``libusb-1.0-0``, and without it ``import open3d`` raises ``ImportError`` (or ``OSError``) from a
shared library. The README promises that such tests skip.
"""

from __future__ import annotations

import importlib
import os

import pytest

REQUIRED = frozenset(filter(None, os.environ.get("POSEGRAPH_TESTS_REQUIRE", "").split(",")))
"""Modules named in ``POSEGRAPH_TESTS_REQUIRE`` (comma-separated) must load: their tests fail
instead of skipping (``.ci/run`` sets it for Open3D once it has installed libusb)."""


def import_or_skip(name: str, needed_for: str = "this test"):
    """The module ``name``, or skip the test (or, at module level, the file) saying why it cannot load."""
    try:
        return importlib.import_module(name)
    except Exception as exc:  # ImportError, OSError from a shared library, or a package's own failure
        if name in REQUIRED:
            raise
        reason = "not installed" if isinstance(exc, ModuleNotFoundError) and exc.name == name else "cannot load"
        text = " ".join(str(exc).split())
        pytest.skip(f"{name} {reason} ({type(exc).__name__}: {text}); {needed_for} needs it", allow_module_level=True)
