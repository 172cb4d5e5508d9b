"""Codecs read back from their names: the spec text (``"float32[8]"``, ``"record{x:int16,y:str<8>}"``) that
configuration and code use, and the binary descriptor a lookup reply carries (docs/protocol.md, "Codecs").

Both readers bound what they build (descriptor nesting, array lengths, field counts): a descriptor comes from the
network.
"""

from __future__ import annotations

from ._contract import CodecTag
from .codec import (
    BY_TAG,
    FLOAT32,
    FLOAT64,
    JSON,
    SCALARS,
    Buffer,
    BytesCodec,
    Codec,
    FloatArrayCodec,
    FloatCodec,
    RecordCodec,
    StrCodec,
    unpack_varint,
)

MAX_DEPTH = 8
"""How deeply records may nest in a descriptor."""


def parse_codec(spec: str | Codec) -> Codec:
    """The codec named by ``spec`` (its ``.spec`` text); a Codec is returned as it is."""
    if isinstance(spec, Codec):
        return spec
    codec, end = _parse(spec.replace(" ", ""), 0)
    if end != len(spec.replace(" ", "")):
        raise ValueError(f"unexpected text after position {end} in codec spec {spec!r}")
    return codec


def _parse(text: str, pos: int) -> tuple[Codec, int]:
    if text.startswith("record{", pos):
        pos += len("record{")
        fields: list[tuple[str, Codec]] = []
        while True:
            colon = text.find(":", pos)
            if colon < 0:
                raise ValueError(f"record field without ':' in codec spec {text!r}")
            name = text[pos:colon]
            codec, pos = _parse(text, colon + 1)
            fields.append((name, codec))
            if pos < len(text) and text[pos] == ",":
                pos += 1
                continue
            if pos < len(text) and text[pos] == "}":
                return RecordCodec(fields), pos + 1
            raise ValueError(f"record not closed with '}}' in codec spec {text!r}")
    end = pos
    while end < len(text) and (text[end].isalnum()):
        end += 1
    word = text[pos:end]
    if word in ("str", "bytes") and text.startswith("<", end):
        close = text.index(">", end)
        max_len = int(text[end + 1 : close])
        return (StrCodec(max_len) if word == "str" else BytesCodec(max_len)), close + 1
    if word not in SCALARS:
        raise ValueError(f"unknown type {word!r} in codec spec {text!r}")
    codec = SCALARS[word]
    if text.startswith("[", end):
        close = text.index("]", end)
        if not isinstance(codec, FloatCodec):
            raise ValueError(f"arrays are of float32 or float64, not {word!r}")
        return FloatArrayCodec(int(text[end + 1 : close]), codec), close + 1
    return codec, end


def codec_from_descriptor(data: Buffer) -> Codec:
    """Rebuild a codec from its binary descriptor; ValueError if malformed."""
    view = memoryview(data)
    codec, end = _from_descriptor(view, 0, depth=0)
    if end != len(view):
        raise ValueError(f"{len(view) - end} trailing byte(s) after a codec descriptor")
    return codec


def _from_descriptor(data: memoryview, offset: int, depth: int) -> tuple[Codec, int]:
    if depth > MAX_DEPTH:
        raise ValueError("codec descriptor nested too deeply")
    if offset >= len(data):
        raise ValueError("codec descriptor is truncated")
    tag = data[offset]
    offset += 1
    if tag in BY_TAG:
        return BY_TAG[tag], offset
    if tag == CodecTag.JSON:
        return JSON, offset
    if tag in (CodecTag.STR, CodecTag.BYTES):
        max_len, offset = unpack_varint(data, offset)
        limit = max_len or None
        return (StrCodec(limit) if tag == CodecTag.STR else BytesCodec(limit)), offset
    if tag == CodecTag.FLOAT_ARRAY:
        if offset >= len(data) or data[offset] not in (CodecTag.FLOAT32, CodecTag.FLOAT64):
            raise ValueError("float array descriptor without a float element type")
        element = FLOAT32 if data[offset] == CodecTag.FLOAT32 else FLOAT64
        length, offset = unpack_varint(data, offset + 1)
        if not 1 <= length <= 65535:
            raise ValueError(f"float array length {length} out of range")
        return FloatArrayCodec(length, element), offset
    if tag == CodecTag.RECORD:
        count, offset = unpack_varint(data, offset)
        if not 1 <= count <= 255:
            raise ValueError(f"record field count {count} out of range")
        fields = []
        for _ in range(count):
            length, offset = unpack_varint(data, offset)
            name = bytes(data[offset : offset + length]).decode("utf-8", errors="strict")
            offset += length
            codec, offset = _from_descriptor(data, offset, depth + 1)
            fields.append((name, codec))
        return RecordCodec(fields), offset
    raise ValueError(f"unknown codec tag {tag:#04x}")
