"""A request over Zenoh to a module nobody serves now: Zenoh finds no queryable and ends the query at once, so the
call fails at once and says so, not "no reply within 30s" after 4 s (a user review of the studio's firmware update
read that on every module while the boards were unreachable)."""

from __future__ import annotations

import time

import pytest

from asm_py.errors import AsmTimeout
from asm_py.node import Node
from asm_py.protocol import Method

from ..transports import zenoh_transports


def test_a_request_nobody_can_answer_fails_at_once_saying_so() -> None:
    with zenoh_transports() as make:
        client = Node("client", make())
        try:
            began = time.monotonic()
            with pytest.raises(AsmTimeout, match=r"nothing answered after [\d.e-]+s \(m9 is not reachable now\)"):
                client.port("m9").call(Method.GET, 0x11, 2, timeout=30.0)
            assert time.monotonic() - began < 20.0
        finally:
            client.close()
