"""Who reads a CAN bus: the transport's receive thread, or a caller waiting for its own reply (issue 31).

A remote call through one reader thread crosses three threads — the server's reader, the client's reader, and the
caller the client's reader wakes with the reply — where a bare python-can echo crosses two. Each wake costs more
than the Python on either side, so the caller reads the bus itself while it waits (leader/follower):

- The **lead** is a lock: whoever holds it, and only they, call ``bus.recv``, so frames are handled one at a time
  in the order they arrived, as with one reader.
- A caller waiting for a reply (``wait``) takes the lead if it is free and reads. Its own reply — a single frame
  from the peer with the expected first header bytes — it hands to the transport's frame handler in its own thread,
  exactly as the receive thread would (the port's delivery completes its call). The first frame that is anything
  else it hands over *with the lead* to the receive thread and becomes a follower: user handlers (requests to this
  node, publications, e-stops, peers coming and going) always run on the receive thread, never on a caller that may
  hold locks of its own, and the handed frame is handled before anything later on the bus.
- A caller that finds the lead taken follows: it waits for the delivery, as before. So do service threads (a
  ``Service.stop`` must interrupt their waits) and the receive thread's own handlers.
- The receive thread stands aside while callers lead: after a caller read the bus it waits ``LINGER`` seconds for a
  frame handed over before it reads again, so the next call of a burst finds the lead free. It never stands aside
  while a follower waits. A frame that arrives while nobody reads (between two calls of a burst) waits at most
  ``LINGER``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import can

log = logging.getLogger("asm_py.transport.can")

LINGER = 0.001
"""Seconds the receive thread stands aside after a caller read the bus (at most this late, a frame between calls)."""
POLL = 0.1
"""Longest blocking read: how soon a reader sees the transport close or a call completed by someone else."""

_DONE, _LATE, _HANDED = 0, 1, 2


class BusReader:
    """The receive thread of one transport and the lead it shares with waiting callers; see the module docstring."""

    def __init__(self, bus: can.BusABC, handle: Callable[[can.Message], None], stop: threading.Event) -> None:
        self._bus = bus
        self._handle = handle
        self._stop = stop
        self._lead = threading.Lock()
        self._handoff: queue.SimpleQueue[can.Message | None] = queue.SimpleQueue()
        self._count_lock = threading.Lock()
        self._followers: tuple[threading.Lock, ...] = ()
        """The ``done`` locks of the calls that wait without reading (copy-on-write: read without the lock)."""
        self._led_at = float("-inf")
        self._thread: threading.Thread | None = None
        self._ident: int | None = None
        self.led = 0
        """Calls whose reply was read by their own caller (for tests and benches)."""
        self.handed = 0
        """Frames a leading caller handed over to the receive thread."""

    def start(self, name: str) -> None:
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def join(self, timeout: float) -> None:
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            self._handoff.put(None)
            thread.join(timeout)

    # -- the receive thread ---------------------------------------------------------------------------------------

    def _run(self) -> None:
        self._ident = threading.get_ident()
        lead, handoff, stop = self._lead, self._handoff, self._stop
        while not stop.is_set():
            frame = None
            idle = self._led_at + LINGER - time.monotonic()
            if idle > 0 and not self._followed():
                wait = idle  # callers lead: stand aside, unless one hands a frame over
            elif lead.acquire(False):
                wait = 0.0
            else:
                wait = POLL  # a caller leads: it hands the lead over with a frame, or wakes this thread
            if wait:
                try:
                    frame = handoff.get(timeout=wait)
                except queue.Empty:
                    continue
                if frame is None:
                    continue  # woken to look again
            # This thread holds the lead: the frame handed over with it first, then the bus.
            try:
                if frame is not None:
                    self._dispatch(frame)
                frame = self._recv(POLL)
                if frame is not None:
                    self._dispatch(frame)
            finally:
                lead.release()

    def _recv(self, timeout: float) -> can.Message | None:
        try:
            return self._bus.recv(timeout=timeout)
        except (can.CanError, RuntimeError, ValueError) as exc:
            if not self._stop.is_set():
                log.warning("CAN receive failed: %s", exc)
                time.sleep(0.05)
            return None

    def _dispatch(self, frame: can.Message) -> None:
        try:
            self._handle(frame)
        except Exception:
            log.exception("a CAN frame could not be handled: %s", frame)

    # -- callers --------------------------------------------------------------------------------------------------

    def _followed(self) -> bool:
        """Whether a call waits for a reply that only the receive thread will read (its ``done`` still held)."""
        return any(done.locked() for done in self._followers)

    def _follow(self, done: threading.Lock) -> None:
        with self._count_lock:
            self._followers = (*self._followers, done)

    def _unfollow(self, done: threading.Lock) -> None:
        with self._count_lock:
            followers = list(self._followers)
            followers.remove(done)
            self._followers = tuple(followers)

    @contextmanager
    def following(self, done: threading.Lock) -> Iterator[None]:
        """A wait for the call ``done`` completes that does not read the bus: the receive thread does not stand
        aside until it is released."""
        self._follow(done)
        try:
            yield
        finally:
            self._unfollow(done)

    def wait(self, done: threading.Lock, timeout: float | None, reply_id: int, head: bytes) -> bool:
        """Wait until ``done`` is released (the reply's delivery completes the call) or ``timeout`` seconds pass;
        whether it was. While the lead is free this thread reads the bus: a frame with identifier ``reply_id``
        whose data begin with ``head`` (the reply's first two bytes) it handles itself; anything else it hands over
        with the lead to the receive thread, and follows."""
        now = time.monotonic()
        deadline = None if timeout is None else now + timeout
        if threading.get_ident() == self._ident:  # a handler of the receive thread: nobody else reads
            return done.acquire(True, -1 if timeout is None else max(0.0, timeout))
        self._led_at = now
        lead = self._lead
        if not lead.acquire(False):
            self._follow(done)
            if not lead.acquire(False):  # tried again once counted: a leader leaving now sees it and wakes the reader
                try:
                    return done.acquire(True, -1 if timeout is None else max(0.0, timeout))
                finally:
                    self._unfollow(done)
            self._unfollow(done)
        outcome = _LATE
        try:
            outcome = self._read_for(done, deadline, reply_id, head)
        finally:
            if outcome != _HANDED:
                lead.release()
                if self._followers and self._followed():
                    self._handoff.put(None)  # they wait for the bus to be read: wake the receive thread
        if outcome == _DONE:
            self.led += 1
            return True
        remaining = None if deadline is None else deadline - time.monotonic()
        if outcome == _LATE:  # the deadline passed (or the transport closes: the node's close completes the call)
            return done.acquire(True, -1 if remaining is None else max(0.0, remaining))
        try:  # the receive thread holds the lead now, and reads until this call is done
            return done.acquire(True, -1 if remaining is None else max(0.0, remaining))
        finally:
            self._unfollow(done)  # counted by _read_for before it handed the lead over

    def _read_for(self, done: threading.Lock, deadline: float | None, reply_id: int, head: bytes) -> int:
        """Read as the leader until the call is done, its deadline passes, or a frame for someone else comes."""
        size = len(head)
        while True:
            if done.acquire(False):
                return _DONE
            if self._stop.is_set():
                return _LATE
            remaining = POLL if deadline is None else min(POLL, deadline - time.monotonic())
            if remaining <= 0:
                return _LATE
            frame = self._recv(remaining)
            if frame is None:
                continue
            if frame.arbitration_id == reply_id and frame.data[:size] == head and frame.is_extended_id:
                self._dispatch(frame)  # its own reply, as the receive thread would handle it; done is released
                continue
            self._follow(done)  # this caller follows now: the receive thread must not stand aside
            self.handed += 1
            self._handoff.put(frame)
            return _HANDED
