"""Shared fixtures. Every test is checked for leaked ASM service threads: a leaked thread is a bug."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("suite", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("suite")
"""Hypothesis judges no example by the wall clock here: its default 200 ms deadline failed a codec round trip of 7
bytes that took 329 ms once under the suite's load and 0.13 ms when replayed (tests/core/test_codec.py, stop 53), and
its too_slow health check times the drawing of examples the same way. Timing is for bench/, as ratios."""


CHECKOUT = Path(__file__).resolve().parents[1]
NOT_SOURCE = frozenset({"build", "docs", "firmware", "recordings", "typings"})
"""The checkout's folders of no module of ours; hidden ones and those starting with ``_`` are left out too (the
virtual environment among them: pip compiled it)."""


def source_folders(root: Path = CHECKOUT) -> list[Path]:
    """The top-level folders of ``root`` whose modules the suite's processes import."""
    return sorted(p for p in root.iterdir() if p.is_dir() and p.name[0] not in "._" and p.name not in NOT_SOURCE)


def compile_checkout(root: Path = CHECKOUT) -> subprocess.CompletedProcess[str]:
    """Write the bytecode of the checkout's modules, once, before any test starts a process.

    Where ``PYTHONDONTWRITEBYTECODE`` is set (it is in this machine's environment) no process writes what it
    compiles, so every studio, robot and tool the suite starts compiled ~150 of our modules from source: 0.2-0.3
    CPU-s each, a few hundred processes a run (docs/benchmarks.md, "The suite's time", stop 54). ``compileall``
    writes it whatever that variable says and skips what is current: ~0.2 s once it is there. Timestamp bytecode
    even when ``SOURCE_DATE_EPOCH`` is set: compileall sees hash-checked bytecode as stale and wrote it all again."""
    folders = [str(p) for p in source_folders(root)]
    command = [sys.executable, "-m", "compileall", "-q", "-j", "0", "--invalidation-mode", "timestamp", *folders]
    return subprocess.run(command, capture_output=True, text=True, timeout=300)


def pytest_configure(config: pytest.Config) -> None:
    """Before any test (in the one process that starts pytest-xdist's workers, or the only one): the checkout's
    bytecode written (:func:`compile_checkout`), and the folder the browser tests write their screenshots to
    (tests/helpers.py ARTIFACTS): a test run alone on a fresh clone found it missing when an earlier test had not made
    it."""
    from .helpers import ARTIFACTS

    if not hasattr(config, "workerinput"):
        compiled = compile_checkout()
        if compiled.returncode != 0:  # the suite runs on; its processes compile what was not written
            said = (compiled.stdout + compiled.stderr).strip().splitlines()[-5:]
            config.issue_config_time_warning(pytest.PytestWarning("compileall: " + " | ".join(said)), stacklevel=2)
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
