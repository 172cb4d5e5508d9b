"""A publication subscription's delivery from Zenoh to Python: a ring of samples, drained by the subscription's thread.

zenoh-python's default for a Python callback hands every sample to a thread of its own through a channel of 256
samples that blocks when full. Two things follow, both measured:

- **A hung listener stops its whole session.** A change listener that blocks (a user's callback waiting on
  something) fills the channel; Zenoh's receive task then blocks on it, and with it every reply and every e-stop on
  that link (tests/transport/test_zenoh_subscription.py reproduced it: a remote get timed out, the e-stop never came).
- **A listener a little slower than the publisher costs two thread switches per sample.** Once the channel is full,
  each sample taken wakes the receive task to put one more: bench/remote.py's receiver spent 2.2 µs of CPU per
  update against raw Zenoh's 1.1 µs, most of it in the kernel's futex calls (issue 31).

A ``RingChannel`` never blocks Zenoh's task: past ``PUBLICATION_BACKLOG`` unread samples the oldest is dropped —
what a publication already allows (it is sent best-effort, and an attribute's newest value wins over an unread one).
The drain takes what is queued without releasing the interpreter lock between samples.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

log = logging.getLogger("asm_py.transport.zenoh")

PUBLICATION_BACKLOG = 4096
"""Samples a subscription holds for a listener that has not taken them yet (past it, the oldest is dropped)."""


def deliver_publications(session: zenoh.Session, key: str, on_bytes: Callable[[bytes], None], what: str) -> Any:
    """Subscribe to ``key`` and call ``on_bytes(payload)`` for each sample, in order, on a thread of its own that
    ends when the subscription is undeclared or its session closes. Returns the subscriber."""
    subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(PUBLICATION_BACKLOG))
    drain = threading.Thread(target=_drain, args=(subscriber.handler, on_bytes, what), name=f"asm-subscription {what}",
                             daemon=True)  # fmt: skip
    drain.start()
    return subscriber


def _drain(handler: Any, on_bytes: Callable[[bytes], None], what: str) -> None:
    recv, try_recv = handler.recv, handler.try_recv
    try:
        while True:
            sample = recv()  # waits with the interpreter lock released
            while sample is not None:
                try:
                    on_bytes(sample.payload.to_bytes())
                except Exception:
                    log.exception("subscriber of %s failed", what)
                sample = try_recv()  # what else is queued, without giving up the lock between samples
    except zenoh.ZError:
        return  # undeclared, or its session closed: the ring is gone
