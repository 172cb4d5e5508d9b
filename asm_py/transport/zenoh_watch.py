"""A Zenoh publisher that knows whether anyone subscribes to it, so a JSON view is formatted only while watched.

A node's own Zenoh transport (asm_py.transport.zenoh) and the bridge's outlets (server.bridge_outlets) each publish
a JSON view beside every binary publication, and formatting a view nobody reads cost the bridge of a running
128-module robot more than forwarding the frames (issue 31). Both follow the view's subscribers the same way — a
declared publisher and a matching listener — and this is that one piece. Its listener runs on the Zenoh thread that
learns of the change (:func:`direct`), not on a Python thread of its own as zenoh-python's default gives every
callback.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import zenoh


def direct(callback: Callable[[Any], None]) -> zenoh.handlers.Callback[Any]:
    """``callback`` run on the Zenoh thread that received the item, not a Python thread of its own (zenoh-python's
    default: one per callback, two per bridged module): only for callbacks that never block."""
    return zenoh.handlers.Callback(callback, indirect=False)


MAX_VIEWS = 1024
"""JSON views a node's transport keeps declared under names no published attribute has (past it, the oldest are
forgotten: asm_py/transport/zenoh.py's ``publish`` takes any name)."""


class WatchedPublisher:
    """A declared publisher and whether a subscriber matches it now (``watched``); ``close`` undeclares both."""

    __slots__ = ("_heard", "_listener", "publisher", "watched")

    def __init__(self, publisher: zenoh.Publisher) -> None:
        self.publisher = publisher
        self.watched = False
        self._heard = False
        # The listener first, then the current status: a change after this point is heard, and a change heard
        # before the status is read is not overwritten by it.
        self._listener = publisher.declare_matching_listener(direct(self._matching))
        matching = bool(publisher.matching_status.matching)  # pyright: ignore[reportAttributeAccessIssue]  # zenoh's stub says bool; it is a MatchingStatus
        if not self._heard:
            self.watched = matching

    def _matching(self, status: zenoh.MatchingStatus) -> None:
        self._heard = True
        self.watched = status.matching

    def put(self, payload: bytes | str) -> None:
        """Put ``payload``; a put that meets ``close`` in another thread is refused as one after it would be (a
        ``zenoh.ZError``): zenoh-python says "Already mutably borrowed" while the undeclare holds the publisher."""
        try:
            self.publisher.put(payload)
        except RuntimeError as exc:
            if not _in_use(exc):
                raise
            raise zenoh.ZError(f"publisher being undeclared: {exc}") from exc

    def close(self) -> None:
        """Undeclare both. Another thread may be in ``put`` (the bridge's reader, as a module leaves): zenoh-python
        then refuses the undeclare ("Already borrowed"), so it is tried again until that put is done; should it
        never be, the publisher is dropped and Zenoh undeclares it with its last reference."""
        _undeclare(self._listener)
        _undeclare(self.publisher)


def _undeclare(entity: Any, seconds: float = 1.0) -> None:
    deadline = time.monotonic() + seconds
    while True:
        try:
            entity.undeclare()
            return
        except RuntimeError as exc:
            if not _in_use(exc):
                raise
            if time.monotonic() > deadline:
                return  # still in use: dropped, not undeclared
            time.sleep(0.001)


def _in_use(exc: RuntimeError) -> bool:
    """Whether zenoh-python refused a call because another thread holds the entity ("Already borrowed", "Already
    mutably borrowed"): a put and an undeclare that met, not a failure."""
    return "borrow" in str(exc)
