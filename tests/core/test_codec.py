"""Codecs: every type round-trips through bytes, has the documented size, and rejects what it cannot encode."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from asm_py import (
    BOOL,
    BYTES,
    FLOAT32,
    FLOAT64,
    INT8,
    INT16,
    INT32,
    INT64,
    STR,
    UINT8,
    UINT16,
    UINT32,
    UINT64,
    Attribute,
    Codec,
    codec_from_descriptor,
    float_array,
    parse_codec,
    record,
)
from asm_py.codec import BytesCodec, FloatArrayCodec, FloatCodec, IntCodec, RecordCodec, StrCodec

INTS = [INT8, INT16, INT32, INT64, UINT8, UINT16, UINT32, UINT64]


def values_of(codec: Codec) -> st.SearchStrategy:
    """Values a codec must accept."""
    if codec is BOOL:
        return st.booleans()
    if isinstance(codec, IntCodec):
        return st.integers(codec.min, codec.max)
    if codec is FLOAT32:
        return st.floats(width=32)
    if codec is FLOAT64:
        return st.floats()
    if isinstance(codec, StrCodec):
        return st.text(max_size=40)
    if isinstance(codec, BytesCodec):
        return st.binary(max_size=40)
    if isinstance(codec, FloatArrayCodec):
        return st.lists(values_of(codec.element), min_size=codec.length, max_size=codec.length)
    if isinstance(codec, RecordCodec):
        return st.fixed_dictionaries({name: values_of(c) for name, c in codec.fields})
    raise AssertionError(codec)


def same(a, b) -> bool:
    """Equality in which NaN equals NaN (bytes decide)."""
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, tuple | list) and isinstance(b, tuple | list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    return a == b and type(a) is type(b)


NESTED = record({"pose": float_array(3), "id": UINT8, "label": STR, "inner": record({"ok": BOOL, "blob": BYTES})})
ALL_CODECS = [BOOL, *INTS, FLOAT32, FLOAT64, STR, BYTES, float_array(4), float_array(2, FLOAT64), NESTED]


@pytest.mark.parametrize("codec", ALL_CODECS, ids=lambda c: c.spec)
@given(data=st.data())
def test_round_trip_and_size(codec: Codec, data) -> None:
    value = data.draw(values_of(codec))
    encoded = codec.encode(value)
    decoded = codec.decode(encoded)
    assert same(decoded, codec.normalize(value))
    assert codec.encode(decoded) == encoded
    if codec.size is not None:
        assert len(encoded) == codec.size


@pytest.mark.parametrize(
    ("codec", "size"),
    [(BOOL, 1), (INT8, 1), (UINT8, 1), (INT16, 2), (UINT16, 2), (INT32, 4), (UINT32, 4), (INT64, 8), (UINT64, 8),
     (FLOAT32, 4), (FLOAT64, 8), (float_array(3), 12), (float_array(3, FLOAT64), 24)],
)  # fmt: skip
def test_fixed_sizes(codec: Codec, size: int) -> None:
    assert codec.size == size


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-3e38, max_value=3e38))
def test_float32_is_exactly_four_bytes_little_endian(value: float) -> None:
    encoded = FLOAT32.encode(value)
    assert len(encoded) == 4
    assert encoded == struct.pack("<f", value)
    assert FLOAT32.decode(encoded) == struct.unpack("<f", encoded)[0]


def test_known_encodings_are_little_endian() -> None:
    assert INT16.encode(0x1234) == b"\x34\x12"
    assert UINT32.encode(1) == b"\x01\x00\x00\x00"
    assert FLOAT32.encode(1.0) == bytes.fromhex("0000803f")
    assert STR.encode("hé") == "hé".encode()
    assert record({"a": UINT8, "s": STR}).encode({"a": 7, "s": "xy"}) == b"\x07\x02xy"


@pytest.mark.parametrize(
    ("codec", "bad", "error"),
    [
        (BOOL, 1, TypeError), (BOOL, "true", TypeError),
        (INT8, 128, ValueError), (INT8, -129, ValueError), (UINT8, -1, ValueError), (UINT64, 1 << 64, ValueError),
        (INT32, 1.5, TypeError), (INT32, True, TypeError), (INT32, "3", TypeError),
        (FLOAT32, 1e39, ValueError), (FLOAT32, "1.0", TypeError),
        (FLOAT64, None, TypeError), (FLOAT64, True, TypeError),
        (STR, b"bytes", TypeError), (STR, "\udcff", ValueError), (StrCodec(3), "four", ValueError),
        (BYTES, "text", TypeError), (BytesCodec(2), b"abc", ValueError),
        (float_array(3), [1.0, 2.0], ValueError), (float_array(3), 1.0, TypeError),
        (float_array(2), ["a", 1.0], TypeError),
        (float_array(2), "ab", TypeError),
        (NESTED, [1, 2], TypeError),
        (record({"a": UINT8}), {"a": 1, "b": 2}, ValueError), (record({"a": UINT8}), {}, ValueError),
        (record({"a": UINT8}), {"a": 300}, ValueError),
    ],
)  # fmt: skip
def test_rejects_what_it_cannot_encode(codec: Codec, bad, error: type[Exception]) -> None:
    with pytest.raises(error):
        codec.encode(bad)
    with pytest.raises(error):
        codec.normalize(bad)


@pytest.mark.parametrize(
    ("codec", "data"),
    [(INT32, b"\x00\x00\x00"), (INT32, b"\x00" * 5), (BOOL, b"\x02"), (STR, b"\xff\xfe"), (FLOAT64, b""),
     (record({"s": STR}), b"\x05ab"), (record({"s": STR}), b"\xff"), (float_array(2), b"\x00" * 7),
     (BytesCodec(2), b"abc")],
)  # fmt: skip
def test_decode_rejects_malformed_bytes(codec: Codec, data: bytes) -> None:
    with pytest.raises(ValueError):
        codec.decode(data)


@given(st.binary(max_size=64))
def test_decode_of_random_bytes_is_a_value_or_value_error(data: bytes) -> None:
    for codec in ALL_CODECS:
        try:
            codec.decode(data)
        except ValueError:
            pass


def test_normalized_forms() -> None:
    assert FLOAT32.normalize(0.1) == struct.unpack("<f", struct.pack("<f", 0.1))[0]
    assert FLOAT64.normalize(3) == 3.0 and isinstance(FLOAT64.normalize(3), float)
    assert float_array(2).normalize([1, 2]) == (1.0, 2.0)
    assert BYTES.normalize(bytearray(b"ab")) == b"ab"
    assert list(record({"b": UINT8, "a": UINT8}).normalize({"a": 1, "b": 2})) == ["b", "a"]


@pytest.mark.parametrize("codec", [*ALL_CODECS, StrCodec(12), BytesCodec(8)], ids=lambda c: c.spec)
def test_spec_and_descriptor_round_trip(codec: Codec) -> None:
    assert parse_codec(codec.spec) == codec
    assert codec_from_descriptor(codec.descriptor()) == codec
    described = codec.describe()
    assert described["spec"] == codec.spec and described["size"] == codec.size


@pytest.mark.parametrize("spec", ["int7", "float32[", "record{a:int8", "bool[3]", "record{}", "float32 x"])
def test_bad_specs_are_refused(spec: str) -> None:
    with pytest.raises(ValueError):
        parse_codec(spec)


@given(st.binary(max_size=32))
def test_random_descriptors_never_crash(data: bytes) -> None:
    try:
        codec_from_descriptor(data)
    except ValueError:
        pass


def test_attribute_is_untouched_by_a_value_its_codec_refuses() -> None:
    attr = Attribute("joint.goal", 0.5, codec="float32")
    attr.set(0.25)
    with pytest.raises(TypeError):
        attr.set("ninety degrees")
    with pytest.raises(ValueError):
        attr.set(1e40)
    assert attr.valid and attr.peek() == 0.25
    assert isinstance(FloatCodec(32).normalize(1), float)
