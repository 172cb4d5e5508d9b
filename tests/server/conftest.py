"""The server layer's fixtures: a robot of eight module runtimes on a simulated CAN bus (no physics), closed even
when the test fails."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from asm_module.bus_robot import BusRobot


@pytest.fixture
def robot() -> Iterator[BusRobot]:
    made = BusRobot(8)
    try:
        yield made
    finally:
        made.close()
