"""The worker processes of a search (gaits/tune.py, the studio's web/tuner.py): how each starts, and how they all end
when the search is stopped — at once, whatever they are simulating, and never left behind."""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import Executor


def start_worker() -> None:
    """A worker's start: it leaves Ctrl-C to the parent, which stops the search and keeps the best so far, and it
    ends itself once the parent is gone (killed with SIGKILL, the parent cannot end it: it stayed, orphaned)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL)
        os._exit(1)

    threading.Thread(target=watch, name="tune-worker-parent", daemon=True).start()


PARENT_POLL = 0.5
"""Seconds between a worker's looks at whether its parent is still there."""


def end_workers(pool: Executor, grace: float = 5.0) -> None:
    """End a process pool's workers now (their simulations killed, not waited for): an interrupted search must not
    wait for them, and a pool whose workers are gone lets the interpreter exit (concurrent.futures' exit handler
    joins the pool's thread, which waits for workers that would never be sent their last job)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        if process.is_alive():
            process.terminate()
    deadline = time.monotonic() + grace
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join(1.0)
