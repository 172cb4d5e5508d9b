"""How a Zenoh node's subscribers and queryable hand what arrives to Python: a ring of samples (or queries) that a
thread of the entity's own drains.

zenoh-python's default for a Python callback hands every item to a thread of its own through a channel of 256 that
blocks when full. Two things follow, both measured:

- **A hung handler stops its whole session.** A handler that blocks (a user's change callback waiting on
  something) fills the channel; Zenoh's receive task then blocks on it, and with it every reply and every e-stop on
  that link. tests/transport/test_zenoh_hung_handlers.py reproduced it twice: a tool whose subscription's listener
  hung timed out on a remote get and never heard the e-stop; a module whose set listener hung under a tool's sets
  never heard the e-stop.
- **A handler a little slower than its sender costs two thread switches per item.** Once the channel is full, each
  item taken wakes the receive task to put one more: bench/remote.py's receiver spent 2.2 µs of CPU per update
  against raw Zenoh's 1.1 µs, most of it in the kernel's futex calls (issue 31).

A ``RingChannel`` never blocks Zenoh's task: past ``BACKLOG`` items not yet taken, the oldest is dropped. For a
publication that is what best-effort delivery already allows (an attribute's newest value wins over an unread one);
for a request it is an overload the sender sees (a dropped query ends its get with no reply at once). The drain
takes what is queued without releasing the interpreter lock between items.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from .zenoh_watch import direct

log = logging.getLogger("asm_py.transport.zenoh")

BACKLOG = 4096
"""Items a subscriber or queryable holds for a handler that has not taken them yet (past it, the oldest is dropped)."""


def drained(declare: Callable[..., Any], key: str, handle: Callable[[Any], None], *, payload: bool = False,
            **options: Any) -> Any:  # fmt: skip
    """``declare(key, ring, **options)`` (a subscriber or a queryable) with a ring of ``BACKLOG``, and a thread
    that calls ``handle`` on each item in order — with ``payload``, on each sample's payload bytes — until the
    entity is undeclared or its session closes. Returns the entity."""
    entity = declare(key, zenoh.handlers.RingChannel(BACKLOG), **options)
    thread = threading.Thread(target=_drain, args=(entity.handler, handle, key, payload), name=f"asm-zenoh {key}",
                              daemon=True)  # fmt: skip
    thread.start()
    return entity


def _drain(ring: Any, handle: Callable[[Any], None], what: str, payload: bool) -> None:
    recv, try_recv = ring.recv, ring.try_recv
    try:
        while True:
            item = recv()  # waits with the interpreter lock released
            while item is not None:
                try:
                    handle(item.payload.to_bytes() if payload else item)
                except Exception:
                    log.exception("the handler of %s failed", what)
                item = try_recv()  # what else is queued, without giving up the lock between items
    except zenoh.ZError:
        return  # undeclared, or its session closed: the ring is gone


def _ignore(reply: zenoh.Reply) -> None:
    """The (absent) reply to a request that wants none."""


IGNORE_REPLIES = direct(_ignore)
"""The handler of a get whose replies nobody reads: run on Zenoh's thread, where a plain callback would have
zenoh-python start a Python thread for each get, alive until its query ends (12,288 sets without a reply took 2.2 s
and left 8,000 threads waiting on a module that had stopped answering; with this one, 0.44 s)."""
