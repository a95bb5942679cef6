"""Registers the ``slow`` marker used by the large-graph solver tests (they run in CI too)."""


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: large-graph solver tests (seconds each; they run in CI)")
