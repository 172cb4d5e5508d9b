"""The gait table as a module stores it: the bytes of its ``gait.table`` attribute (docs/protocol.md §9).

A module needs only its own automaton — its phase and direction are attributes of their own — so the table is the
list of states in a compact little-endian layout that firmware can parse without a TOML reader:

    offset 0   2 bytes  magic b"GT"
    offset 2   1 byte   version (1)
    offset 3   2 bytes  uint16 number of states N (1..1024)
    then N × 9 bytes:   float32 angle (degrees), float32 duration (seconds, at least one control tick:
                        0.02), uint8 interpolation (0 step, 1 linear)

Version 2 holds a program (asm_module/program.py): several modes (gaits), a sequence, sensor- and
neighbour-driven states and one-shot modes. A program that version 1 can say is always written as version 1, so
its bytes and checksum do not change:

    offset 0   2 bytes  magic b"GT"
    offset 2   1 byte   version (2)
    offset 3   1 byte   uint8 number of modes M (1..16)
    offset 4   1 byte   uint8 sequence length Q (0..32)
    then Q × 3 bytes:   uint8 mode, uint16 cycles
    then per mode:      float32 phase, int8 direction, uint8 flags (bit 0: one-shot), uint16 number of states N,
                        then N × 19 bytes: float32 angle, float32 duration (0: none, only with an event), uint8
                        interpolation, uint8 event (0 none, 1 contact, 2 no_contact, 3 at_goal, 4 torque,
                        5 neighbour, 6 signal), uint8 on timeout (0 next, 1 stop), float32 tolerance or
                        threshold, int8 neighbour (relative ID), uint16 neighbour state or signal number,
                        uint8 signal emitted on entering the state (0: none)
    at most 1024 states over all modes

``checksum`` is CRC-32 (IEEE 802.3, zlib's) of those bytes: a deploying tool reads ``gait.checksum`` back from each
module to verify the transfer before it starts anything.

A deployment *stages* a table first (``gait.staged``, activated later by one broadcast): the staged record is a
12-byte header — magic b"GS", version 1, uint32 deploy ID (non-zero), float32 phase in [0, 1), int8 direction ±1 —
followed by the table. A staged record must fit one ASM message (protocol.MAX_MESSAGE with its 4-byte header), so a
staged table holds at most MAX_STAGED_STATES states.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

from asm_py.automaton import Interpolation, PhaseState
from asm_py.protocol import HEADER_SIZE, MAX_MESSAGE

from .program import (
    EVENTS,
    MAX_MODES,
    MAX_SEQUENCE,
    MIN_DURATION,
    MIN_DURATION_TEXT,
    OUTCOMES,
    Mode,
    ModeState,
    Program,
    Until,
    program_of,
)

MAGIC = b"GT"
VERSION = 1
MAX_STATES = 1024
_HEADER = struct.Struct("<2sBH")
_STATE = struct.Struct("<ffB")
VERSION_PROGRAM = 2
_PROGRAM = struct.Struct("<2sBBB")
_STEP = struct.Struct("<BH")
_MODE = struct.Struct("<fbBH")
_STATE2 = struct.Struct("<ffBBBfbHB")
_BY_CODE: dict[int, Interpolation] = {0: "step", 1: "linear"}
_INTERPOLATION = {name: code for code, name in _BY_CODE.items()}
STAGED_MAGIC = b"GS"
_STAGED = struct.Struct("<2sBIfb")
MAX_STAGED_STATES = (MAX_MESSAGE - HEADER_SIZE - _STAGED.size - _HEADER.size) // _STATE.size
"""The most states a staged table can have: the staged record travels as one message of at most MAX_MESSAGE."""


def encode_table(states: Sequence[PhaseState]) -> bytes:
    """The bytes of a table of scalar states (ValueError if it cannot be one)."""
    if not 1 <= len(states) <= MAX_STATES:
        raise ValueError(f"a gait table has 1..{MAX_STATES} states, not {len(states)}")
    out = bytearray(_HEADER.pack(MAGIC, VERSION, len(states)))
    for state in states:
        if isinstance(state.target, tuple):
            raise ValueError("a module's gait table drives one joint: its targets are single angles")
        out += _STATE.pack(state.target, state.duration, _INTERPOLATION[state.interpolation])
    return bytes(out)


def decode_table(data: bytes) -> list[PhaseState]:
    """The states in ``data``; ValueError saying what is wrong with a malformed table."""
    if len(data) < _HEADER.size:
        raise ValueError(f"a gait table needs at least {_HEADER.size} bytes, got {len(data)}")
    magic, version, count = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ValueError(f"not a gait table (magic {magic!r}, expected {MAGIC!r})")
    if version != VERSION:
        raise ValueError(f"gait table version {version} is not supported (this module reads version {VERSION})")
    if not 1 <= count <= MAX_STATES:
        raise ValueError(f"a gait table has 1..{MAX_STATES} states, not {count}")
    expected = _HEADER.size + count * _STATE.size
    if len(data) != expected:
        raise ValueError(f"a gait table of {count} states is {expected} bytes, got {len(data)}")
    states = []
    for k in range(count):
        angle, duration, code = _STATE.unpack_from(data, _HEADER.size + k * _STATE.size)
        if code not in _BY_CODE:
            raise ValueError(f"state {k}: unknown interpolation code {code}")
        if not (math.isfinite(angle) and math.isfinite(duration) and duration >= MIN_DURATION):
            raise ValueError(f"state {k}: angle {angle} and duration {duration} must be finite, the duration at "
                             f"least one control tick ({MIN_DURATION_TEXT})")  # fmt: skip
        states.append(PhaseState(float(angle), float(duration), _BY_CODE[code]))
    return states


def encode_program(program: Program) -> bytes:
    """The bytes of a module's program: version 1 when it is one periodic time-driven mode, else version 2."""
    if program.simple:
        return encode_table(program.modes[0].phase_states())
    if sum(len(m.states) for m in program.modes) > MAX_STATES:
        raise ValueError(f"a program has at most {MAX_STATES} states over all its modes")
    out = bytearray(_PROGRAM.pack(MAGIC, VERSION_PROGRAM, len(program.modes), len(program.sequence)))
    for mode, cycles in program.sequence:
        out += _STEP.pack(mode, cycles)
    for mode in program.modes:
        out += _MODE.pack(mode.phase, mode.direction, int(mode.one_shot), len(mode.states))
        for st in mode.states:
            until = st.until or Until("contact")
            event = 0 if st.until is None else EVENTS.index(until.event) + 1
            out += _STATE2.pack(st.target, st.duration or 0.0, _INTERPOLATION[st.interpolation], event,
                                OUTCOMES.index(until.on_timeout), until.value, until.neighbour if event == 5 else 0,
                                until.state if event in (5, 6) else 0, st.emit)  # fmt: skip
    return bytes(out)


def decode_program(data: bytes) -> Program:
    """The program in ``data`` (a version 1 or 2 table); ValueError saying what is wrong with a malformed one."""
    if len(data) >= 3 and data[:2] == MAGIC and data[2] == VERSION:
        return program_of(decode_table(data))
    if len(data) < _PROGRAM.size:
        raise ValueError(f"a gait table needs at least {_PROGRAM.size} bytes, got {len(data)}")
    magic, version, count, steps = _PROGRAM.unpack_from(data)
    if magic != MAGIC:
        raise ValueError(f"not a gait table (magic {magic!r}, expected {MAGIC!r})")
    if version != VERSION_PROGRAM:
        raise ValueError(f"gait table version {version} is not supported (this module reads versions 1 and 2)")
    if not 1 <= count <= MAX_MODES or steps > MAX_SEQUENCE:
        raise ValueError(f"a program has 1..{MAX_MODES} modes and 0..{MAX_SEQUENCE} sequence steps")
    offset = _PROGRAM.size

    def need(size: int, what: str) -> None:
        if offset + size > len(data):
            raise ValueError(f"the gait table ends inside {what} (byte {offset}, {len(data)} bytes)")

    need(steps * _STEP.size, "the sequence")
    sequence = [_STEP.unpack_from(data, offset + k * _STEP.size) for k in range(steps)]
    offset += steps * _STEP.size
    modes, total = [], 0
    for m in range(count):
        need(_MODE.size, f"mode {m}")
        phase, direction, flags, n = _MODE.unpack_from(data, offset)
        offset += _MODE.size
        total += n
        if n < 1 or total > MAX_STATES or flags & ~1:
            raise ValueError(f"mode {m}: {n} states and flags {flags:#x} (1..{MAX_STATES} states in all, flag bit 0)")
        need(n * _STATE2.size, f"the states of mode {m}")
        states = []
        for k in range(n):
            angle, duration, interp, event, timeout, value, neighbour, state, emit = _STATE2.unpack_from(data, offset)
            offset += _STATE2.size
            if interp not in _BY_CODE or event > len(EVENTS) or timeout >= len(OUTCOMES):
                raise ValueError(f"mode {m} state {k}: codes interpolation {interp}, event {event}, timeout {timeout}")
            unused = (timeout if event == 0 else 0, value if event not in (3, 4) else 0,
                      neighbour if event != 5 else 0, state if event not in (5, 6) else 0)  # fmt: skip
            if any(unused):
                raise ValueError(f"mode {m} state {k}: a field its event does not use is not 0 (one table, one form)")
            try:
                kind = EVENTS[event - 1] if event else None
                watch = (neighbour, state) if kind == "neighbour" else (-1, state) if kind == "signal" else (-1, 0)
                until = None if kind is None else Until(kind, value, *watch, OUTCOMES[timeout])
                states.append(ModeState(angle, duration if duration != 0 else None, _BY_CODE[interp], until, emit))
            except ValueError as exc:
                raise ValueError(f"mode {m} state {k}: {exc}") from None
        try:
            modes.append(Mode(tuple(states), phase, direction, bool(flags & 1)))
        except ValueError as exc:
            raise ValueError(f"mode {m}: {exc}") from None
    if offset != len(data):
        raise ValueError(f"a gait table of these modes is {offset} bytes, got {len(data)}")
    program = Program(tuple(modes), tuple((int(a), int(b)) for a, b in sequence))
    if program.simple:  # one program, one form (and one checksum)
        raise ValueError("one periodic time-driven mode without a sequence is a version-1 table, not version 2")
    return program


def checksum(data: bytes) -> int:
    """CRC-32 of a table's bytes, as the module reports it in ``gait.checksum``."""
    return zlib.crc32(data) & 0xFFFFFFFF


def rounded(states: Sequence[PhaseState]) -> list[PhaseState]:
    """The states as a module holds them after the float32 round trip: the simulation runs exactly these."""
    return decode_table(encode_table(states))


@dataclass(frozen=True)
class Staged:
    """A staged deployment as a module holds it (``gait.staged``)."""

    deploy_id: int
    """Non-zero; a ``gait.activate`` carrying it makes this table, phase and direction the running gait."""
    phase: float
    direction: int
    table: bytes
    """The gait table bytes (layout above)."""


def encode_staged(staged: Staged) -> bytes:
    """The bytes of ``gait.staged`` (ValueError when a field is out of its domain or the record is too long)."""
    if not 1 <= staged.deploy_id <= 0xFFFFFFFF:
        raise ValueError(f"a deploy ID is 1..2^32-1, not {staged.deploy_id}")
    if not 0.0 <= staged.phase < 1.0 or staged.direction not in (1, -1):
        raise ValueError(f"phase must be in [0, 1) and direction ±1, not {staged.phase}, {staged.direction}")
    data = _STAGED.pack(STAGED_MAGIC, VERSION, staged.deploy_id, staged.phase, staged.direction) + staged.table
    if len(data) + HEADER_SIZE > MAX_MESSAGE:
        limit = MAX_MESSAGE - HEADER_SIZE
        raise ValueError(f"a staged table of {len(data)} bytes is too long; one message carries at most {limit} "
                         f"bytes ({MAX_STAGED_STATES} states of a version-1 table)")  # fmt: skip
    return data


def decode_staged(data: bytes) -> Staged:
    """The staged record in ``data`` (its table checked too); ValueError saying what is wrong."""
    if len(data) < _STAGED.size:
        raise ValueError(f"a staged gait needs at least {_STAGED.size} bytes, got {len(data)}")
    magic, version, deploy_id, phase, direction = _STAGED.unpack_from(data)
    if magic != STAGED_MAGIC or version != VERSION:
        raise ValueError(f"not a staged gait of version {VERSION} (magic {magic!r}, version {version})")
    if deploy_id == 0 or not 0.0 <= phase < 1.0 or direction not in (1, -1):
        raise ValueError(f"staged deploy ID {deploy_id}, phase {phase}, direction {direction} out of their domains")
    table = bytes(data[_STAGED.size :])
    decode_program(table)
    return Staged(deploy_id, float(phase), int(direction), table)
