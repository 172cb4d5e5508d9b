"""The C hot path (asm_py._speedups, issue 31) against the pure-Python path it replaces: the same messages from the
same bytes, the same handling of every kind of frame, and a fallback that is chosen and said when it is missing."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from asm_py import speedups as loader
from asm_py.canbus.ids import CanId, Dest, FrameType, Priority, SystemCode
from asm_py.protocol import MAX_MESSAGE, ProtocolError, decode
from asm_py.transport.can import CanTransport

from ..helpers import ROOT
from ..transports import fresh_name

fast = loader.speedups
needs_c = pytest.mark.skipif(fast is None, reason=f"the C hot path is not built: {loader.REASON}")


@pytest.mark.skipif(shutil.which("gcc") is None or not (Path(sysconfig.get_paths()["include"]) / "Python.h").exists(),
                    reason="no C compiler or no Python headers: the pure-Python path runs")  # fmt: skip
def test_make_built_the_extension() -> None:
    assert loader.COMPILED, loader.REASON


headers = st.binary(min_size=0, max_size=12) | st.builds(
    lambda b0, b1, rest: bytes((b0, b1)) + rest, st.integers(0x40, 0x7F), st.integers(0, 255), st.binary(max_size=40)
)


@needs_c
@settings(max_examples=3000, deadline=None)
@given(raw=headers)
def test_decode_agrees_with_the_python_decoder(raw: bytes) -> None:
    assert fast is not None
    try:
        expected = decode(raw)
    except ProtocolError:
        expected = None
    got = fast.decode(raw)
    assert got == expected
    if got is not None:
        assert type(got) is type(expected) and [type(v) for v in got] == [type(v) for v in expected]  # type: ignore[arg-type]


@needs_c
def test_decode_leaves_what_it_does_not_take_to_the_python_decoder() -> None:
    assert fast is not None
    assert fast.decode(bytearray(b"\x51\x05\x11\x01")) is None  # not bytes
    assert fast.decode(b"\x51\x05\x11\x01" + bytes(MAX_MESSAGE)) is None  # longer than any message: refused before


class Inbox:
    def __init__(self) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.stops: list[tuple[str, str]] = []
        self.peers: list[tuple[str, bool]] = []
        self.publications: list[bytes] = []

    def __call__(self, source: str, data: bytes, respond: object) -> None:
        self.got.append((source, data))


def opened(compiled: bool) -> tuple[CanTransport, Inbox, can.BusABC]:
    bus = can.Bus(interface="virtual", channel=fresh_name("asm-speedups"))
    transport = CanTransport(1, bus=bus, compiled=compiled, heartbeat_period=60)
    inbox = Inbox()
    transport.attach("m1", inbox)
    transport.on_estop(lambda source, reason: inbox.stops.append((source, reason)))
    transport.on_peer(lambda name, alive: inbox.peers.append((name, alive)))
    transport.subscribe("m2", "x", inbox.publications.append, object_id=5)
    return transport, inbox, bus


def frame_of(priority: int, dest_kind: int, dest: int, source: int, kind: int, data: bytes, flags: int) -> can.Message:
    ident = CanId(priority, dest_kind, dest, source, kind).pack()
    return can.Message(arbitration_id=ident, data=data, is_extended_id=not flags & 1, is_error_frame=bool(flags & 2),
                       is_remote_frame=bool(flags & 4))  # fmt: skip


frames = st.builds(
    frame_of,
    st.integers(0, 7),
    st.integers(0, 3),
    st.sampled_from([0, 1, 2, 7, 255]),
    st.sampled_from([0, 1, 2, 3, 255]),
    st.sampled_from([FrameType.SINGLE] * 4 + [FrameType.FIRST, FrameType.LAST]),
    st.sampled_from([b"m2", b"stop", b"\x51\x05\x11\x01", b"\xf0\x00\x11\x05\x01", b"\x61\x01\x00\x01", b""])
    | st.binary(max_size=8),
    st.sampled_from([0] * 6 + [1, 2, 4]),
)


@pytest.fixture(scope="module")
def both() -> Iterator[list[tuple[CanTransport, Inbox]]]:
    """A compiled and a pure-Python transport, fed the same frames for the whole module (state carries over: the
    same state on both sides)."""
    made = [opened(compiled) for compiled in (True, False)]
    heartbeat = frame_of(Priority.HEARTBEAT, Dest.SYSTEM, SystemCode.HEARTBEAT, 2, FrameType.SINGLE, b"m2", 0)
    for transport, _, _ in made:
        transport.on_frame(heartbeat)  # names node 2, so frames from it take the C path
    yield [(transport, inbox) for transport, inbox, _ in made]
    for transport, _, bus in made:
        transport.close()
        bus.shutdown()


@needs_c
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batch=st.lists(frames, max_size=25))
def test_the_receiver_handles_every_frame_as_the_python_path_does(both, batch: list[can.Message]) -> None:
    """The same frames into a compiled and a pure-Python transport: the same messages delivered, e-stops, peers
    and publications, counted alike."""
    outcomes = []
    for transport, inbox in both:
        assert (transport._fast is not None) == transport.compiled
        for frame in batch:
            transport.on_frame(frame)
        counts = (transport.frames_received, transport.handler_errors, transport.reassembler.partials)
        outcomes.append(
            (inbox.got, inbox.stops, inbox.peers, inbox.publications, counts, sorted(transport._last_heard))
        )
    assert outcomes[0] == outcomes[1]


@needs_c
def test_a_gateway_that_overrides_on_message_still_decides() -> None:
    seen: list[tuple[int, int, int, bytes]] = []

    class Gateway(CanTransport):
        def on_message(self, source_id: int, dest_kind: int, dest: int, data: bytes) -> None:
            seen.append((source_id, dest_kind, dest, data))

    bus = can.Bus(interface="virtual", channel=fresh_name("asm-speedups"))
    gateway = Gateway(1, bus=bus, heartbeat_period=60)
    gateway.attach("gw", lambda *args: None)
    gateway.accept_node_id(7)
    gateway._alive.add(2)
    try:
        gateway.on_frame(frame_of(Priority.REQUEST, Dest.NODE, 7, 2, FrameType.SINGLE, b"\x51\x05\x11\x01", 0))
        assert seen == [(2, Dest.NODE, 7, b"\x51\x05\x11\x01")]
    finally:
        gateway.close()
        bus.shutdown()


def run_python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT,
                          env={**os.environ, **env})  # fmt: skip


def test_the_pure_python_path_is_chosen_and_said_when_asked() -> None:
    done = run_python("import asm_py.speedups as s, logging; print(s.COMPILED, s.REASON)", ASM_PURE_PYTHON="1")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False ASM_PURE_PYTHON is set"


def test_a_missing_extension_falls_back_and_warns() -> None:
    blocker = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'asm_py._speedups':\n"
        "            raise ImportError('no such extension (blocked by the test)')\n"
        "sys.meta_path.insert(0, Block())\n"
        "import asm_py.speedups as s\n"
        "from asm_py import Attribute, Node\n"
        "from asm_py.transport.can import CanTransport\n"
        "t = CanTransport(1, interface='virtual', channel='fallback-test')\n"
        "n = Node('m1', t)\n"
        "print(s.COMPILED, t.compiled, t._fast, n._decode)\n"
        "n.close()\n"
    )
    done = run_python(blocker)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False False None None"
    assert "the pure-Python path runs: the extension is not built" in done.stderr
