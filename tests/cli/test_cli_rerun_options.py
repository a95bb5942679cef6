"""The Rerun options without Rerun: the missing package is a one-line usage error before any work,
viewer addresses, and ``--help`` naming the options (no rerun-sdk needed)."""

from __future__ import annotations

import argparse
import importlib.util

import pytest

from posegraph.cli.common import UsageError
from posegraph.cli.rerun_output import check_rerun_options, viewer_url, wants_rerun
from tests.cli.conftest import run_cli


def _args(**given):
    values = {"input": "in.g2o", "rerun": None, "rerun_spawn": False, "rerun_connect": None}
    return argparse.Namespace(**{**values, **given})


@pytest.mark.parametrize("given", [{"rerun": "x.rrd"}, {"rerun_spawn": True}, {"rerun_connect": "host:1"}])
def test_without_rerun_sdk_each_option_is_a_usage_error_naming_the_extra(monkeypatch, tmp_path, given):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "rerun" else real(name, *a))
    if "rerun" in given:
        given = {"rerun": str(tmp_path / "x.rrd")}
    with pytest.raises(UsageError, match=r"pip install 'posegraph\[rerun\]'"):
        check_rerun_options(_args(**given))


def test_no_option_asks_for_nothing(monkeypatch):
    monkeypatch.setattr(importlib.util, "find_spec", lambda *a: pytest.fail("looked for rerun"))
    assert not wants_rerun(_args())
    check_rerun_options(_args())


def test_viewer_addresses():
    assert viewer_url("localhost:9877") == "rerun+http://localhost:9877/proxy"
    assert viewer_url("rerun+https://example.org:443/proxy") == "rerun+https://example.org:443/proxy"


@pytest.mark.parametrize("command", ["optimize", "replay"])
def test_help_lists_the_rerun_options(command):
    run = run_cli(command, "--help")
    assert run.returncode == 0
    for option in ("--rerun OUT.rrd", "--rerun-spawn", "--rerun-connect ADDR"):
        assert option in run.stdout
