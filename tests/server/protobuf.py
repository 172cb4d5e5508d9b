"""A minimal protobuf reader: the tests decode what foxglove-sdk encoded (frame transforms) without the SDK, so a
recording is checked against the wire format, not against the library that wrote it."""

from __future__ import annotations

import struct


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        value |= (byte & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if not byte & 0x80:
            return value, i


def fields(data: bytes) -> list[tuple[int, bytes | int | float]]:
    """(field number, value) of a protobuf message: length-delimited as bytes, doubles as float, varints as int."""
    out: list[tuple[int, bytes | int | float]] = []
    i = 0
    while i < len(data):
        key, i = _varint(data, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(data, i)
            out.append((number, value))
        elif wire == 1:
            out.append((number, struct.unpack_from("<d", data, i)[0]))
            i += 8
        elif wire == 2:
            length, i = _varint(data, i)
            out.append((number, data[i : i + length]))
            i += length
        else:
            raise ValueError(f"wire type {wire}")
    return out


def transforms(data: bytes) -> list[tuple[str, str, tuple[float, ...]]]:
    """foxglove.FrameTransforms → (parent, child, (x, y, z)) per transform (fields 2, 3, 4 of FrameTransform)."""
    out = []
    for number, each in fields(data):
        assert number == 1 and isinstance(each, bytes)
        parts = dict(fields(each))
        xyz = dict(fields(parts.get(4, b"")))  # type: ignore[arg-type]
        out.append((parts[2].decode(), parts[3].decode(), tuple(float(xyz.get(k, 0.0)) for k in (1, 2, 3))))  # type: ignore[union-attr]
    return out
