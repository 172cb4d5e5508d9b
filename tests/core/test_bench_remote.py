"""bench/remote.py fails when its server is gone instead of hanging: a stop-54 run sat ten minutes on raw gets of a
server that had exited, each waiting Zenoh's default 10 s for a reply that could not come."""

from __future__ import annotations

import time

import pytest

from asm_py import Node
from asm_py.transport.zenoh import ZenohTransport
from bench.remote import raw_get
from server.child import free_port


def test_a_raw_get_nobody_answers_is_an_error_within_its_timeout() -> None:
    transport = ZenohTransport(listen=[f"tcp/127.0.0.1:{free_port()}"])
    node = Node("bench-client", transport)  # as the bench's client opens its session
    try:
        began = time.monotonic()
        with pytest.raises(RuntimeError, match=r"no reply in 0\.3 s"):
            raw_get(transport.session, timeout=0.3)
        assert time.monotonic() - began < 5.0
    finally:
        node.close()
