"""Factories of connected transports for the conformance suite and the node tests: every transport, same tests."""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from asm_py.transport import MemoryNetwork, MemoryTransport, Transport
from asm_py.transport.can import CanTransport
from asm_py.transport.zenoh import ZenohTransport
from server.child import free_port

_names = itertools.count()


def fresh_name(prefix: str) -> str:
    """A name no other test of this run has used (a python-can virtual channel, a network namespace)."""
    return f"{prefix}-{os.getpid()}-{next(_names)}"


FAST_BEATS = {"heartbeat_period": 0.05, "missed_heartbeats": 40}
"""A CAN transport's heartbeats for the tests' in-process peers: found within 0.05 s, lost after 2 s of silence (not
0.2 s: a loaded machine starves a process that long, and a lost peer fails every call in flight to it)."""


@contextmanager
def memory_transports() -> Iterator[Callable[[], Transport]]:
    network = MemoryNetwork()
    yield lambda: MemoryTransport(network)


@contextmanager
def zenoh_transports() -> Iterator[Callable[[], Transport]]:
    """The first transport listens on a free loopback port; every later one connects to it (peer mode). Every node
    is a module of one robot: each may serve and call the others."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    made: list[Transport] = []

    def make() -> Transport:
        where = {"listen": [endpoint]} if not made else {"connect": [endpoint]}
        transport = ZenohTransport(role="module", **where)
        made.append(transport)
        return transport

    yield make


@contextmanager
def can_transports(interface: str = "virtual", **options) -> Iterator[Callable[[], Transport]]:
    """Transports with node IDs 1, 2, … on a fresh in-process channel (fast heartbeats for the tests): python-can's
    ``virtual`` bus, or ``asm_sim``, which filters like a CAN controller.
    (FAST_BEATS: with 4 beats, 0.2 s, a starved process lost its "server" and failed the call in flight, ``node
    'server' left``, reproduced with a GIL switch interval of 0.1 s and a busy thread.)"""
    channel = fresh_name("asm-test")
    ids = itertools.count(1)
    settings = {**FAST_BEATS, **options}
    yield lambda: CanTransport(next(ids), interface=interface, channel=channel, **settings)


@contextmanager
def sim_can_transports(**options) -> Iterator[Callable[[], Transport]]:
    with can_transports("asm_sim", **options) as make:
        yield make


@contextmanager
def pushed_can_transports(**options) -> Iterator[Callable[[], Transport]]:
    """``asm_sim`` with no reader thread per transport: the channel's dispatch thread pushes every frame (how the
    simulated robot hosts its modules)."""
    with can_transports("asm_sim", receive_thread=False, **options) as make:
        yield make


FACTORIES = {"memory": memory_transports, "zenoh": zenoh_transports, "can": can_transports,
             "can-sim": sim_can_transports, "can-pushed": pushed_can_transports}  # fmt: skip
