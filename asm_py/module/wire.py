"""The gait table as a module stores it: the bytes of its ``gait.table`` attribute (docs/protocol.md §9).

A module needs only its own automaton — its phase and direction are attributes of their own — so the table is the
list of states in a compact little-endian layout that firmware can parse without a TOML reader:

    offset 0   2 bytes  magic b"GT"
    offset 2   1 byte   version (1)
    offset 3   2 bytes  uint16 number of states N (1..1024)
    then N × 9 bytes:   float32 angle (degrees), float32 duration (seconds, > 0), uint8 interpolation (0 step, 1 linear)

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

from ..automaton import PhaseState
from ..protocol import HEADER_SIZE, MAX_MESSAGE

MAGIC = b"GT"
VERSION = 1
MAX_STATES = 1024
_HEADER = struct.Struct("<2sBH")
_STATE = struct.Struct("<ffB")
_INTERPOLATION = {"step": 0, "linear": 1}
_BY_CODE = {code: name for name, code in _INTERPOLATION.items()}
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
        if not (math.isfinite(angle) and math.isfinite(duration) and duration > 0):
            raise ValueError(f"state {k}: angle {angle} and duration {duration} must be finite, duration > 0")
        states.append(PhaseState(float(angle), float(duration), _BY_CODE[code]))  # type: ignore[arg-type]
    return states


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
        states = (len(staged.table) - _HEADER.size) // _STATE.size
        raise ValueError(f"a staged table of {states} states is {len(data)} bytes; one message carries at most "
                         f"{MAX_MESSAGE - HEADER_SIZE} ({MAX_STAGED_STATES} states)")  # fmt: skip
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
    decode_table(table)
    return Staged(deploy_id, float(phase), int(direction), table)
