"""The unified ASM message: one binary format for every transport (see docs/protocol.md, the normative spec).

A 4-byte header, an optional 1-byte timeout, then data encoded by the object's codec::

    byte 0   VV KK MMMM   version (2 bits, = 1) | kind (2 bits) | method (4 bits)
    byte 1   T SSSSSSS    T: a timeout byte follows the header | transaction id (0–127)
    byte 2   class ID     requests and publications;  status  in replies
    byte 3   object ID
    [byte 4  timeout]     present when T = 1
    data …

Kinds: 0 request (no reply), 1 request, reply wanted (the paper's reply flag), 2 reply, 3 publication. The
transaction id pairs a reply with its request on one client port; in a publication it is a sequence number.
A get or set of a value of up to 4 bytes is 8 bytes: one classic CAN frame each way.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

from .errors import AsmError, MessageTooLarge

VERSION = 1
HEADER_SIZE = 4
MAX_TXN = 0x7F
MAX_MESSAGE = 4096
"""The largest ASM message in bytes, header included, on every transport and through every bridge. A sender refuses
a longer message before sending it (TOO_LARGE); a receiver drops it at its edge, so no layer ever buffers more."""


class ProtocolError(AsmError, ValueError):
    """Bytes that are not a valid ASM message of a version this implementation speaks."""


class Kind(IntEnum):
    REQUEST = 0
    """A request whose sender wants no reply."""
    REQUEST_REPLY = 1
    """A request whose sender waits for a reply (the paper's reply flag)."""
    REPLY = 2
    """The answer to a REQUEST_REPLY, with a status in byte 2."""
    PUBLICATION = 3
    """A value an attribute publishes to its subscribers (method PUBLISH)."""


class Method(IntEnum):
    LOOKUP = 0
    """Find an object by name (data: UTF-8 name, object ID 0) or describe one by ID (no data)."""
    GET = 1
    """Read an attribute's value and make it invalid (blocks on a sync_get attribute)."""
    SET = 2
    """Write an attribute's value (data: the value; blocks on a sync_set attribute while valid)."""
    RESET = 3
    """Reset an attribute or a service."""
    START = 4
    """Start a service (data: its parameters, encoded by its parameter codec)."""
    STOP = 5
    """Stop a service; with a reply wanted, the reply comes once it has stopped."""
    SUSPEND = 6
    """Suspend a service."""
    RESUME = 7
    """Resume (continue) a suspended service."""
    STATUS = 8
    """Read flags: attribute valid; service started, running, failed (reply data: flags byte, then error text)."""
    WAIT = 9
    """Wait for the next firing of an event (reply data: the firing's value)."""
    PEEK = 10
    """Read an attribute's value without consuming it (for monitors)."""
    PUBLISH = 11
    """A publication (kind 3): data is the attribute's current value."""


class Status(IntEnum):
    OK = 0
    TIMEOUT = 1
    SERVICE_ERROR = 2
    TYPE_ERROR = 3
    VALUE_ERROR = 4
    NOT_FOUND = 5
    UNSUPPORTED = 6
    BAD_MESSAGE = 7
    BUSY = 8
    INTERNAL = 9
    READ_ONLY = 10
    """A remote SET or RESET of an attribute that only its node writes (a measurement, a checksum, a state)."""
    ESTOP = 11
    """Refused: the node's emergency stop is latched, and the request would move a joint (or load a gait)."""
    LOCKED = 12
    """Refused: another client holds the lease this request needs (the data names the holder)."""
    TOO_LARGE = 13
    """The message is longer than :data:`MAX_MESSAGE` bytes (answered at the edge that saw it, before forwarding)."""


class ObjectKind(IntEnum):
    """What a lookup reply says an object is."""

    ATTRIBUTE = 0
    EVENT = 1
    SERVICE = 2


FOREVER = 0xFF
"""Timeout byte meaning 'block without limit'."""


def encode_timeout(seconds: float | None) -> int:
    """The timeout byte for ``seconds`` (None: forever), rounded *down* so a server gives up before its client.

    Byte b = (e << 4) | m: e = 0 gives m milliseconds (0–15, 0 = do not block); e ≥ 1 gives (16 + m) << (e - 1) ms,
    up to 491,520 ms for 0xFE; 0xFF is forever.
    """
    if seconds is None:
        return FOREVER
    ms = int(max(0.0, seconds) * 1000)
    if ms < 16:
        return ms
    exponent = ms.bit_length() - 4  # so that (ms >> (exponent - 1)) is in 16..31
    if exponent > 15:
        return 0xFE
    mantissa = (ms >> (exponent - 1)) - 16
    return min((exponent << 4) | mantissa, 0xFE)


def decode_timeout(code: int) -> float | None:
    """Seconds for a timeout byte (None: forever)."""
    if code == FOREVER:
        return None
    exponent, mantissa = code >> 4, code & 0x0F
    ms = mantissa if exponent == 0 else (16 + mantissa) << (exponent - 1)
    return ms / 1000


class Message(NamedTuple):
    """One ASM message, decoded (a named tuple: immutable and cheap to make on the hot path)."""

    kind: int
    """Request, request with reply, reply or publication."""
    method: int
    """A :class:`Method` value (kept as an int, so an unknown method can still be answered UNSUPPORTED)."""
    txn: int = 0
    """Transaction id 0–127 (publications: sequence number mod 128)."""
    class_id: int = 0
    """The object's class ID (requests, publications); 0 in replies."""
    object_id: int = 0
    """The object's ID on its node; 0 addresses the node itself, or 'the object of this class' in a group."""
    status: int = Status.OK
    """Outcome, replies only."""
    timeout: int | None = None
    """The raw timeout byte when present (see :func:`encode_timeout`), else None."""
    data: bytes = b""
    """The payload: a value encoded by the object's codec, a name, parameters or an error text."""

    @property
    def wants_reply(self) -> bool:
        return self.kind == Kind.REQUEST_REPLY

    @property
    def timeout_seconds(self) -> float | None:
        """Seconds the server may block on this request (None: forever, also when no timeout was sent)."""
        return None if self.timeout is None else decode_timeout(self.timeout)


def first_byte(kind: int, method: int) -> int:
    """Byte 0 of a message — version, kind, method — laid out in this one place (hot paths build headers in place)."""
    return (VERSION << 6) | (kind << 4) | method


def kind_of(raw: bytes) -> int | None:
    """The kind of a message, read from its first byte without decoding the rest (None for no bytes)."""
    return (raw[0] >> 4) & 0x03 if raw else None


def encode(message: Message) -> bytes:
    """The wire bytes of ``message``; ValueError if a field is out of range."""
    if not 0 <= message.method <= 0x0F:
        raise ValueError(f"method {message.method} does not fit 4 bits")
    if not 0 <= message.txn <= MAX_TXN:
        raise ValueError(f"transaction id {message.txn} does not fit 7 bits")
    third = message.status if message.kind == Kind.REPLY else message.class_id
    if not 0 <= third <= 0xFF or not 0 <= message.object_id <= 0xFF:
        raise ValueError("class ID, status and object ID are single bytes")
    has_timeout = message.timeout is not None
    head = bytes(
        (
            first_byte(int(message.kind), message.method),
            (0x80 if has_timeout else 0) | message.txn,
            third,
            message.object_id,
        )
    )
    if has_timeout:
        if message.kind == Kind.REPLY or not 0 <= message.timeout <= 0xFF:  # type: ignore[operator]
            raise ValueError("a timeout byte belongs to requests and fits one byte")
        head += bytes((message.timeout,))  # type: ignore[arg-type]
    return head + message.data


def decode(data: bytes | bytearray | memoryview) -> Message:
    """Parse wire bytes; ProtocolError for a short message or a version this implementation does not speak."""
    raw = data if type(data) is bytes else bytes(data)
    if len(raw) < HEADER_SIZE:
        raise ProtocolError(f"message of {len(raw)} bytes is shorter than the {HEADER_SIZE}-byte header")
    version = raw[0] >> 6
    if version != VERSION:
        raise ProtocolError(f"protocol version {version} is not supported (this node speaks {VERSION})")
    kind = kind_of(raw)
    method = raw[0] & 0x0F
    has_timeout = bool(raw[1] & 0x80)
    offset = HEADER_SIZE
    timeout = None
    if has_timeout:
        if kind == Kind.REPLY or len(raw) < HEADER_SIZE + 1:
            raise ProtocolError("timeout flag on a reply, or a missing timeout byte")
        timeout = raw[HEADER_SIZE]
        offset += 1
    if kind == Kind.REPLY:
        return Message(kind, method, raw[1] & MAX_TXN, 0, raw[3], raw[2], None, raw[offset:])
    return Message(kind, method, raw[1] & MAX_TXN, raw[2], raw[3], Status.OK, timeout, raw[offset:])


def too_large(length: int, what: object = None) -> str:
    """Why a message of ``length`` bytes (sent for ``what``) is refused: one wording at every edge that enforces
    MAX_MESSAGE."""
    prefix = "" if what is None else f"{what}: "
    return f"{prefix}message of {length} bytes exceeds the {MAX_MESSAGE}-byte maximum"


def check_size(raw: bytes, what: object = None) -> bytes:
    """``raw`` if it fits one ASM message; MessageTooLarge, before anything is sent, otherwise."""
    if len(raw) > MAX_MESSAGE:
        raise MessageTooLarge(too_large(len(raw), what))
    return raw


def reply_head(request: bytes, status: int) -> bytes:
    """The 4-byte reply header to the raw request ``request`` (at least 4 bytes), for an edge that answers a
    request it will not decode: same method, transaction and object ID, the given status."""
    return bytes((first_byte(Kind.REPLY, request[0] & 0x0F), request[1] & MAX_TXN, status, request[3]))


def reply_to(request: Message, status: int = Status.OK, data: bytes = b"") -> Message:
    """The reply message for ``request``."""
    return Message(Kind.REPLY, request.method, request.txn, 0, request.object_id, status, None, data)


# Classes with a fixed ID on every node, so that "joint.angle" means the same thing on every module and a group
# message can address "the object of this class" on each member. Other classes get node-local IDs from 0x80 up,
# in the order they are registered.
WELL_KNOWN_CLASSES: dict[str, int] = {
    "node": 0x01,
    "heartbeat": 0x02,
    "estop": 0x03,
    "joint.goal": 0x10,
    "joint.angle": 0x11,
    "joint.limits": 0x12,
    "joint.torque": 0x13,
    "servo.service": 0x14,
    "gait.table": 0x20,
    "gait.phase": 0x21,
    "gait.direction": 0x22,
    "gait.state": 0x23,
    "gait.service": 0x24,
    "gait.tick": 0x25,
    "gait.checksum": 0x26,
    "gait.staged": 0x27,
    "gait.staged_checksum": 0x28,
    "gait.activate": 0x29,
    "gait.lease": 0x2A,
    "gait.switch": 0x2B,
    "gait.cycle": 0x2C,
    "gait.mode": 0x2D,
    "gait.done": 0x2E,
    "gait.signal": 0x2F,
    "sensor.contact": 0x30,
}
LOCAL_CLASS_BASE = 0x80
