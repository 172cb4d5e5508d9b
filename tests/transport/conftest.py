"""Fixtures of the transport tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import zenoh

from asm_py.transport.zenoh_config import make_config

from ..transports import free_port
from .virtual_can import Bus


@pytest.fixture
def bus() -> Iterator[Bus]:
    """A virtual CAN channel, its nodes closed at the end."""
    made = Bus()
    yield made
    made.close()


@pytest.fixture
def router() -> Iterator[str]:
    """A Zenoh router (a plain Python session in router mode) on a free loopback port; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(make_config(mode="router", listen=[endpoint]))
    try:
        yield endpoint
    finally:
        session.close()
