"""Fixtures of the transport tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from .virtual_can import Bus


@pytest.fixture
def bus() -> Iterator[Bus]:
    """A virtual CAN channel, its nodes closed at the end."""
    made = Bus()
    yield made
    made.close()
