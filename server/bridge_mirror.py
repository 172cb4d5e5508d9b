"""What the CAN-Zenoh bridge (server/bridge.py) holds for one CAN node it mirrors on Zenoh: its declarations, how
far it has read the node's object table, and how its claim of the node's name stands."""

from __future__ import annotations

import logging
import time
from typing import Any

from asm_py.remote import RemoteObject
from asm_py.transport.zenoh_claim import CLAIM_SETTLE, CLAIM_WAIT, Holding

from .bridge_outlets import Outlet

log = logging.getLogger("server.bridge")

TABLE_BACKOFF = (0.05, 2.0)
"""First and longest pause between attempts to read a table (doubling)."""


class Mirror:
    """What the bridge declared on Zenoh for one CAN node, and how far it has read the node's object table."""

    def __init__(self, name: str, node_id: int) -> None:
        self.name = name
        self.node_id = node_id
        self.entities: list[Any] = []
        self.objects: dict[int, RemoteObject] = {}
        self.outlets: dict[int, Outlet] = {}
        """Each published object's declared publishers (made at its first publication)."""
        self.table_read = False
        self.next_attempt = 0.0
        self.backoff = TABLE_BACKOFF[0]
        self.attempts = 0
        self.holding = Holding()
        """Requests and messages for the node while its claim is unsettled: answered only if the bridge keeps it
        (``holding.kept``: the name is the bridge's; until then it looks again at ``claim_due``)."""
        self.claim_due = time.monotonic() + CLAIM_SETTLE
        self.claim_deadline = time.monotonic() + CLAIM_WAIT
        self.last_look: set[str] = set()
        """The claimants its last look saw (a rival it saw and the next look misses is looked for again)."""
        self.unreadable: set[int] = set()
        """Objects whose description the bridge could not read (each said once at WARNING)."""

    def object_read(self, object_id: int, client: RemoteObject) -> None:
        self.objects[object_id] = client
        self.backoff = TABLE_BACKOFF[0]

    def lookup_failed(self, object_id: int, exc: Exception, now: float, *, unreadable: bool) -> None:
        """A table lookup failed: asked again after the backoff (doubling). A lost frame or a busy module is
        usual (DEBUG); a description this side cannot read is not (a firmware's codec unknown here): the user is
        told once, as this object and every later one reach no Zenoh subscriber until it reads."""
        self.attempts += 1
        self.next_attempt = now + self.backoff
        self.backoff = min(TABLE_BACKOFF[1], self.backoff * 2)
        if unreadable and object_id not in self.unreadable:
            self.unreadable.add(object_id)
            log.warning("cannot read object %d of %s's table (%s): it and the objects after it are not bridged; "
                        "asked again every %g s", object_id, self.name, exc, TABLE_BACKOFF[1])  # fmt: skip
        else:
            log.debug("reading the table of %s (object %d): %s", self.name, object_id, exc)
