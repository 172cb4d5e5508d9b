"""Typed attribute values: one definition per type, from which the wire bytes, the GUI input and the docs derive.

A codec does three things with a value: ``normalize`` (check it and bring it to canonical Python form — the form
every reader gets back, local or remote), ``encode`` to bytes and ``decode`` from bytes. ``normalize`` is what
``Attribute.set`` calls before touching anything, so a bad value raises ``TypeError`` (wrong kind) or ``ValueError``
(out of range, wrong length, unknown field) and leaves the attribute unchanged.

Byte order is little-endian throughout (the order of the ARM/x86 processors on modules and PCs). A top-level value
of a variable-size type (str, bytes) is its raw bytes, its length being that of the message; inside a record, such
a field is prefixed with its length as an unsigned LEB128 varint. ``descriptor()`` is a compact binary type tag that
a lookup reply carries, so a client learns the type of a remote attribute; ``spec`` is the same type as text
(``"float32"``, ``"float32[3]"``, ``"record{x:float32,ok:bool}"``), for files and docs.
"""

from __future__ import annotations

import json
import operator
import struct
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

from ._contract import CodecTag

Buffer = bytes | bytearray | memoryview


class Codec(ABC):
    """The type of an attribute value; see the module docstring."""

    spec: str
    """Canonical text form of the type, parsed back by :func:`parse_codec`."""
    size: int | None
    """Encoded size in bytes when every value has the same size, else None."""

    @abstractmethod
    def normalize(self, value: Any) -> Any:
        """Check ``value`` and return it in canonical form; TypeError or ValueError if it cannot be encoded."""

    @abstractmethod
    def descriptor(self) -> bytes:
        """The binary type tag carried in lookup replies (see docs/protocol.md)."""

    @abstractmethod
    def describe(self) -> dict[str, Any]:
        """What a GUI input or a doc needs: kind, bounds, lengths, fields."""

    @abstractmethod
    def _pack(self, out: bytearray, value: Any) -> None:
        """Append the embedded form of an already normalized value."""

    @abstractmethod
    def _unpack(self, data: memoryview, offset: int) -> tuple[Any, int]:
        """Read the embedded form at ``offset``; return the value and the offset after it."""

    def encode(self, value: Any) -> bytes:
        out = bytearray()
        self._pack(out, self.normalize(value))
        return bytes(out)

    def encode_canonical(self, value: Any) -> bytes:
        """Encode a value that went through :meth:`normalize` already (an attribute's stored value): no check."""
        out = bytearray()
        self._pack(out, value)
        return bytes(out)

    def decode(self, data: Buffer) -> Any:
        view = memoryview(data)
        try:
            value, end = self._unpack(view, 0)
        except (struct.error, IndexError) as exc:
            raise ValueError(f"{self.spec}: cannot decode {len(view)} bytes: {exc}") from None
        if end != len(view):
            raise ValueError(f"{self.spec}: {len(view) - end} trailing byte(s) after the value")
        return value

    def plain_struct(self) -> struct.Struct | None:
        """The one ``struct`` whose unpacking of exactly its size is the decoded value, if this codec has one (a
        number): a publication's receiver unpacks it in place, with no call of :meth:`decode` (issue 31)."""
        return None

    def __repr__(self) -> str:
        return f"<codec {self.spec}>"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Codec) and other.spec == self.spec

    def __hash__(self) -> int:
        return hash(self.spec)


class _Fixed(Codec):
    """A scalar packed with one ``struct`` format."""

    def __init__(self, spec: str, fmt: str, tag: int) -> None:
        self.spec = spec
        self._struct = struct.Struct("<" + fmt)
        self.size = self._struct.size
        self._tag = tag
        self._plain = type(self)._unpack is _Fixed._unpack
        """Whether a value is the struct's unpacking as it is (a bool checks its byte)."""

    def descriptor(self) -> bytes:
        return bytes([self._tag])

    def _pack(self, out: bytearray, value: Any) -> None:
        out += self._struct.pack(value)

    def encode_canonical(self, value: Any) -> bytes:
        return self._struct.pack(value)

    def _unpack(self, data: memoryview, offset: int) -> tuple[Any, int]:
        end = offset + self._struct.size
        if end > len(data):
            raise ValueError(f"{self.spec}: needs {self._struct.size} bytes, {len(data) - offset} left")
        return self._struct.unpack_from(data, offset)[0], end

    def encode(self, value: Any) -> bytes:
        return self._struct.pack(self.normalize(value))

    def plain_struct(self) -> struct.Struct | None:
        return self._struct if self._plain else None

    def decode(self, data: Buffer) -> Any:
        if self._plain and len(data) == self.size:  # every get and publication of a number: one unpack (issue 31)
            return self._struct.unpack(data)[0]
        return super().decode(data)


class BoolCodec(_Fixed):
    def __init__(self) -> None:
        super().__init__("bool", "B", CodecTag.BOOL)

    def normalize(self, value: Any) -> bool:
        if value is True or value is False:
            return value
        if type(value).__name__ == "bool_":  # numpy.bool_, without importing numpy
            return bool(value)
        raise TypeError(f"bool attribute needs True or False, got {type(value).__name__}")

    def _unpack(self, data: memoryview, offset: int) -> tuple[Any, int]:
        raw, end = super()._unpack(data, offset)
        if raw > 1:
            raise ValueError(f"bool: byte {raw:#04x} is neither 0 nor 1")
        return raw == 1, end

    def describe(self) -> dict[str, Any]:
        return {"spec": self.spec, "kind": "bool", "size": 1}


class IntCodec(_Fixed):
    def __init__(self, bits: int, signed: bool) -> None:
        fmt = {8: "b", 16: "h", 32: "i", 64: "q"}[bits]
        spec = f"{'' if signed else 'u'}int{bits}"
        tag = CodecTag[spec.upper()]
        super().__init__(spec, fmt if signed else fmt.upper(), tag)
        self.min = -(1 << (bits - 1)) if signed else 0
        self.max = (1 << (bits - 1)) - 1 if signed else (1 << bits) - 1

    def normalize(self, value: Any) -> int:
        if isinstance(value, bool):
            raise TypeError(f"{self.spec} attribute needs an integer, got bool")
        try:
            number = operator.index(value)
        except TypeError:
            raise TypeError(f"{self.spec} attribute needs an integer, got {type(value).__name__}") from None
        if not self.min <= number <= self.max:
            raise ValueError(f"{number} is outside {self.spec} range [{self.min}, {self.max}]")
        return number

    def describe(self) -> dict[str, Any]:
        return {"spec": self.spec, "kind": "int", "size": self.size, "min": self.min, "max": self.max}


class FloatCodec(_Fixed):
    def __init__(self, bits: int) -> None:
        super().__init__(
            f"float{bits}", "f" if bits == 32 else "d", CodecTag.FLOAT32 if bits == 32 else CodecTag.FLOAT64
        )

    def normalize(self, value: Any) -> float:
        if type(value) is float:  # the common case first: no type checks, one round trip through the struct
            if self.size == 8:
                return value
            try:
                return self._struct.unpack(self._struct.pack(value))[0]
            except OverflowError:
                raise ValueError(f"{value} is outside the float32 range") from None
        if isinstance(value, bool | str | bytes):
            raise TypeError(f"{self.spec} attribute needs a number, got {type(value).__name__}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise TypeError(f"{self.spec} attribute needs a number, got {type(value).__name__}") from None
        if self.size == 4:
            try:
                return self._struct.unpack(self._struct.pack(number))[0]
            except (OverflowError, struct.error):
                raise ValueError(f"{number} is outside the float32 range") from None
        return number

    def describe(self) -> dict[str, Any]:
        return {"spec": self.spec, "kind": "float", "size": self.size}


def _pack_varint(out: bytearray, number: int) -> None:
    while number >= 0x80:
        out.append((number & 0x7F) | 0x80)
        number >>= 7
    out.append(number)


def unpack_varint(data: memoryview, offset: int) -> tuple[int, int]:
    number = shift = 0
    while True:
        if offset >= len(data):
            raise ValueError("varint runs past the end of the data")
        byte = data[offset]
        offset += 1
        number |= (byte & 0x7F) << shift
        if byte < 0x80:
            return number, offset
        shift += 7
        if shift > 63:
            raise ValueError("varint longer than 64 bits")


class _Variable(Codec):
    """str or bytes: raw at top level, varint-length-prefixed inside a record."""

    size = None
    _tag: int

    def __init__(self, max_len: int | None) -> None:
        self.max_len = max_len

    @abstractmethod
    def _to_bytes(self, value: Any) -> bytes: ...

    @abstractmethod
    def _from_bytes(self, raw: bytes) -> Any: ...

    def _check_len(self, raw: bytes) -> None:
        if self.max_len is not None and len(raw) > self.max_len:
            raise ValueError(f"{self.spec}: {len(raw)} bytes exceed the maximum of {self.max_len}")

    def encode(self, value: Any) -> bytes:
        return self._to_bytes(self.normalize(value))

    def decode(self, data: Buffer) -> Any:
        raw = bytes(data)
        self._check_len(raw)
        return self._from_bytes(raw)

    def _pack(self, out: bytearray, value: Any) -> None:
        raw = self._to_bytes(value)
        _pack_varint(out, len(raw))
        out += raw

    def _unpack(self, data: memoryview, offset: int) -> tuple[Any, int]:
        length, offset = unpack_varint(data, offset)
        end = offset + length
        if end > len(data):
            raise ValueError(f"{self.spec}: field of {length} bytes runs past the end of the data")
        raw = bytes(data[offset:end])
        self._check_len(raw)
        return self._from_bytes(raw), end

    def descriptor(self) -> bytes:
        out = bytearray([self._tag])
        _pack_varint(out, 0 if self.max_len is None else self.max_len)
        return bytes(out)


class StrCodec(_Variable):
    _tag = CodecTag.STR

    def __init__(self, max_len: int | None = None) -> None:
        super().__init__(max_len)
        self.spec = "str" if max_len is None else f"str<{max_len}>"

    def normalize(self, value: Any) -> str:
        if not isinstance(value, str):
            raise TypeError(f"{self.spec} attribute needs a str, got {type(value).__name__}")
        try:
            self._check_len(value.encode("utf-8"))
        except UnicodeEncodeError as exc:
            raise ValueError(f"{self.spec}: not encodable as UTF-8: {exc.reason}") from None
        return value

    def _to_bytes(self, value: str) -> bytes:
        return value.encode("utf-8")

    def _from_bytes(self, raw: bytes) -> str:
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{self.spec}: invalid UTF-8: {exc.reason}") from None

    def describe(self) -> dict[str, Any]:
        return {"spec": self.spec, "kind": "str", "size": None, "max_len": self.max_len}


class BytesCodec(_Variable):
    _tag = CodecTag.BYTES

    def __init__(self, max_len: int | None = None) -> None:
        super().__init__(max_len)
        self.spec = "bytes" if max_len is None else f"bytes<{max_len}>"

    def normalize(self, value: Any) -> bytes:
        if not isinstance(value, bytes | bytearray | memoryview):
            raise TypeError(f"{self.spec} attribute needs bytes, got {type(value).__name__}")
        raw = bytes(value)
        self._check_len(raw)
        return raw

    def _to_bytes(self, value: bytes) -> bytes:
        return value

    def _from_bytes(self, raw: bytes) -> bytes:
        return raw

    def describe(self) -> dict[str, Any]:
        return {"spec": self.spec, "kind": "bytes", "size": None, "max_len": self.max_len}


class FloatArrayCodec(Codec):
    """A fixed number of float32 or float64 values; the canonical Python form is a tuple."""

    def __init__(self, length: int, element: FloatCodec) -> None:
        if length < 1:
            raise ValueError(f"a float array needs at least one element, not {length}")
        self.length = length
        self.element = element
        self.spec = f"{element.spec}[{length}]"
        self._struct = struct.Struct(f"<{length}{'f' if element.size == 4 else 'd'}")
        self.size = self._struct.size

    def normalize(self, value: Any) -> tuple[float, ...]:
        if isinstance(value, str | bytes | Mapping) or not hasattr(value, "__len__"):
            raise TypeError(f"{self.spec} attribute needs a sequence of numbers, got {type(value).__name__}")
        if len(value) != self.length:
            raise ValueError(f"{self.spec} attribute needs {self.length} values, got {len(value)}")
        return tuple(self.element.normalize(item) for item in value)

    def descriptor(self) -> bytes:
        out = bytearray([CodecTag.FLOAT_ARRAY, self.element._tag])
        _pack_varint(out, self.length)
        return bytes(out)

    def describe(self) -> dict[str, Any]:
        return {"spec": self.spec, "kind": "float_array", "size": self.size, "length": self.length,
                "element": self.element.describe()}  # fmt: skip

    def _pack(self, out: bytearray, value: Any) -> None:
        out += self._struct.pack(*value)

    def _unpack(self, data: memoryview, offset: int) -> tuple[Any, int]:
        end = offset + self._struct.size
        if end > len(data):
            raise ValueError(f"{self.spec}: needs {self._struct.size} bytes, {len(data) - offset} left")
        return self._struct.unpack_from(data, offset), end


class RecordCodec(Codec):
    """Named fields of other codecs, in a fixed order; the canonical Python form is a dict in that order."""

    def __init__(self, fields: Sequence[tuple[str, Codec]] | Mapping[str, Codec]) -> None:
        items = list(fields.items() if isinstance(fields, Mapping) else fields)
        if not items:
            raise ValueError("a record needs at least one field")
        names = [name for name, _ in items]
        if len(set(names)) != len(names):
            raise ValueError(f"record field names must be unique: {names}")
        for name in names:
            if not name.isidentifier():
                raise ValueError(f"record field name {name!r} is not an identifier")
        self.fields: tuple[tuple[str, Codec], ...] = tuple(items)
        self.spec = "record{" + ",".join(f"{name}:{codec.spec}" for name, codec in items) + "}"
        sizes = [codec.size for _, codec in items]
        self.size = None if None in sizes else sum(s for s in sizes if s is not None)

    def normalize(self, value: Any) -> dict[str, Any]:
        if not isinstance(value, Mapping):
            raise TypeError(f"{self.spec} attribute needs a mapping of its fields, got {type(value).__name__}")
        unknown = set(value) - {name for name, _ in self.fields}
        if unknown:
            raise ValueError(f"unknown record field(s) {sorted(map(str, unknown))} for {self.spec}")
        result = {}
        for name, codec in self.fields:
            if name not in value:
                raise ValueError(f"record field {name!r} is missing for {self.spec}")
            result[name] = codec.normalize(value[name])
        return result

    def descriptor(self) -> bytes:
        out = bytearray([CodecTag.RECORD])
        _pack_varint(out, len(self.fields))
        for name, codec in self.fields:
            raw = name.encode("utf-8")
            _pack_varint(out, len(raw))
            out += raw
            out += codec.descriptor()
        return bytes(out)

    def describe(self) -> dict[str, Any]:
        fields = [{"name": name, **codec.describe()} for name, codec in self.fields]
        return {"spec": self.spec, "kind": "record", "size": self.size, "fields": fields}

    def _pack(self, out: bytearray, value: Any) -> None:
        for name, codec in self.fields:
            codec._pack(out, value[name])

    def _unpack(self, data: memoryview, offset: int) -> tuple[Any, int]:
        result = {}
        for name, codec in self.fields:
            result[name], offset = codec._unpack(data, offset)
        return result, offset


class JsonCodec(_Variable):
    """Any JSON-representable value, as UTF-8 JSON text: how an attribute without a codec travels on the wire.

    The canonical form is what JSON gives back (tuples become lists), so local and remote readers agree.
    """

    spec = "json"
    _tag = CodecTag.JSON

    def __init__(self) -> None:
        super().__init__(None)

    def normalize(self, value: Any) -> Any:
        try:
            return json.loads(json.dumps(value, allow_nan=True))
        except (TypeError, ValueError) as exc:
            raise TypeError(f"json attribute needs a JSON-representable value: {exc}") from None

    def descriptor(self) -> bytes:
        return bytes([self._tag])

    def describe(self) -> dict[str, Any]:
        return {"spec": self.spec, "kind": "json", "size": None}

    def _to_bytes(self, value: Any) -> bytes:
        return json.dumps(value, separators=(",", ":")).encode("utf-8")

    def _from_bytes(self, raw: bytes) -> Any:
        try:
            return json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f"json: cannot decode: {exc}") from None


def to_json(value: Any) -> Any:
    """A JSON-ready form of any codec's value (bytes as hex), for the JSON view of publications."""
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, tuple | list):
        return [to_json(v) for v in value]
    if isinstance(value, Mapping):
        return {k: to_json(v) for k, v in value.items()}
    return value


BOOL = BoolCodec()
INT8, INT16, INT32, INT64 = (IntCodec(bits, True) for bits in (8, 16, 32, 64))
UINT8, UINT16, UINT32, UINT64 = (IntCodec(bits, False) for bits in (8, 16, 32, 64))
FLOAT32 = FloatCodec(32)
FLOAT64 = FloatCodec(64)
STR = StrCodec()
BYTES = BytesCodec()
JSON = JsonCodec()

SCALARS: dict[str, Codec] = {
    c.spec: c
    for c in (BOOL, INT8, INT16, INT32, INT64, UINT8, UINT16, UINT32, UINT64, FLOAT32, FLOAT64, STR, BYTES, JSON)
}
BY_TAG: dict[int, Codec] = {c._tag: c for c in SCALARS.values() if isinstance(c, _Fixed)}


def float_array(length: int, element: FloatCodec = FLOAT32) -> FloatArrayCodec:
    return FloatArrayCodec(length, element)


def record(fields: Sequence[tuple[str, Codec]] | Mapping[str, Codec]) -> RecordCodec:
    return RecordCodec(fields)
