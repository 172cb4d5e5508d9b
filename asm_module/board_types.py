"""What an emulated board and its owner exchange (asm_module/emulator.py's :class:`~asm_module.emulator.Cortex` and
asm_module/emulated.py): how a core stops — a fault, or a reset a new core on the same flash follows — the joint's
side of its pins, and the tick statistics the emulator keeps. Apart so the owner's types are read without the core.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


class FirmwareFault(RuntimeError):
    """The emulated core stopped on something a board would fault on (or hang in Default_Handler for)."""


class BoardReset(Exception):
    """The board reset itself: the independent watchdog expired, or the image asked (SCB AIRCR SYSRESETREQ). A new
    :class:`Cortex` on the same flash is the board after it."""


@dataclass
class Joint:
    """The joint's side of the pins: ``command(degrees)`` when the servo's pulse changes, ``relax()`` when the
    pulse stops, ``read()`` the (angle in degrees, contact) the encoder and the switch show now."""

    command: Callable[[float], None]
    relax: Callable[[], None]
    read: Callable[[], tuple[float, bool]]


@dataclass
class TickStats:
    """Instructions per call of asm_module_tick (the control tick): how many ticks, their sum and the worst."""

    ticks: int = 0
    total: int = 0
    worst: int = 0
