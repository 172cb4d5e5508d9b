"""The files of one recording: MCAP writers that rotate by size, stay readable when the recorder is killed.

Why its own module: asm-record decides *what* to record (server/record.py); this decides *how it lands on disk*,
and the two guarantees that matter for a flight recorder live here:

- **bounded**: with ``max_bytes`` a file is finished (summary, footer) before it would grow past that many bytes —
  what it holds, the chunk in progress (taken as incompressible) and an estimate of its summary — and the next
  numbered file starts (``run-000.mcap``, ``run-001.mcap``, …); with ``max_files`` the oldest files are deleted, so
  a recorder left running keeps at most ``max_files × max_bytes`` on disk. Only a file whose fixed part alone (its
  attachments and schemas) passes ``max_bytes`` can be larger, by its first message;
- **readable after SIGKILL**: the file is written unbuffered in small chunks, and the chunk in progress is closed
  at least every ``flush_seconds``; a recorder killed without a chance to write its summary leaves every chunk it
  finished, which a reader without a summary (``read_tolerant``) reads up to the first incomplete record.

Every file stands alone: its own schemas and channels, the metadata naming the robot, and the attachments (the
gait file, the robot's MJCF model).
"""

from __future__ import annotations

import json
import re
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path
from typing import IO, Any, cast

from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import NonSeekingReader
from mcap.records import Channel, Message, MessageIndex, Schema
from mcap.writer import Writer

LIBRARY = "asm-record"
CHUNK_SIZE = 64 * 1024
_SUMMARY_BASE = 600
"""Statistics, summary offsets, data end, footer, magic and the metadata indexes, with room to spare (bytes)."""
_CHUNK_INDEX = 100
_PER_CHANNEL = 10
"""A chunk index's and the statistics' entry per channel (ID and offset or count)."""
_ATTACHMENT_INDEX = 70


@dataclass(frozen=True)
class SchemaDef:
    """A schema as MCAP stores it: its name, encoding (``jsonschema``, ``protobuf``) and bytes, and the encoding of
    its channels' messages."""

    name: str
    encoding: str
    data: bytes
    message_encoding: str

    @classmethod
    def json(cls, schema: dict[str, object]) -> SchemaDef:
        return cls(str(schema["title"]), "jsonschema", json.dumps(schema).encode(), "json")


@dataclass
class Attachment:
    name: str
    media_type: str
    data: bytes


@dataclass
class RecordingInfo:
    """What every file of the recording carries besides its messages."""

    metadata: dict[str, str]
    attachments: list[Attachment] = field(default_factory=list)


class _Unbuffered:
    """A file every write of which reaches the kernel at once (what is written survives SIGKILL). Not a RawIOBase:
    mcap's Writer would wrap one in a BufferedWriter."""

    def __init__(self, path: Path) -> None:
        # never over a file ("x"); a device or a pipe that is there is what was asked for (/dev/full, a FIFO)
        mode = "wb" if path.exists() and not path.is_file() else "xb"
        self._file = open(path, mode, buffering=0)  # noqa: SIM115  # closed by close()
        self._position = 0
        """Bytes written: the file is only appended to, so this is its tell() without a system call (asked after
        every message, to see whether a chunk was written)."""

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data).cast("B")
        size = len(view)
        while view:
            view = view[self._file.write(view) or 0 :]
        self._position += size
        return size

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self._file.close()


_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
"""A Message record up to its data: opcode, record length, channel, sequence, log time, publish time."""
_FINALIZE_CHUNK: Callable[[Writer], None] | None = vars(Writer).get("_Writer__finalize_chunk")
_INDEX_HEADER = struct.Struct("<BQHI")
"""A MessageIndex record up to its entries: opcode, record length, channel, the entries' length."""


class _MessageIndex(MessageIndex):
    """mcap's MessageIndex, written in two ``struct.pack`` calls instead of two per entry: the same bytes. A chunk
    ends with one per channel, and a 128-module robot's chunk holds a few hundred messages of hundreds of channels
    (a tenth of the recorder's writing, measured with py-spy)."""

    def write(self, stream: Any) -> None:
        entries = len(self.records)
        stream.write(_INDEX_HEADER.pack(Opcode.MESSAGE_INDEX, 6 + 16 * entries, self.channel_id, 16 * entries))
        stream.write(struct.pack(f"<{2 * entries}Q", *chain.from_iterable(self.records)))


class FastWriter(Writer):
    """mcap's Writer, with ``add_message`` writing the same bytes in one ``struct.pack``: the library's builds a
    Message object and packs each field apart (about 14 µs a message, most of the recorder's writing at 6,000
    messages a second). It updates the writer's statistics and the chunk's index exactly as the library does, through
    their private attributes; where those are not there (another mcap version), the library's own method runs.
    tests/server/test_record.py checks that both write the same file."""

    def __init__(self, output: IO[bytes], **options: Any) -> None:
        super().__init__(output, **options)
        state = self.__dict__
        builder, statistics = state.get("_Writer__chunk_builder"), state.get("_Writer__statistics")
        chunk_size = state.get("_Writer__chunk_size")
        self._fast: tuple[Any, Any, int] | None = None
        """The library's chunk builder, statistics and chunk size (each made once, in its ``__init__``)."""
        if None not in (builder, statistics, chunk_size, _FINALIZE_CHUNK) and hasattr(builder, "record_writer"):
            self._fast = (builder, statistics, cast(int, chunk_size))

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0) -> None:
        fast = self._fast
        buffer = getattr(fast[0].record_writer, "_buffer", None) if fast is not None else None
        if fast is None or buffer is None:
            return super().add_message(channel_id, log_time, data, publish_time, sequence)
        builder, statistics, chunk_size = fast
        if statistics.message_count == 0 or log_time < statistics.message_start_time:
            statistics.message_start_time = log_time
        if log_time > statistics.message_end_time:
            statistics.message_end_time = log_time
        statistics.channel_message_counts[channel_id] += 1
        statistics.message_count += 1
        if builder.num_messages == 0 or log_time < builder.message_start_time:
            builder.message_start_time = log_time
        if log_time > builder.message_end_time:
            builder.message_end_time = log_time
        index = builder.message_indices.get(channel_id)
        if index is None:
            index = builder.message_indices[channel_id] = _MessageIndex(channel_id=channel_id, records=[])
        position = buffer.tell()
        index.records.append((log_time, position))
        builder.num_messages += 1
        buffer.write(_MESSAGE_HEADER.pack(Opcode.MESSAGE, 22 + len(data), channel_id, sequence, log_time,
                                          publish_time))  # fmt: skip
        buffer.write(data)
        if position + _MESSAGE_HEADER.size + len(data) > chunk_size:
            assert _FINALIZE_CHUNK is not None
            _FINALIZE_CHUNK(self)


def rotated(output: Path, index: int) -> Path:
    """The ``index``-th file of a rotated recording named ``output``."""
    return output.with_name(f"{output.stem}-{index:03d}{output.suffix or '.mcap'}")


def existing_files(output: Path, rotating: bool) -> list[Path]:
    """The files a recording named ``output`` would write that are there already (``rotating``: any
    ``<stem>-NNN<suffix>``, whatever its number: a rotation runs through them all). A recording is never written over
    (asm-record overwrote a run, and a rotated one numbered from 000 again over an earlier one's files)."""
    if not rotating:
        return [output] if output.is_file() else []  # a device or a pipe (/dev/full, a FIFO) is written to
    pattern = re.compile(re.escape(output.stem) + r"-\d{3,}" + re.escape(output.suffix or ".mcap"))
    return sorted(p for p in output.parent.iterdir() if pattern.fullmatch(p.name) and p.is_file())


class McapFiles:
    """Writes messages to ``output`` (numbered ``<stem>-NNN<suffix>`` when ``max_bytes`` rotates); one thread only."""

    def __init__(
        self,
        output: Path,
        info: RecordingInfo,
        *,
        max_bytes: int | None = None,
        max_files: int = 0,
        chunk_size: int = CHUNK_SIZE,
        flush_seconds: float = 1.0,
    ) -> None:
        self.output = output
        self.info = info
        self.max_bytes = max_bytes
        self.max_files = max_files
        self.chunk_size = chunk_size if max_bytes is None else max(1024, min(chunk_size, max_bytes // 8))
        """Chunks stay a small fraction of a rotated file: the room kept for the chunk in progress."""
        self.flush_seconds = flush_seconds
        self.paths: list[Path] = []
        self.messages = 0
        self._index = 0
        self._stream: _Unbuffered | None = None
        self._writer: Writer | None = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._flushed = time.monotonic()
        self._summary = 0
        """Bytes the summary of the current file will take, estimated (schemas, channels, indexes)."""
        self._written = 0
        self._in_file = 0
        self.on_new_file: Callable[[int], None] | None = None
        """Called when a rotated file has started, before its first message: what every file must begin with (the
        recorder's scene) is written there, at the log time (ns) of the message that started the file."""
        self._open()

    def path(self, index: int) -> Path:
        if self.max_bytes is None:
            return self.output
        return rotated(self.output, index)

    def _open(self) -> None:
        path = self.path(self._index)
        try:
            self._start(path)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from None

    def _start(self, path: Path) -> None:
        self._stream = _Unbuffered(path)
        self.paths.append(path)
        writer = self._writer = FastWriter(cast(IO[bytes], self._stream), chunk_size=self.chunk_size)
        writer.start(profile="", library=LIBRARY)
        self._schemas, self._channels = {}, {}
        self._summary = _SUMMARY_BASE + sum(_ATTACHMENT_INDEX + len(a.name) for a in self.info.attachments)
        writer.add_metadata("asm.recording", {**self.info.metadata, "file_index": str(self._index)})
        now = time.time_ns()
        for attachment in self.info.attachments:
            writer.add_attachment(now, now, attachment.name, attachment.media_type, attachment.data)
        writer.flush()
        self._flushed = time.monotonic()
        self._written = self._size()
        self._in_file = 0
        while self.max_files and len(self.paths) > self.max_files:
            self.paths.pop(0).unlink(missing_ok=True)

    def write(self, topic: str, schema: SchemaDef, data: bytes, log_ns: int, publish_ns: int = 0, seq: int = 0) -> None:
        """One message on ``topic`` (its channel and schema are declared in the current file the first time)."""
        if self.max_bytes is not None and self._full(len(data)):
            self._finish()
            self._index += 1
            self._open()
            if self.on_new_file is not None:
                self.on_new_file(log_ns)
        writer = self._writer
        if writer is None:
            raise ValueError("the recording is closed")
        channel = self._channels.get(topic)
        if channel is None:
            schema_id = self._schemas.get(schema.name)
            if schema_id is None:
                schema_id = self._schemas[schema.name] = writer.register_schema(schema.name, schema.encoding,
                                                                                schema.data)  # fmt: skip
                self._summary += 32 + len(schema.name) + len(schema.encoding) + len(schema.data)
            channel = self._channels[topic] = writer.register_channel(topic, schema.message_encoding, schema_id)
            self._summary += 40 + len(topic) + len(schema.message_encoding) + 2 * _PER_CHANNEL
        writer.add_message(channel, log_ns, data, publish_ns or log_ns, seq & 0xFFFFFFFF)
        self.messages += 1
        self._in_file += 1
        if time.monotonic() - self._flushed >= self.flush_seconds:
            self.flush()
        size = self._stream.tell() if self._stream is not None else 0
        if size > self._written:  # a chunk was written: the summary will index it
            self._written = size
            self._summary += _CHUNK_INDEX + _PER_CHANNEL * len(self._channels)

    @property
    def index(self) -> int:
        """The number of the file being written (0 for the first)."""
        return self._index

    def _full(self, more: int) -> bool:
        """Would ``more`` bytes of message take the file past ``max_bytes`` (a file takes at least one message)?"""
        if self.max_bytes is None or not self._in_file:
            return False
        return self._size() + self.chunk_size + self._summary + more + 32 >= self.max_bytes

    def _size(self) -> int:
        return self._stream.tell() if self._stream is not None else 0

    def flush_if_due(self) -> None:
        """:meth:`flush` if the chunk in progress has been open ``flush_seconds`` (the writer calls this when no
        message has come for a while, since only a message written checks the time otherwise)."""
        if time.monotonic() - self._flushed >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Close the chunk in progress: what was written so far is on disk as whole records."""
        if self._writer is not None:
            self._writer.flush()
            if self._size() > self._written:
                self._written = self._size()
                self._summary += _CHUNK_INDEX + _PER_CHANNEL * len(self._channels)
        self._flushed = time.monotonic()

    def _finish(self, end: dict[str, str] | None = None) -> None:
        writer, stream = self._writer, self._stream
        self._writer = self._stream = None
        if writer is not None:
            if end:
                writer.add_metadata("asm.recording.end", end)
            writer.finish()
        if stream is not None:
            stream.close()

    def close(self, end: dict[str, str] | None = None) -> None:
        """Finish the current file: summary and footer (``end``: metadata saying how the recording went)."""
        self._finish(end)


def read_tolerant(stream: IO[bytes]) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """The messages of an MCAP file read front to back without its summary, up to the first incomplete record:
    all that a recorder killed mid-write had finished."""
    reader: Any = NonSeekingReader(stream)
    try:
        yield from reader.iter_messages(log_time_order=False)  # in file order: sorting would read to the end first
    except (McapError, EOFError, ValueError):
        return
