"""The worker processes of a search (gaits/tune.py, the studio's web/tuner.py): how each starts, and how they all end
when the search is stopped — at once, whatever they are simulating, and never left behind."""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import Executor
from typing import Any


def start_worker() -> None:
    """A worker's start: it leaves Ctrl-C to the parent, which stops the search and keeps the best so far, and it
    ends itself once the parent is gone (killed with SIGKILL, the parent cannot end it: it stayed, orphaned)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # and SIGTERM (stop_pool's terminate) ends it at once: a handler inherited from a parent that turns SIGTERM into
    # KeyboardInterrupt would only fail the running job, and the worker would go on to the next
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL)
        os._exit(1)

    threading.Thread(target=watch, name="tune-worker-parent", daemon=True).start()


PARENT_POLL = 0.5
"""Seconds between a worker's looks at whether its parent is still there."""


def stop_pool(pool: Executor, grace: float = 5.0) -> None:
    """Shut down a process pool without waiting for the simulations it runs: queued jobs are cancelled, running
    ones killed, and the pool's thread joined. An interrupted search must not wait for them, and a pool whose
    workers are gone lets the interpreter exit (concurrent.futures' exit handler joins the pool's thread, which
    waits for workers that would never be sent their last job). Shutdown forgets the pool's processes, so they are
    captured first (`gaits tune` ended them after shutdown, which ended none: it waited for its simulations).

    The order matters on CPython 3.11. Killed before the pool's thread has dropped the cancelled jobs (those of
    shutdown's ``cancel_futures`` and those ``Executor.map`` cancels when its caller is interrupted), the workers'
    deaths make that thread set an error on a cancelled job, which raises InvalidStateError in it (2 of 5
    interrupted searches printed it). So: capture the workers, shut down, wait (at most a second) for the thread to
    have handled the shutdown — it clears ``_cancel_pending_futures`` once it has — and only then kill them. Once its
    workers are gone the thread closes its wake-up pipe, which 3.11's exit handler writes to unless closed: joining
    the thread here keeps the two from racing at exit ("OSError: [Errno 9] Bad file descriptor")."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager: threading.Thread | None = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    handled_by = time.monotonic() + 1.0
    while (getattr(pool, "_cancel_pending_futures", False) and manager is not None and manager.is_alive()
           and time.monotonic() < handled_by):  # fmt: skip
        time.sleep(0.005)
    _end(processes, grace)
    if manager is not None:
        manager.join(10.0)  # bounded: `gaits tune` must write its best gait before its exit deadline (30 s)


def _end(processes: list[Any], grace: float) -> None:
    """Terminate ``processes`` (multiprocessing's), then kill those still alive after ``grace`` seconds."""
    for process in processes:
        if process.is_alive():
            process.terminate()
    deadline = time.monotonic() + grace
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join(1.0)
