"""A ``gaits tune`` process to be stopped by a signal, for the tests of what stopping leaves behind."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from gaits.model import LIBRARY

ROOT = Path(__file__).resolve().parents[2]


def long_search(out: Path, entry: Sequence[str] = ("-m", "gaits.cli")) -> subprocess.Popen[str]:
    """``gaits tune`` with two workers and a budget far beyond a test's patience: to be stopped by a signal.
    ``entry``: how Python starts it (``-c`` and a script around the command, for a test that changes its process)."""
    command = [sys.executable, *entry, "tune", str(LIBRARY / "caterpillar.toml"), "--free",
               "amplitude=20:85", "--budget", "2000", "--seconds", "1", "--warmup", "0.5", "--workers", "2",
               "--out", str(out)]  # fmt: skip
    return subprocess.Popen(command, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)


@contextmanager
def workers_of(process: subprocess.Popen[str]) -> Iterator[list]:
    """The list the test fills with the search's worker processes (psutil's); whatever happens, none of them and
    not the search itself is left running afterwards."""
    workers: list = []
    try:
        yield workers
    finally:
        for child in workers:
            if child.is_running():
                child.kill()
        if process.poll() is None:
            process.kill()
            process.wait()


def interrupt(process: subprocess.Popen[str], at: str, signals: Sequence[int]) -> list:
    """Wait for the search's stderr line that starts with ``at``, then send it ``signals``, 50 ms apart (until it
    has ended); its worker processes (psutil's) as they were then."""
    import psutil

    assert process.stderr is not None
    for line in process.stderr:
        if line.startswith(at):
            workers = psutil.Process(process.pid).children(recursive=True)
            for number in signals:
                if process.poll() is not None:
                    break
                os.kill(process.pid, number)
                time.sleep(0.05)
            return workers
    raise AssertionError(f"the search ended before {at!r}")
