"""Shared fixtures. Every test is checked for leaked ASM service threads: a leaked thread is a bug."""

from __future__ import annotations

import threading
import time

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("suite", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("suite")
"""Hypothesis judges no example by the wall clock here: its default 200 ms deadline failed a codec round trip of 7
bytes that took 329 ms once under the suite's load and 0.13 ms when replayed (tests/core/test_codec.py, stop 53), and
its too_slow health check times the drawing of examples the same way. Timing is for bench/, as ratios."""


def pytest_configure(config: pytest.Config) -> None:
    """The folder the browser tests write their screenshots to (tests/helpers.py ARTIFACTS), there before any test:
    a test run alone on a fresh clone found it missing when an earlier test had not made it."""
    from .helpers import ARTIFACTS

    ARTIFACTS.mkdir(exist_ok=True)


def _asm_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.name.startswith(("asm:", "asm-"))}


@pytest.fixture(autouse=True)
def no_leaked_threads():
    before = _asm_threads()
    yield
    deadline = time.monotonic() + 5.0
    while (leaked := _asm_threads() - before) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not leaked, f"test leaked service threads: {sorted(t.name for t in leaked)}"


@pytest.fixture
def services():
    """Services registered here are stopped at the end of the test, even when it fails."""
    started: list = []
    yield started
    for service in reversed(started):
        service.stop(timeout=None)


@pytest.fixture
def studio():
    """The studio in this process (its robot a child process), on a free port; closed even when the test fails."""
    from server.studio import Studio, StudioOptions

    studio = Studio(StudioOptions(port=0))
    studio.app.draw_unwatched = True  # the tests read the 3D view and the control table with no browser
    try:
        yield studio
    finally:
        studio.close()
