"""Time for every ASM object, and the monitor through which every ASM wait goes.

All timing — timeouts, service sleeps, timers, polling — is measured on a :class:`Clock`. The wall clock is the
default. A :class:`SimClock` is advanced by hand (by a simulator, or a test) and is *deterministic*: ``advance``
returns only once every service thread running on that clock has reacted to the time change and is blocked again
in an ASM wait. A phase automaton therefore produces exactly the same outputs on a simulation clock every time, and
a simulator can read the outputs right after ``advance`` returns.

Determinism rests on one rule: on a SimClock, service threads block only through ASM objects (attributes, events,
``Service.sleep``/``checkpoint``), i.e. through :class:`Monitor`. A thread that blocks elsewhere (a socket, a plain
lock) looks busy to the clock, and ``advance`` raises :class:`~asm_py.errors.SimulationStalled` after
``settle_timeout`` real seconds instead of hanging.

How the clock knows who is busy: each service thread of a SimClock counts as busy from ``start`` until it blocks in a
monitor; a monitor's ``notify_all`` hands the busy count back for each such thread it wakes, under the monitor's lock,
so there is no instant at which a woken thread is neither waiting nor counted busy.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import TYPE_CHECKING

from .errors import ServiceStopped, SimulationStalled

if TYPE_CHECKING:
    from .service import Service


class _Local(threading.local):
    service: Service | None = None
    """The class's None for threads that never set it: a missing thread-local attribute read with a default costs
    an exception each time (0.7 µs on every remote call; issue 31)."""


_local = _Local()


def current_service() -> Service | None:
    """The service whose thread is running this code, if any (set by the service thread itself)."""
    return _local.service


def _set_current_service(service: Service | None) -> None:
    _local.service = service


class Monitor:
    """A lock and one condition; timed waits are measured on a clock.

    This is the paper's monitor object: every attribute and service owns exactly one. Waits made from a service
    thread are interruptible: ``Service.stop`` wakes the monitor its thread is blocked on, and the wait raises
    :class:`~asm_py.errors.ServiceStopped`.
    """

    __slots__ = ("_cond", "_sim_waiters", "_waiters", "clock", "lock")

    def __init__(self, clock: Clock | None = None) -> None:
        self.clock: Clock = clock if clock is not None else WALL_CLOCK
        self.lock = threading.Lock()
        self._cond = threading.Condition(self.lock)
        self._waiters = 0
        self._sim_waiters = 0

    def __enter__(self) -> Monitor:
        self.lock.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.lock.release()

    def wait_for(self, predicate: Callable[[], bool], timeout: float | None, *, interruptible: bool = True) -> bool:
        """Block (lock held) until ``predicate()`` holds or ``timeout`` clock seconds pass; False on timeout.

        With ``interruptible`` and called from a service thread, a ``stop()`` of that service raises
        ServiceStopped here rather than leaving the thread blocked forever.
        """
        if predicate():
            return True
        deadline = None if timeout is None else self.clock.now() + max(0.0, timeout)
        service = current_service() if interruptible else None
        if service is None:
            return self.clock._wait_for(self, predicate, deadline)

        def stop_or_ready() -> bool:
            return service._stop_requested or predicate()

        # Publish where we block before testing the flag; stop() sets the flag before reading this (see Service.stop).
        service._blocked_on = self
        try:
            if service._stop_requested:
                raise ServiceStopped(service.name)
            ok = self.clock._wait_for(self, stop_or_ready, deadline)
        finally:
            service._blocked_on = None
        if service._stop_requested and not predicate():
            raise ServiceStopped(service.name)
        return ok

    def notify_all(self) -> None:
        """Wake every waiter (lock held)."""
        if self._waiters:
            self.clock._notify_all(self)


class Clock(ABC):
    """A source of time that ASM objects wait on."""

    @abstractmethod
    def now(self) -> float:
        """Seconds on this clock; only differences are meaningful."""

    def reached(self, when: float) -> bool:
        """True once clock time ``when`` has come (at this clock's resolution)."""
        return self.now() >= when

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of this clock pass (not interruptible; services use ``Service.sleep``)."""
        monitor = Monitor(self)
        deadline = self.now() + seconds
        with monitor:
            monitor.wait_for(lambda: self.reached(deadline), seconds, interruptible=False)

    @abstractmethod
    def _wait_for(self, monitor: Monitor, predicate: Callable[[], bool], deadline: float | None) -> bool: ...

    def _notify_all(self, monitor: Monitor) -> None:
        monitor._cond.notify_all()

    def _thread_starting(self) -> None:
        """A service thread of this clock is about to start (called before ``Thread.start``)."""

    def _thread_exited(self) -> None:
        """A service thread of this clock has finished all its work."""


class WallClock(Clock):
    """Real time (``time.monotonic``)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))

    def _wait_for(self, monitor: Monitor, predicate: Callable[[], bool], deadline: float | None) -> bool:
        cond = monitor._cond
        while not predicate():
            monitor._waiters += 1
            try:
                if deadline is None:
                    cond.wait()
                else:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return False
                    cond.wait(remaining)
            finally:
                monitor._waiters -= 1
        return True


WALL_CLOCK: Clock = WallClock()


class _Deadline:
    __slots__ = ("alive", "monitor", "seq", "when")

    def __init__(self, when: int, seq: int, monitor: Monitor) -> None:
        self.when = when
        self.seq = seq
        self.monitor = monitor
        self.alive = True

    def __lt__(self, other: _Deadline) -> bool:
        return (self.when, self.seq) < (other.when, other.seq)


def _ns(seconds: float) -> int:
    return round(seconds * 1_000_000_000)


class SimClock(Clock):
    """Simulated time, advanced by hand; ``advance`` waits until every service thread on it has settled.

    Time is kept in integer nanoseconds, so ``advance(0.1)`` three times reaches a deadline computed as
    ``3 * 0.1`` (0.30000000000000004 in floating point) exactly, and ``now()`` reads 0.3.
    """

    def __init__(self, start: float = 0.0, *, settle_timeout: float = 10.0) -> None:
        self._now = _ns(start)
        self.settle_timeout = settle_timeout
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._busy = 0
        self._heap: list[_Deadline] = []
        self._seq = itertools.count()

    def now(self) -> float:
        return self._now / 1_000_000_000

    def reached(self, when: float) -> bool:
        return self._now >= _ns(when)

    @property
    def busy_threads(self) -> int:
        """Service threads of this clock that are running rather than blocked in an ASM wait."""
        return self._busy

    def advance(self, seconds: float) -> None:
        """Move time forward by ``seconds``, waking every timed wait that falls due, in order."""
        if seconds < 0:
            raise ValueError(f"cannot advance a clock by a negative time ({seconds})")
        self._advance_to_ns(self._now + _ns(seconds))

    def advance_to(self, when: float) -> None:
        """Move time to ``when``; each due deadline is reached in turn and the system settles after each."""
        self._advance_to_ns(_ns(when))

    def _advance_to_ns(self, when: int) -> None:
        if self._is_participant():
            raise RuntimeError("a service thread of this SimClock cannot advance it (it would wait for itself)")
        self.settle()
        while True:
            with self._lock:
                heap = self._heap
                while heap and not heap[0].alive:
                    heapq.heappop(heap)
                if not heap or heap[0].when > when:
                    self._now = max(self._now, when)
                    return
                due_at = heap[0].when
                self._now = max(self._now, due_at)
                due: list[Monitor] = []
                while heap and heap[0].when <= due_at:
                    entry = heapq.heappop(heap)
                    if entry.alive and entry.monitor not in due:
                        due.append(entry.monitor)
            for monitor in due:
                with monitor:
                    monitor.notify_all()
            self.settle()

    def settle(self) -> None:
        """Block until no service thread of this clock is busy (bounded by ``settle_timeout`` real seconds)."""
        with self._lock:
            end = time.monotonic() + self.settle_timeout
            while self._busy > 0:
                remaining = end - time.monotonic()
                if remaining <= 0:
                    raise SimulationStalled(
                        f"SimClock at t={self.now()}: {self._busy} service thread(s) still busy after "
                        f"{self.settle_timeout}s of real time (blocked outside ASM, or looping?)"
                    )
                self._idle.wait(remaining)

    def _is_participant(self) -> bool:
        service = current_service()
        return service is not None and service.clock is self

    def _change_busy(self, delta: int) -> None:
        with self._lock:
            self._busy += delta
            if self._busy <= 0:
                self._busy = 0
                self._idle.notify_all()

    def _wait_for(self, monitor: Monitor, predicate: Callable[[], bool], deadline: float | None) -> bool:
        participant = self._is_participant()
        entry: _Deadline | None = None
        try:
            while not predicate():
                if deadline is not None:
                    if self.reached(deadline):
                        return False
                    if entry is None:
                        entry = _Deadline(_ns(deadline), next(self._seq), monitor)
                        with self._lock:
                            heapq.heappush(self._heap, entry)
                monitor._waiters += 1
                if participant:
                    monitor._sim_waiters += 1
                    self._change_busy(-1)
                try:
                    monitor._cond.wait()
                finally:
                    monitor._waiters -= 1
            return True
        finally:
            if entry is not None:
                entry.alive = False

    def _notify_all(self, monitor: Monitor) -> None:
        woken = monitor._sim_waiters
        if woken:
            monitor._sim_waiters = 0
            self._change_busy(woken)
        monitor._cond.notify_all()

    def _thread_starting(self) -> None:
        self._change_busy(1)

    def _thread_exited(self) -> None:
        self._change_busy(-1)


__all__ = ["Clock", "Monitor", "SimClock", "WallClock", "WALL_CLOCK", "current_service"]
