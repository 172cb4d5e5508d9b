"""What the CAN-Zenoh bridge (server/bridge.py) holds for one CAN node it mirrors on Zenoh: its declarations, how
far it has read the node's object table, and how its claim of the node's name stands."""

from __future__ import annotations

import time
from typing import Any

from asm_py.remote import RemoteObject
from asm_py.transport.zenoh_claim import CLAIM_SETTLE, CLAIM_WAIT, Holding

from .bridge_outlets import Outlet

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
