"""Fragmentation and bounded reassembly of ASM messages over CAN frames (docs/protocol.md, "CAN").

A message that fits one frame is sent as a SINGLE frame, unchanged. A longer one is a FIRST frame — a 4-byte
preamble (total length, uint16 little-endian; CRC-16/CCITT-FALSE of the message, little-endian) and the first bytes
of the message — then MIDDLE frames and a LAST frame carrying nothing but message bytes, the fragment counter in the
identifier running 0, 1, … mod 64. No flow control: the same frames serve one receiver, a group or everyone (MDCN).

On CAN FD a frame's data length must be one of 0-8, 12, 16, 20, 24, 32, 48, 64: the final frame is padded with
zeros to the next such length (the receiver knows the true length from the preamble), and a message whose length
is not a valid FD size travels fragmented, in which case its FIRST frame may complete it on its own.

Efficiency for a 1 KiB message: 1024 / 1028 data bytes, on classic CAN (129 frames) and on FD (17 frames).

The receiver is bounded whatever arrives: one partial message per (source, destination), at most ``max_partials``
of them (the oldest is evicted), none longer than ``max_message`` bytes, each discarded ``timeout`` seconds after
its last fragment; a gap in the counter, an overrun or a CRC mismatch discards the message. A fragment repeated
at once (CAN's double reception, when a transmitter retries after an acknowledgement error) is ignored.
"""

from __future__ import annotations

import binascii
from collections.abc import Iterator
from dataclasses import dataclass, field

from .._contract import MAX_MESSAGE as PROTOCOL_MAX_MESSAGE
from .._contract import REASSEMBLY_TIMEOUT
from .ids import FrameType

PREAMBLE = 4
FD_SIZES = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
MAX_MESSAGE = 0xFFFF


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF), as C firmware commonly has it."""
    return binascii.crc_hqx(data, 0xFFFF)


def fd_size(length: int) -> int:
    """The smallest valid CAN FD data length holding ``length`` bytes."""
    for size in FD_SIZES:
        if size >= length:
            return size
    raise ValueError(f"{length} bytes do not fit one CAN FD frame")


def fits_one_frame(length: int, frame_size: int = 8) -> bool:
    """Whether a message of ``length`` bytes travels as one SINGLE frame (on FD: only at a valid FD length)."""
    return length <= frame_size and (frame_size == 8 or length in FD_SIZES)


def fragment(message: bytes, *, frame_size: int = 8) -> Iterator[tuple[int, int, bytes]]:
    """Yield (frame type, counter, data) for each frame of ``message``; ``frame_size`` 8 (classic) or 64 (FD)."""
    fd = frame_size > 8
    length = len(message)
    if fits_one_frame(length, frame_size):
        yield FrameType.SINGLE, 0, message
        return
    if length > MAX_MESSAGE:
        raise ValueError(f"message of {length} bytes exceeds the {MAX_MESSAGE}-byte maximum")
    first = length.to_bytes(2, "little") + crc16(message).to_bytes(2, "little") + message[: frame_size - PREAMBLE]
    offset = frame_size - PREAMBLE
    counter = 0
    yield FrameType.FIRST, counter, _pad(first, fd)
    while offset < length:
        chunk = message[offset : offset + frame_size]
        offset += frame_size
        counter = (counter + 1) & 0x3F
        yield (FrameType.LAST if offset >= length else FrameType.MIDDLE), counter, _pad(chunk, fd)


def _pad(data: bytes, fd: bool) -> bytes:
    if not fd or len(data) in FD_SIZES:
        return data
    return data + bytes(fd_size(len(data)) - len(data))


def frame_count(length: int, *, frame_size: int = 8) -> int:
    """How many frames a message of ``length`` bytes takes."""
    if fits_one_frame(length, frame_size):
        return 1
    rest = max(0, length - (frame_size - PREAMBLE))
    return 1 + -(-rest // frame_size)


def wire_bytes(length: int, *, frame_size: int = 8) -> int:
    """Data bytes on the bus (preamble and FD padding included) for a message of ``length`` bytes."""
    return sum(len(data) for _, _, data in fragment(bytes(length), frame_size=frame_size))


@dataclass
class _Partial:
    length: int
    crc: int
    data: bytearray
    counter: int
    touched: float
    last_chunk: bytes


@dataclass
class Reassembler:
    """Rebuilds fragmented messages; see the module docstring for the bounds."""

    max_message: int = PROTOCOL_MAX_MESSAGE
    """A first frame announcing more is dropped at once."""
    max_partials: int = 64
    timeout: float = REASSEMBLY_TIMEOUT
    dropped: dict[str, int] = field(default_factory=dict)
    _partials: dict[tuple[int, int, int], _Partial] = field(default_factory=dict)

    def feed(self, key: tuple[int, int, int], frame: int, counter: int, data: bytes, now: float) -> bytes | None:
        """Take one frame from ``key`` = (source, destination kind, destination); return a completed message."""
        if frame == FrameType.SINGLE:
            return bytes(data)
        if frame == FrameType.FIRST:
            return self._first(key, counter, data, now)
        partial = self._partials.get(key)
        if partial is None:
            return self._drop("orphan fragment")
        if counter == partial.counter and partial.last_chunk == data:
            return self._drop("duplicate fragment")  # CAN's double reception: harmless, ignored
        if counter != (partial.counter + 1) & 0x3F:
            del self._partials[key]
            return self._drop("fragment gap")
        partial.counter = counter
        partial.touched = now
        partial.last_chunk = bytes(data)
        partial.data += data
        return self._check(key, partial, frame == FrameType.LAST)

    def _first(self, key: tuple[int, int, int], counter: int, data: bytes, now: float) -> bytes | None:
        current = self._partials.get(key)
        if current is not None and current.counter == 0 and current.last_chunk == data:
            return self._drop("duplicate fragment")
        if current is not None:
            del self._partials[key]
            self._drop("message interrupted")
        if len(data) < PREAMBLE or counter != 0:
            return self._drop("malformed first fragment")
        length = int.from_bytes(data[0:2], "little")
        if length > self.max_message:
            return self._drop("message too long")
        if len(self._partials) >= self.max_partials:
            oldest = min(self._partials, key=lambda k: self._partials[k].touched)
            del self._partials[oldest]
            self._drop("too many partial messages")
        partial = _Partial(length, int.from_bytes(data[2:4], "little"), bytearray(data[PREAMBLE:]), 0, now,
                           bytes(data))  # fmt: skip
        self._partials[key] = partial
        return self._check(key, partial, False)

    def _check(self, key: tuple[int, int, int], partial: _Partial, last: bool) -> bytes | None:
        have = len(partial.data)
        if have < partial.length:  # appending stops here, so a partial never outgrows its length + one frame
            if last:
                del self._partials[key]
                return self._drop("message ended short")
            return None
        del self._partials[key]
        if have - partial.length >= 64:  # more than FD padding: bytes that belong to nothing
            return self._drop("fragment overrun")
        message = bytes(partial.data[: partial.length])
        if crc16(message) != partial.crc:
            return self._drop("crc mismatch")
        return message

    def expire(self, now: float) -> None:
        """Discard partial messages whose last fragment is older than ``timeout``."""
        for key in [k for k, p in self._partials.items() if now - p.touched > self.timeout]:
            del self._partials[key]
            self._drop("reassembly timeout")

    def _drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1
        return None

    @property
    def partials(self) -> int:
        return len(self._partials)

    @property
    def buffered_bytes(self) -> int:
        """Bytes held in partial messages now (what a test bounds)."""
        return sum(len(p.data) for p in self._partials.values())

    @property
    def bound(self) -> int:
        """The most bytes the reassembler can ever hold."""
        return self.max_partials * (self.max_message + 64)
