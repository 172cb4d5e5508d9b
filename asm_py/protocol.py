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

from typing import NamedTuple

from ._contract import (
    HEADER_SIZE,
    KIND_MASK,
    KIND_SHIFT,
    LOCAL_CLASS_BASE,
    MAX_ERROR_TEXT,
    MAX_MESSAGE,
    MAX_TXN,
    METHOD_MASK,
    TIMEOUT_FLAG_MASK,
    TIMEOUT_FLAG_SHIFT,
    TIMEOUT_FOREVER,
    TIMEOUT_LONGEST,
    VERSION,
    VERSION_SHIFT,
    WRITES,
    Kind,
    LookupFlag,
    Method,
    ObjectKind,
    Status,
    StatusFlag,
)
from .errors import AsmError, MessageTooLarge

__all__ = [
    "FOREVER", "HEADER_SIZE", "LOCAL_CLASS_BASE", "MAX_ERROR_TEXT", "MAX_MESSAGE", "MAX_TXN", "TIMEOUT_FLAG", "VERSION",
    "WRITES", "Kind", "LookupFlag", "Message", "Method", "ObjectKind", "ProtocolError", "Status", "StatusFlag",
    "check_size", "decode", "decode_timeout", "encode", "encode_timeout", "first_byte", "has_timeout", "kind_of",
    "reply_head", "reply_to", "too_large", "txn_of", "with_txn",
]  # fmt: skip

FOREVER = TIMEOUT_FOREVER
"""Timeout byte meaning 'block without limit'."""
TIMEOUT_FLAG = TIMEOUT_FLAG_MASK << TIMEOUT_FLAG_SHIFT
"""Byte 1's flag: a timeout byte follows the header."""


class ProtocolError(AsmError, ValueError):
    """Bytes that are not a valid ASM message of a version this implementation speaks."""


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
        return TIMEOUT_LONGEST
    mantissa = (ms >> (exponent - 1)) - 16
    return min((exponent << 4) | mantissa, TIMEOUT_LONGEST)


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
    return (VERSION << VERSION_SHIFT) | (kind << KIND_SHIFT) | method


def kind_of(raw: bytes) -> int | None:
    """The kind of a message, read from its first byte without decoding the rest (None for no bytes)."""
    return (raw[0] >> KIND_SHIFT) & KIND_MASK if raw else None


def version_of(raw: bytes) -> int:
    """The protocol version in byte 0 of a message (at least one byte)."""
    return raw[0] >> VERSION_SHIFT


def method_of(raw: bytes) -> int:
    """The method in byte 0 of a message (at least one byte)."""
    return raw[0] & METHOD_MASK


def txn_of(raw: bytes) -> int:
    """The transaction id in byte 1 of a message (at least two bytes)."""
    return raw[1] & MAX_TXN


def has_timeout(raw: bytes) -> bool:
    """Whether byte 1 of a request says a timeout byte follows the header (at least two bytes)."""
    return bool(raw[1] & TIMEOUT_FLAG)


def with_txn(raw: bytes, txn: int) -> bytes:
    """``raw`` with its transaction id replaced by ``txn``, the timeout flag kept (a bridge's or a client's)."""
    return raw[:1] + bytes(((raw[1] & TIMEOUT_FLAG) | (txn & MAX_TXN),)) + raw[2:]


def encode(message: Message) -> bytes:
    """The wire bytes of ``message``; ValueError if a field is out of range."""
    if not 0 <= message.method <= METHOD_MASK:
        raise ValueError(f"method {message.method} does not fit 4 bits")
    if not 0 <= message.txn <= MAX_TXN:
        raise ValueError(f"transaction id {message.txn} does not fit 7 bits")
    third = message.status if message.kind == Kind.REPLY else message.class_id
    if not 0 <= third <= 0xFF or not 0 <= message.object_id <= 0xFF:
        raise ValueError("class ID, status and object ID are single bytes")
    timeout = message.timeout
    timed = timeout is not None
    head = bytes(
        (
            first_byte(int(message.kind), message.method),
            (TIMEOUT_FLAG if timed else 0) | message.txn,
            third,
            message.object_id,
        )
    )
    if timeout is not None:
        if message.kind == Kind.REPLY or not 0 <= timeout <= 0xFF:
            raise ValueError("a timeout byte belongs to requests and fits one byte")
        head += bytes((timeout,))
    return head + message.data


def decode(data: bytes | bytearray | memoryview) -> Message:
    """Parse wire bytes; ProtocolError for a short message or a version this implementation does not speak."""
    raw = data if type(data) is bytes else bytes(data)
    if len(raw) < HEADER_SIZE:
        raise ProtocolError(f"message of {len(raw)} bytes is shorter than the {HEADER_SIZE}-byte header")
    version = version_of(raw)
    if version != VERSION:
        raise ProtocolError(f"protocol version {version} is not supported (this node speaks {VERSION})")
    kind = (raw[0] >> KIND_SHIFT) & KIND_MASK  # at least a header's bytes: never None as kind_of's can be
    method = method_of(raw)
    timed = has_timeout(raw)
    offset = HEADER_SIZE
    timeout = None
    if timed:
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
    return bytes((first_byte(Kind.REPLY, method_of(request)), txn_of(request), status, request[3]))


def reply_to(request: Message, status: int = Status.OK, data: bytes = b"") -> Message:
    """The reply message for ``request``."""
    return Message(Kind.REPLY, request.method, request.txn, 0, request.object_id, status, None, data)
