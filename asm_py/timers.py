"""One thread runs the timed work of every object on one clock: rate publications, heartbeats, expiries.

A publisher with a rate, a transport's heartbeat, a reassembler's expiry each need "call me at time t". With a
thread each, a process hosting 128 modules ran 128 × 5 threads that mostly slept (issue 31); here each clock has
one :class:`Timers` — a heap of deadlines and one worker thread (``asm:timers``) that sleeps until the earliest,
runs its callback, and files the deadline the callback returns. The worker exists only while there are deadlines:
it ends when the heap is empty and is started again by the next ``call_at``, so an idle process and a finished test
hold no timer thread.

On a :class:`~asm_py.clock.SimClock` the worker is a service thread of that clock and waits in a monitor, so
``advance`` returns only after every callback due by then has run — the determinism services have.

Callbacks run one at a time, in deadline order (ties in the order they were filed); they must be short and must
not block: every timer of the clock waits behind them.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import weakref
from collections.abc import Callable

from .clock import WALL_CLOCK, Clock, Monitor
from .service import Service

log = logging.getLogger("asm_py.timers")

TimerCallback = Callable[[float], "float | None"]
"""Called with its due time; returns the next due time (clock seconds), or None to end."""


class TimerHandle:
    """A filed deadline; ``cancel`` ends it (waiting for its callback if that is running in another thread).

    The heap holds ``(when, seq, handle)`` tuples: compared in C, where a ``__lt__`` of the handle's own was the
    timer thread's largest cost in an idle 128-module robot (issue 31)."""

    __slots__ = ("_timers", "alive", "callback", "seq", "when")

    def __init__(self, timers: Timers, when: float, seq: int, callback: TimerCallback) -> None:
        self._timers = timers
        self.when = when
        self.seq = seq
        self.callback = callback
        self.alive = True

    def cancel(self) -> None:
        self._timers._cancel(self)


class _Worker(Service):
    """The thread of one :class:`Timers` while it has deadlines."""

    def __init__(self, timers: Timers) -> None:
        super().__init__("timers", clock=timers.clock)
        self._timers = timers

    def run(self, *params: object) -> None:
        timers = self._timers
        while (handle := timers._next_due(self)) is not None:
            try:
                again = handle.callback(handle.when)
            except Exception:
                log.exception("a timer callback failed; its timer ends")
                again = None
            timers._done(handle, again)


class Timers:
    """The deadlines of one clock and the thread that meets them; see the module docstring."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self._mon = Monitor(clock)
        self._heap: list[tuple[float, int, TimerHandle]] = []
        self._seq = itertools.count()
        self._worker: _Worker | None = None
        self._running: TimerHandle | None = None
        self._running_in: int | None = None

    def call_at(self, when: float, callback: TimerCallback) -> TimerHandle:
        """Run ``callback(when)`` at clock time ``when`` on the timers' thread, then again at what it returns."""
        start = None
        with self._mon:
            handle = TimerHandle(self, when, next(self._seq), callback)
            heapq.heappush(self._heap, (when, handle.seq, handle))
            if self._worker is None:
                self._worker = start = _Worker(self)
            self._mon.notify_all()
        if start is not None:
            start.start()
        return handle

    def _next_due(self, worker: _Worker) -> TimerHandle | None:
        """The next deadline once it is due (popped), or None when the worker should end."""
        mon, clock, heap = self._mon, self.clock, self._heap
        with mon:
            while True:
                while heap and not heap[0][2].alive:
                    heapq.heappop(heap)
                if worker.stop_requested or not heap:
                    if self._worker is worker:
                        self._worker = None
                    return None
                when, _, top = heap[0]
                if clock.reached(when):
                    heapq.heappop(heap)
                    self._running, self._running_in = top, threading.get_ident()
                    return top

                def changed(top: TimerHandle = top) -> bool:
                    return worker.stop_requested or not heap or heap[0][2] is not top or not top.alive

                mon.wait_for(changed, when - clock.now(), interruptible=False)

    def _done(self, handle: TimerHandle, again: float | None) -> None:
        with self._mon:
            self._running = self._running_in = None
            if again is not None and handle.alive:
                handle.when = again
                handle.seq = next(self._seq)
                heapq.heappush(self._heap, (again, handle.seq, handle))
            self._mon.notify_all()

    def _cancel(self, handle: TimerHandle) -> None:
        with self._mon:
            handle.alive = False
            self._mon.notify_all()
            if self._running is handle and self._running_in != threading.get_ident():
                self._mon.wait_for(lambda: self._running is not handle, 5.0, interruptible=False)

    def close(self) -> None:
        """End every deadline and the thread (tests; a process's timers otherwise end with their last deadline)."""
        with self._mon:
            for _, _, handle in self._heap:
                handle.alive = False
            worker = self._worker
            self._mon.notify_all()
        if worker is not None:
            worker.stop(timeout=5.0)

    @property
    def pending(self) -> int:
        """Deadlines filed and not cancelled."""
        return sum(1 for _, _, h in self._heap if h.alive)


_BY_CLOCK: weakref.WeakKeyDictionary[Clock, Timers] = weakref.WeakKeyDictionary()
_BY_CLOCK_LOCK = threading.Lock()


def timers_of(clock: Clock | None = None) -> Timers:
    """The one :class:`Timers` of ``clock`` (the wall clock by default)."""
    clock = clock if clock is not None else WALL_CLOCK
    with _BY_CLOCK_LOCK:
        timers = _BY_CLOCK.get(clock)
        if timers is None:
            timers = _BY_CLOCK[clock] = Timers(clock)
        return timers


__all__ = ["TimerHandle", "Timers", "timers_of"]
