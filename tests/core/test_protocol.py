"""The wire format: golden vectors (shared with other implementations), timeouts, and malformed input."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from asm_py import codec_from_descriptor, parse_codec
from asm_py.protocol import (
    FOREVER,
    Kind,
    Message,
    Method,
    ProtocolError,
    Status,
    decode,
    decode_timeout,
    encode,
    encode_timeout,
)

from ..helpers import VECTORS

MESSAGES = json.loads((VECTORS / "messages.json").read_text())["messages"]
CODECS = json.loads((VECTORS / "codecs.json").read_text())["codecs"]


def message_of(fields: dict) -> Message:
    return Message(Kind(fields["kind"]), fields["method"], fields["txn"], fields["class_id"], fields["object_id"],
                   fields["status"], fields["timeout"], bytes.fromhex(fields["data_hex"]))  # fmt: skip


@pytest.mark.parametrize("vector", MESSAGES, ids=[v["name"][:40] for v in MESSAGES])
def test_golden_messages(vector: dict) -> None:
    message = message_of(vector["message"])
    assert encode(message).hex() == vector["hex"]
    assert decode(bytes.fromhex(vector["hex"])) == message


@pytest.mark.parametrize("vector", CODECS, ids=[v["spec"] for v in CODECS])
def test_golden_codecs(vector: dict) -> None:
    codec = parse_codec(vector["spec"])
    value = bytes.fromhex(vector["value"]) if vector["spec"] == "bytes" else vector["value"]
    assert codec.encode(value).hex() == vector["hex"]
    assert codec.descriptor().hex() == vector["descriptor_hex"]
    assert codec_from_descriptor(bytes.fromhex(vector["descriptor_hex"])) == codec
    assert codec.encode(codec.decode(bytes.fromhex(vector["hex"]))).hex() == vector["hex"]


def test_a_four_byte_get_and_set_fit_one_classic_can_frame() -> None:
    for name in ("get request", "get reply", "set request without reply", "set request with reply"):
        vector = next(v for v in MESSAGES if v["name"].startswith(name))
        assert len(bytes.fromhex(vector["hex"])) <= 8, name


@given(st.floats(min_value=0, max_value=600))
def test_timeout_byte_rounds_down_within_a_sixteenth(seconds: float) -> None:
    granted = decode_timeout(encode_timeout(seconds))
    assert granted is not None
    assert granted <= seconds + 1e-9
    if seconds < 491.52:
        assert granted >= seconds * (1 - 1 / 16) - 0.001


def test_timeout_byte_is_monotonic_and_forever_is_reserved() -> None:
    values = [decode_timeout(code) for code in range(0xFF)]
    assert values == sorted(values)
    assert encode_timeout(None) == FOREVER and decode_timeout(FOREVER) is None
    assert encode_timeout(0) == 0 and encode_timeout(1e9) == 0xFE


messages = st.builds(
    Message,
    kind=st.sampled_from(list(Kind)),
    method=st.integers(0, 15),
    txn=st.integers(0, 127),
    class_id=st.integers(0, 255),
    object_id=st.integers(0, 255),
    status=st.integers(0, 255),
    timeout=st.none() | st.integers(0, 255),
    data=st.binary(max_size=64),
)


@given(messages)
def test_every_message_round_trips(message: Message) -> None:
    # a reply carries a status and no class ID or timeout; a request carries no status
    if message.kind == Kind.REPLY:
        message = message._replace(class_id=0, timeout=None)
    else:
        message = message._replace(status=Status.OK)
    assert decode(encode(message)) == message


@given(st.binary(max_size=40))
def test_random_bytes_decode_or_raise_protocol_error(data: bytes) -> None:
    try:
        decode(data)
    except ProtocolError:
        pass


@pytest.mark.parametrize(
    "raw",
    [
        b"",
        b"\x51\x00\x11",
        bytes([0x11, 0, 0, 0]),
        bytes([0xD1, 0, 0, 0]),
        bytes([0x61, 0x80, 0, 0, 5]),
        bytes([0x51, 0x80, 0x11, 0x01]),
    ],
    ids=["empty", "short", "version 0", "version 3", "timeout on a reply", "missing timeout byte"],
)
def test_malformed_messages_are_refused(raw: bytes) -> None:
    with pytest.raises(ProtocolError):
        decode(raw)


def test_encode_checks_ranges() -> None:
    bad_messages = [
        Message(Kind.REQUEST, 16),
        Message(Kind.REQUEST, Method.GET, txn=128),
        Message(Kind.REQUEST, Method.GET, class_id=256),
        Message(Kind.REPLY, Method.GET, timeout=1),
    ]
    for bad in bad_messages:
        with pytest.raises(ValueError):
            encode(bad)
