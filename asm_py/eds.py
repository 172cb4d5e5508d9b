"""The event-driven service (paper section 4.2): a service whose body runs once per firing of its event.

Every firing while the service runs is delivered to ``handle`` exactly once, in order, even when firings arrive
faster than ``handle`` returns: they wait in a bounded queue (``max_pending``; on overflow the oldest is discarded
and counted in ``overruns``, so a slow handler can never grow memory).

Firings that arrive while the service is *suspended* follow ``while_suspended``:

- ``"drop"`` (default): they are discarded and counted in ``dropped``. A paused service does not wait on its event,
  so, as in the paper, it does not see those firings; a resumed gait continues from where it paused instead of
  replaying the ticks it missed.
- ``"coalesce"``: of the firings during one suspension only the latest is kept, and handled once on resume (the
  others count as ``dropped``): "something happened while paused, here is the newest value". Firings queued
  before the suspension are still handled.
- ``"queue"``: all are kept (within ``max_pending``) and handled in order on resume.

Firings before ``start`` or after ``stop`` are never handled.

``inline=True`` runs ``handle`` in the thread that fires the event, and the service has no thread of its own. The
semantics above are unchanged (one firing, one ``handle``, in order, never two at once; firings while suspended
follow the policy and are handled on resume, in the thread that resumes it); what changes is the cost: a simulator
ticking 128 module automata pays a function call per module instead of a thread handoff, and a process hosting many
modules no thread per service (issue 31: threads of a 128-module robot no more than of a 32-module one).
``handle`` must then be short and must not block. ``request_stop`` still never waits: with a firing being handled
in another thread, that thread ends the service when its ``handle`` returns.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from typing import Any, Literal

from .attribute import Attribute
from .clock import Clock
from .service import Service

log = logging.getLogger("asm_py.eds")

SuspendedPolicy = Literal["drop", "coalesce", "queue"]


class EventDrivenService(Service):
    """Runs ``handle(value)`` once per firing of ``event`` while running; see the module docstring."""

    def __init__(
        self,
        name: str,
        event: Attribute,
        *,
        handler: Callable[[Any], None] | None = None,
        while_suspended: SuspendedPolicy = "drop",
        max_pending: int = 64,
        inline: bool = False,
        clock: Clock | None = None,
    ) -> None:
        if while_suspended not in ("drop", "coalesce", "queue"):
            raise ValueError(f"while_suspended must be 'drop', 'coalesce' or 'queue', not {while_suspended!r}")
        if max_pending < 1:
            raise ValueError(f"max_pending must be at least 1, not {max_pending}")
        super().__init__(name, clock=clock if clock is not None else event.clock)
        self.event = event
        self.while_suspended: SuspendedPolicy = while_suspended
        self.max_pending = max_pending
        self._handler = handler
        self._pending: deque[Any] = deque()
        self._unlisten: Callable[[], None] | None = None
        self._tail_is_coalesced = False  # the newest pending firing arrived while suspended (coalesce policy)
        self.inline = inline
        # one handle() at a time, whichever thread runs it; re-entrant so that a start whose own on_start fires the
        # event still handles that firing inline, as before
        self._handling = threading.RLock()
        self.dropped = 0
        self.overruns = 0
        self.handled = 0

    def handle(self, value: Any) -> None:
        """The body of the service, run in its thread once per firing; default: the ``handler`` given."""
        if self._handler is None:
            raise NotImplementedError(f"{type(self).__name__} needs a handle() method or a handler")
        self._handler(value)

    def run(self, *params: Any) -> None:
        mon = self._mon
        pending = self._pending

        def ready() -> bool:
            return self._stop_requested or (self._running and bool(pending))

        while True:
            with mon:
                mon.wait_for(ready, None, interruptible=False)
                if self._stop_requested:
                    return
            with self._handling:  # taken before popping, so an inline firing cannot overtake this one
                with mon:
                    value = pending.popleft()
                self.handle(value)
                self.handled += 1

    def _is_software(self) -> bool:
        return not self.inline  # inline: firings are handled in the firing thread, no thread of its own

    def stop(self, timeout: float | None = None, *, wait: bool = True) -> None:
        if not self.inline:
            super().stop(timeout, wait=wait)
            return
        self._ask_to_stop()
        with self._handling:  # a firing being handled in another thread ends first (this thread's own: re-entrant)
            if self._started:
                self._finish()

    def request_stop(self) -> None:
        if not self.inline:
            super().request_stop()
            return
        asked, _ = self._ask_to_stop()
        if asked and self._handling.acquire(blocking=False):  # else the handler in flight ends it (_end_if_asked)
            try:
                self._end_if_asked()
            finally:
                self._handling.release()

    def _end_if_asked(self) -> None:
        """With ``_handling`` held: finish an inline service whose stop was asked while a firing was handled."""
        if self._stop_requested and self._started:
            self._finish()

    def resume(self, *, wait: bool = True) -> None:
        super().resume(wait=wait)
        if self.inline:
            self._drain()  # firings kept while suspended ("coalesce", "queue"), in this thread

    def _drain(self) -> None:
        """Handle the queued firings in this thread (an inline service has no thread of its own)."""
        mon = self._mon
        with self._handling:
            while True:
                with mon:
                    if self._stop_requested or not self._running or not self._pending:
                        break
                    value = self._pending.popleft()
                if not self._handle_one(value):
                    break
            self._end_if_asked()

    def _handle_one(self, value: Any) -> bool:
        """``handle`` one firing (``_handling`` held); a failure stops the service (False), as in its thread."""
        try:
            self.handle(value)
            self.handled += 1
        except Exception as exc:
            self._last_error = exc
            log.exception("service %r failed and stopped", self.name)
            self.stop(wait=False)
            return False
        return True

    def start(self, *params: Any, wait: bool = True) -> None:
        """As Service.start; an inline firing from another thread waits until the start is complete: the service
        listens to its event from ``_starting`` on, before ``on_start`` (a phase automaton's initialisation) has
        run, and a tick handled in between would run a half-initialised service."""
        with self._handling:
            super().start(*params, wait=wait)
            if self.inline:  # a stop asked meanwhile could not take _handling (held here): it takes effect now
                self._end_if_asked()

    def _starting(self, *params: Any) -> None:
        self._pending.clear()
        self._tail_is_coalesced = False
        self._unlisten = self.event.on_change(self._on_firing)

    def _resuming(self) -> None:
        self._tail_is_coalesced = False

    def _stopped(self) -> None:
        if self._unlisten is not None:
            self._unlisten()
            self._unlisten = None
        with self._handling:  # an inline handle() in flight finishes before the service counts as stopped
            pass

    def _handle_inline(self, value: Any) -> bool:
        """Handle a firing in this thread; False if the service was suspended meanwhile (then it is queued)."""
        with self._handling:
            if self._stop_requested:
                self._end_if_asked()
                return True
            if not self._running or self._pending:
                return False
            if self._handle_one(value):
                self._end_if_asked()
        return True

    def _on_firing(self, value: Any) -> None:
        if self.inline:
            # The common case of an inline service — started, running, nothing queued — decided under
            # ``_handling`` alone: the flags it reads are the ones _handle_inline reads there (without the monitor
            # as well, whose Python-level enter and exit were a tenth of a 128-module tick; issue 31).
            with self._handling:
                if self._running and self._started and not self._stop_requested and not self._pending:
                    if self._handle_one(value) and self._stop_requested:
                        self._end_if_asked()
                    return
        mon = self._mon
        with mon.lock:
            if not self._started or self._stop_requested:
                return
            pending = self._pending
            inline = self.inline and self._running and not pending
        if inline and self._handle_inline(value):
            return
        with mon:
            if not self._started or self._stop_requested:
                return
            if not self._running:
                if self.while_suspended == "drop":
                    self.dropped += 1
                    return
                if self.while_suspended == "coalesce":
                    if self._tail_is_coalesced:
                        pending[-1] = value
                        self.dropped += 1
                        return
                    self._tail_is_coalesced = True
            pending.append(value)
            if len(pending) > self.max_pending:
                pending.popleft()
                self.overruns += 1
            mon.notify_all()
            running = self._running
        if self.inline and running:
            self._drain()
