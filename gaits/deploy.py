"""Deploying a gait to modules — simulated or real, over any transport — through their ASM objects only.

For each module: stop its gait, write ``gait.table`` (its automaton as gaits.wire bytes), ``gait.phase`` and
``gait.direction``, then read ``gait.checksum`` back and compare it with the CRC-32 of what was sent. Only when every
module verified does :func:`start_all` start them together, with one group message (one broadcast frame on CAN).
A module that is missing, refuses a value or reports another checksum fails the whole deployment before anything
starts: a robot never runs half a gait.
"""

from __future__ import annotations

from collections.abc import Callable

from asm_py import Node
from asm_py.errors import AsmError
from asm_py.transport.base import BROADCAST

from .model import Gait
from .table import phase_states
from .wire import checksum, encode_table


class DeployError(AsmError):
    """A module could not be given its part of the gait (which module and why are in the message)."""


def module_name(module_id: int) -> str:
    """The node name of gait module ``module_id`` (the studio and ``asm-module`` use it: m1, m2, …)."""
    return f"m{module_id}"


def module_tables(gait: Gait) -> dict[int, bytes]:
    """Each module's ``gait.table`` bytes."""
    return {a.id: encode_table(phase_states(gait.automata[a.automaton])) for a in gait.modules}


def deploy(
    node: Node,
    gait: Gait,
    *,
    name_of: Callable[[int], str] = module_name,
    direction: int = 1,
    progress: Callable[[int, int, str], None] | None = None,
    timeout: float = 2.0,
) -> dict[int, int]:
    """Transfer and verify; returns module id → verified checksum. DeployError names the module that failed.

    ``progress(done, total, message)`` is called after each module. ``direction`` -1 deploys the gait reversed.
    """
    tables = module_tables(gait)
    verified: dict[int, int] = {}
    total = len(gait.modules)
    for done, assignment in enumerate(gait.modules, start=1):
        name = name_of(assignment.id)
        data = tables[assignment.id]
        try:
            node.lookup(name, "gait.service", timeout=timeout).stop(wait=True)
            node.lookup(name, "gait.table", timeout=timeout).set(data, wait=True)
            node.lookup(name, "gait.phase", timeout=timeout).set(assignment.phase, wait=True)
            node.lookup(name, "gait.direction", timeout=timeout).set(assignment.direction * direction, wait=True)
            reported = node.lookup(name, "gait.checksum", timeout=timeout).peek()
        except (AsmError, TimeoutError, ValueError, LookupError) as exc:
            raise DeployError(f"module {assignment.id} ({name}): {exc}") from exc
        if reported != checksum(data):
            raise DeployError(
                f"module {assignment.id} ({name}): checksum {reported:#010x}, sent {checksum(data):#010x}"
            )
        verified[assignment.id] = reported
        if progress is not None:
            progress(done, total, f"module {assignment.id} verified ({len(data)} bytes, crc {reported:#010x})")
    return verified


def start_all(node: Node, group: str = BROADCAST) -> None:
    """Start every module's gait at once: one group message, each module starts at its own gait.phase."""
    node.group(group).service("gait.service").start()


def stop_all(node: Node, group: str = BROADCAST) -> None:
    node.group(group).service("gait.service").stop()
