"""A search's worker pool, stopped (gaits/workers.py): running jobs are killed, not waited for, queued ones are
cancelled, and the pool's own thread ends without an error — the order that CPython 3.11 needs."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ProcessPoolExecutor

import pytest

from gaits.workers import start_worker, stop_pool

pytestmark = pytest.mark.timeout(120)
LONG = 60.0
"""Seconds each job would run: far beyond how long stopping may take."""


@pytest.fixture
def thread_errors(monkeypatch: pytest.MonkeyPatch) -> list[BaseException]:
    """Exceptions that ended any thread (the pool's own thread among them) during the test."""
    errors: list[BaseException] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: errors.append(args.exc_value))
    return errors


def busy_pool() -> tuple[ProcessPoolExecutor, list]:
    """Two workers each running a long job, and queued jobs of which those not yet handed to a worker are cancelled
    (as ``Executor.map`` cancels them when its caller is interrupted)."""
    pool = ProcessPoolExecutor(2, initializer=start_worker)
    futures = [pool.submit(time.sleep, LONG) for _ in range(8)]
    deadline = time.monotonic() + 30
    while sum(f.running() for f in futures) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    for future in futures:
        future.cancel()
    return pool, futures


@pytest.mark.parametrize("round_", range(4))
def test_stopping_a_busy_pool_kills_its_jobs_and_its_thread_ends_cleanly(
    round_: int, thread_errors: list[BaseException]
) -> None:
    pool, futures = busy_pool()
    processes = list(pool._processes.values())  # type: ignore[union-attr]  # (the workers, to check they are gone)
    manager = pool._executor_manager_thread
    began = time.monotonic()
    stop_pool(pool)
    assert time.monotonic() - began < LONG / 2, "stopping waited for the running jobs"
    assert not any(p.is_alive() for p in processes)
    assert manager is None or not manager.is_alive()
    assert all(f.done() for f in futures)
    assert thread_errors == []
