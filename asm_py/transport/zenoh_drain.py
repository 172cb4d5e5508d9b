"""Where zenoh-python's default handler costs too much: a publication subscription's ring of samples, drained by a
thread of its own, and the handler of replies nobody reads (``IGNORE_REPLIES``).

zenoh-python's default for a Python callback hands every sample to a thread of its own through a channel of 256 that
blocks when full. Two things follow, both measured:

- **A hung listener stops its whole session.** A change listener that blocks (a user's callback waiting on
  something) fills the channel; Zenoh's receive task then blocks on it, and with it every reply and every e-stop on
  that link (tests/transport/test_zenoh_hung_handlers.py reproduced it: a remote get timed out, the e-stop never
  came).
- **A listener a little slower than the publisher costs two thread switches per sample.** Once the channel is full,
  each sample taken wakes the receive task to put one more: bench/remote.py's receiver spent 2.2 µs of CPU per
  update against raw Zenoh's 1.1 µs, most of it in the kernel's futex calls (issue 31).

A ``RingChannel`` never blocks Zenoh's task: past ``BACKLOG`` samples not yet taken, the oldest is dropped, which a
publication already allows (it is sent best-effort, and an attribute's newest value wins over an unread one). The
drain takes what is queued without releasing the interpreter lock between samples.

Only publications: a request or a node leaving must not be dropped (a set lost without its sender knowing, a
blocking call left waiting for a reply that will never come: a review measured both when they were drained this
way). A node's requests, messages and group messages go through queues of their own that refuse (BUSY, for a request
that wants a reply) what they cannot hold (asm_py/transport/zenoh_requests.py), so a handler that hangs under a flood
no longer stops its session; e-stops and liveliness keep zenoh-python's channel, their handlers never block.
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
"""Publications a subscription holds for a listener that has not taken them yet (past it, the oldest is dropped)."""


def drained(declare: Callable[..., Any], key: str, handle: Callable[[bytes], None]) -> Any:
    """``declare(key, ring)`` with a ring of ``BACKLOG``, and a thread that calls ``handle`` on each sample's payload
    in order until the entity is undeclared or its session closes. The thread holds the entity, so it lives on
    while unreferenced (as zenoh-python's callbacks do), and is not a daemon: the interpreter waits for it at exit
    rather than tear it down inside Zenoh's ``recv`` (a daemon one aborted the process at exit, 4 runs in 20)."""
    entity = declare(key, zenoh.handlers.RingChannel(BACKLOG))
    threading.Thread(target=_drain, args=(entity, handle, key), name=f"asm-zenoh {key}").start()
    return entity


def _drain(entity: Any, handle: Callable[[bytes], None], key: str) -> None:
    recv, try_recv = entity.handler.recv, entity.handler.try_recv
    try:
        while True:
            sample = recv()  # waits with the interpreter lock released
            while sample is not None:
                try:
                    handle(sample.payload.to_bytes())
                except BaseException:  # SystemExit too: one failing call must not end the subscription
                    log.exception("a subscriber of %s failed", key)
                sample = try_recv()  # what else is queued, without giving up the lock between samples
    except zenoh.ZError:
        return  # undeclared, or its session closed: the ring is gone


def _ignore(reply: zenoh.Reply) -> None:
    """The (absent) reply to a request that wants none."""


IGNORE_REPLIES = direct(_ignore)
"""The handler of a get whose replies nobody reads (a request that wants none: it runs only for the timeout Zenoh
reports when the get ends). On Zenoh's thread, where a plain callback would have zenoh-python start a Python thread
for each get, alive until its query ends: 12,288 sets without a reply took 2.2-2.8 s, now 0.52-0.60 s."""
