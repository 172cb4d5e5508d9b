"""viser's message buffers, made safe to push to from the studio's threads while a browser tab closes.

Every message the page sends (a markdown line, a pose, a notification) is pushed into a viser ``AsyncMessageBuffer``
by whichever thread makes it: the studio's refresh and render threads, viser's callback pool, Zenoh's callbacks.
``push`` sets the buffer's ``message_event``, an ``asyncio.Event``, right there in that thread, and
``asyncio.Event.set`` walks the event's waiters (a deque) to wake them. Each tab's sender waits on that event in
viser's event loop, and when a tab closes its sender is cancelled there, and its waiter is removed from the deque:
the pushing thread, half-way through the deque, failed with "RuntimeError: deque mutated during iteration" and the
studio logged a traceback for the refresh or the drawing it was doing (a review saw it when closing a tab).

:func:`install` gives every buffer viser makes from then on a :class:`LoopSafeEvent`: set from another thread, it
raises its flag at once (the buffer reads it there) and leaves waking the waiters to the loop, the only thread that
touches them. viser has no option for this; the class is patched once, before the studio's server starts.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from typing import Any

_INSTALLED = threading.Lock()


class LoopSafeEvent(asyncio.Event):
    """An asyncio.Event of ``loop`` that any thread may set; its waiters are only ever touched in ``loop``."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__()
        self._owner = loop

    def set(self) -> None:
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:  # a thread with no event loop: the studio's own threads
            running = None
        if running is self._owner:
            super().set()
            return
        if self._value:
            return  # already raised: its waiters are being woken (as Event.set, which wakes them once)
        self._value = True
        with contextlib.suppress(RuntimeError):  # the loop closed (the server stopping): nobody waits any more
            self._owner.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        """In the loop: wake every waiter parked now, even if the flag was lowered since it was raised (a tab's
        sender that woke on the flag and cleared it must not leave another tab's sender asleep)."""
        for waiter in self._waiters:  # asyncio.Event's own deque, in the loop that owns it
            if not waiter.done():
                waiter.set_result(True)


def make_loop_safe(buffer: Any) -> None:
    """Give one viser message buffer a LoopSafeEvent (before anything waits on its event); a buffer of a viser
    that has no such event or loop is left as it is (the page works, with the race)."""
    if isinstance(getattr(buffer, "message_event", None), asyncio.Event) and hasattr(buffer, "event_loop"):
        buffer.message_event = LoopSafeEvent(buffer.event_loop)


def install() -> None:
    """Every viser message buffer made from now on gets a LoopSafeEvent (once per process; idempotent)."""
    from viser.infra import _async_message_buffer as module

    with _INSTALLED:
        cls: Any = module.AsyncMessageBuffer
        if getattr(cls, "_asm_loop_safe", False):
            return
        original = cls.__init__

        def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
            original(self, *args, **kwargs)
            make_loop_safe(self)

        cls.__init__ = __init__
        cls._asm_loop_safe = True
