"""A tab closing while a studio thread sends to the page (issue 29's review: "RuntimeError: deque mutated during
iteration" logged on the studio's console when a browser tab was closed; web/viser_events.py).

The race is made to happen every time rather than once in a while: a tab's sender is parked on the page's message
event, as every open tab's is, and the pushing thread is held at the exact point of the race — inside the event's
walk over its waiters — until the tab's sender has been cancelled in viser's loop (its waiter removed), which is
what closing the tab does there."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

from viser._messages import SetGuiPanelLabelMessage

from web.guard import AccessGuard, guarded_server


class _TabClosingHere:
    """A waiter that closes a tab when the event's walk reaches it: the tab's sender is cancelled in the loop, and
    this returns once the loop has removed the sender's waiter from the deque being walked."""

    def __init__(self, loop: asyncio.AbstractEventLoop, sender: Any) -> None:
        self.loop, self.sender = loop, sender
        self.reached = False
        """Whether a thread other than the loop's walked the waiters."""

    def done(self) -> bool:
        try:
            asyncio.get_running_loop()
            return True  # the loop's own walk: nothing races it
        except RuntimeError:
            pass
        self.reached = True
        closed = threading.Event()
        self.loop.call_soon_threadsafe(lambda: (self.sender.cancel(), self.sender.add_done_callback(
            lambda _: closed.set())))  # fmt: skip
        assert closed.wait(10), "the tab's sender was not cancelled"
        return True

    def cancelled(self) -> bool:
        return False


def test_a_message_sent_while_a_tab_closes_raises_nothing_and_reaches_the_other_tabs():
    server = guarded_server(AccessGuard("127.0.0.1"), host="127.0.0.1", port=0, verbose=False)
    try:
        buffer = server._websock_server._broadcast_buffer  # what every tab is sent
        loop = buffer.event_loop
        event = buffer.message_event

        async def park() -> tuple[asyncio.Task[bool], asyncio.Task[bool]]:
            event.clear()
            closing, staying = (asyncio.ensure_future(event.wait()) for _ in range(2))
            await asyncio.sleep(0)  # both parked: their waiters are in the event's deque
            return closing, staying

        closing, staying = asyncio.run_coroutine_threadsafe(park(), loop).result(10)
        probe = _TabClosingHere(loop, closing)
        event._waiters.appendleft(probe)  # the walk meets it first
        buffer.push(SetGuiPanelLabelMessage(label="sent while a tab closes"))  # raised RuntimeError here
        woken = asyncio.run_coroutine_threadsafe(asyncio.wait_for(asyncio.shield(staying), 10), loop)
        assert woken.result(15) is True  # the tab that stays is woken for the message
        asyncio.run_coroutine_threadsafe(_cancel(closing), loop).result(10)  # closed, if it was not yet
        assert closing.done()
    finally:
        server.stop()


async def _cancel(task: asyncio.Task[bool]) -> None:
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
