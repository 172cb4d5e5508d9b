"""Remote event WAITs without a thread each.

A WAIT is the most common blocking request (a client waiting for a contact, a gait's end, a trigger), and it only
ever needs the event's next firing or its deadline. Serving each one on a server daemon of its own cost a thread
apiece: 8 modules × 16 pending waits held 128 threads and about 24 MiB in one robot process, for requests that do
nothing until they end. Here a pending wait is a listener on the event plus, with a deadline, an entry in a short
list, and one service thread per node (started with the first such wait) answers the ones whose time runs out.
The node's caps on blocking requests per client and in all still count these waits, so what a client may hold is
unchanged.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .clock import Clock
from .codec import Codec
from .errors import AsmTimeout, ServiceError
from .event import Event
from .service import Service

Answer = Callable[["PendingWait", Exception | None, bytes], None]
"""Called once per wait: (the wait, the failure or None, the encoded value)."""


class PendingWait:
    """One client's WAIT on one event: answered once, at the firing, at its deadline, or never if cancelled."""

    __slots__ = ("_remove", "_taken", "deadline", "request", "respond", "source")

    def __init__(self, source: str, request: Any, respond: Any, deadline: float | None) -> None:
        self.source = source
        self.request = request
        self.respond = respond
        self.deadline = deadline
        self._remove: Callable[[], None] | None = None
        self._taken = False


class EventWaits(Service):
    """The pending WAITs of one node and the one thread that times them out.

    The node admits at most ``max_daemons`` blocking requests, so the waits with a deadline are a short list: a wait
    leaves it the moment it is answered, whichever way, and nothing outlives its wait.
    """

    def __init__(self, name: str, answer: Answer, *, clock: Clock | None = None) -> None:
        super().__init__(f"waits:{name}", clock=clock)
        self._answer = answer
        self._timed: dict[PendingWait, float] = {}  # wait -> deadline, for those not answered yet (the monitor's)
        self._version = 0  # bumped at every new deadline, to wake the thread

    def add(self, wait: PendingWait, event: Event, codec: Codec) -> None:
        """Answer ``wait`` with the event's next firing (encoded with ``codec``) or TIMEOUT at its deadline."""

        def fired(value: Any) -> None:
            if not self._take(wait):
                return
            try:
                data = codec.encode(value)
            except Exception as exc:  # a value the codec refuses is the wait's failure, not the setter's
                self._answer(wait, exc, b"")
                return
            self._answer(wait, None, data)

        remove = event.on_change(fired)
        with self._mon:
            wait._remove = remove
            taken = wait._taken
            if not taken and wait.deadline is not None:
                self._timed[wait] = wait.deadline
                self._version += 1
                self._mon.notify_all()
        if taken:  # it fired between the listener's registration and here
            remove()
            return
        if wait.deadline is not None and not self.started:
            try:
                self.start()
            except ServiceError:  # a concurrent add started it first
                pass

    def cancel(self, wait: PendingWait) -> None:
        """Forget ``wait`` without answering it (its node is closing)."""
        self._take(wait)

    def _take(self, wait: PendingWait) -> bool:
        """Claim ``wait`` for exactly one answer; False if it was already answered or cancelled."""
        with self._mon:
            if wait._taken:
                return False
            wait._taken = True
            remove = wait._remove
            self._timed.pop(wait, None)
        if remove is not None:
            remove()
        return True

    def run(self, *params: Any) -> None:
        mon = self._mon
        while True:
            with mon:
                version = self._version
                first = min(self._timed.values(), default=None)
                timeout = None if first is None else max(0.0, first - self.clock.now())
                mon.wait_for(lambda version=version: self._version != version, timeout)
                due = [wait for wait, deadline in self._timed.items() if self.clock.reached(deadline)]
            for wait in due:
                if self._take(wait):
                    self._answer(wait, AsmTimeout("waiting on the event timed out"), b"")
