"""Shared pytest configuration: hypothesis profiles, reproducible in CI."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# the independent reference implementation lives beside the tests
sys.path.insert(0, str(Path(__file__).parent))

settings.register_profile(
    "default",
    deadline=None,
    max_examples=20,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "ci",
    deadline=None,
    max_examples=20,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("ci" if os.environ.get("CI") else "default")

_TERMINAL_STDERR = pytest.StashKey[int]()


def pytest_configure(config: pytest.Config) -> None:
    # pytest captures the tests' output from here on; keep the run's own stderr
    # for what must be seen even when the process is ended (a watchdog's traceback)
    config.stash[_TERMINAL_STDERR] = os.dup(2)


@pytest.fixture(scope="session")
def terminal_stderr(pytestconfig: pytest.Config) -> int:
    """A file descriptor of the run's stderr, past pytest's capture (faulthandler writes there)."""
    return pytestconfig.stash[_TERMINAL_STDERR]
