"""A recording read back for replay: what asm-record or the Record button wrote (server/record.py), held in memory
as the Replay tab serves it — the pose frames, every attribute value, the events, the robot's model.

Why a reader of its own (and not server/): the page imports nothing of server/, and replay needs the file read
*tolerantly*: a recording whose writer was killed has no summary and ends mid-record, and everything up to its last
whole chunk must replay (as ``mcap_files.read_tolerant`` reads it). So the file is read front to back with the
``mcap`` stream reader, stopping at the first incomplete record, and its protobuf poses are decoded here by field
number (``foxglove.FrameTransforms``: the few fields the recorder writes; no protobuf runtime is needed).

Hostile input is refused with :class:`RecordingError`, one sentence the page shows: not an MCAP file, larger than
``MAX_BYTES`` (the whole recording is held in memory), nothing replayable in it.
"""

from __future__ import annotations

import io
import itertools
import json
import struct
from array import array
from bisect import bisect_right
from collections.abc import Iterable, Iterator, MutableSequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any

import numpy as np

from asm_module.feed import PoseFrame
from asm_module.recording_topics import TOPIC_ESTOP, TOPIC_GROUP, TOPIC_STATUS, TOPIC_TRANSFORMS, attribute_of

MAGIC = b"\x89MCAP0\r\n"
MAX_BYTES = 256 * 1024 * 1024
"""The largest file opened: a recording is held in memory whole (an hour of a 12-module robot is about 100 MB)."""
MAX_EXPANDED = 4 * MAX_BYTES
"""The most its chunks may expand to, decompressed (the recorder's zstd chunks shrink to about a third)."""
MAX_CHUNK = 64 * 1024 * 1024
"""The largest chunk decompressed (the recorder writes 64 kB ones)."""


class RecordingError(ValueError):
    """The file cannot be replayed: why, in one sentence."""


@dataclass(frozen=True)
class Event:
    time: float
    """Seconds since the recording's first message."""
    kind: str
    """``e-stop``, ``group`` (a deploy's activation, a drive's goals) or ``status`` (e-stop latched/released)."""
    text: str


class Series:
    """One publishing object's recorded values, in file order, held compactly: a replay keeps every value of a run
    in memory, and a list of Python floats and (seq, t) tuples took about 180 bytes a value — ten times the file's
    bytes for it. Times, stamps and float values are machine arrays (8 bytes each); any other value (an int, a
    bool, text, a list) turns ``values`` into a list, kept so (Python's small ints and booleans are shared)."""

    __slots__ = ("_seqs", "_stamp_times", "times", "values")

    def __init__(self, times: Iterable[float] = (), values: Iterable[Any] = (),
                 stamps: Iterable[tuple[int, float]] = ()) -> None:  # fmt: skip
        self.times = array("d", times)
        self.values: MutableSequence[Any] = array("d")
        """As the file holds them (JSON-decoded): numbers, booleans, lists, text."""
        for value in values:
            self._append_value(value)
        pairs = list(stamps)
        self._seqs = array("q", (seq for seq, _ in pairs))
        self._stamp_times = array("d", (t for _, t in pairs))

    def append(self, t: float, value: Any, seq: int, stamp: float) -> None:
        """One value; OverflowError, nothing kept, for a ``seq`` beyond 64 bits (a hostile file's)."""
        self._seqs.append(seq)  # first: the one that can fail
        self.times.append(t)
        self._append_value(value)
        self._stamp_times.append(stamp)

    def _append_value(self, value: Any) -> None:
        if isinstance(self.values, array):
            if type(value) is float:
                self.values.append(value)
                return
            self.values = list(self.values)
        self.values.append(value)

    @property
    def stamps(self) -> list[tuple[int, float]]:
        """Each value's (seq, t) as its publisher stamped it (the JSON view's ``seq`` and ``t``; 0 when absent)."""
        return list(zip(self._seqs, self._stamp_times, strict=True))

    def until(self, t: float) -> int:
        """How many values were published at or before ``t``."""
        return bisect_right(self.times, t)


@dataclass
class Recording:
    """A recording's content, times in seconds since its first message (``start_ns``)."""

    name: str
    start_ns: int = 0
    metadata: dict[str, str] = field(default_factory=dict)
    mjcf: str | None = None
    """The robot's model (the ``robot.mjcf`` attachment): what the 3D view draws."""
    gait: tuple[str, str] | None = None
    """(file name, text) of the gait attached."""
    frames: list[PoseFrame] = field(default_factory=list)
    """The pose frames: ``time`` is seconds since the start, ``seq`` the feed's sequence number."""
    series: dict[tuple[str, str], Series] = field(default_factory=dict)
    """(node, object) → its values."""
    events: list[Event] = field(default_factory=list)
    complete: bool = False
    """The file ended with its summary and footer; False: its writer was killed, read up to its last whole chunk."""
    jumps: list[tuple[float, float]] = field(default_factory=list)
    """(where, by how many seconds) the recording's log times jump forward by more than JUMP_SECONDS: its clock
    stepped (log times are the recorder's wall clock) or a message carries a wrong time; the timeline spans them."""
    damaged: int = 0
    """Chunks whose bytes do not decompress (a damaged file): skipped, the chunks after them read."""
    _frame_times: list[float] = field(default_factory=list, repr=False)

    @property
    def duration(self) -> float:
        ends = [self.frames[-1].time] if self.frames else []
        ends += [s.times[-1] for s in self.series.values() if s.times]
        ends += [e.time for e in self.events]
        return max(ends, default=0.0)

    @property
    def frame_times(self) -> list[float]:
        """The frames' times (kept: the replay looks one up 60 times a second)."""
        if len(self._frame_times) != len(self.frames):
            self._frame_times = [f.time for f in self.frames]
        return self._frame_times

    def frame_at(self, t: float) -> PoseFrame | None:
        """The pose frame shown at ``t``: the last one recorded at or before it; before the first, the first (a
        recording's first message is its scene, a few ms before its first pose: at t = 0 the robot was not drawn,
        its bodies piled at the origin); None without frames."""
        if not self.frames:
            return None
        return self.frames[max(0, bisect_right(self.frame_times, t) - 1)]

    def nodes(self) -> list[str]:
        """The nodes that published, m2 before m10."""
        return sorted({node for node, _ in self.series}, key=lambda n: (len(n), n))

    def objects(self) -> list[str]:
        """The objects with numeric values (what a plot can show), sorted."""
        return sorted({obj for (_, obj), s in self.series.items() if s.values and all(map(_numeric, s.values))})


JUMP_SECONDS = 600.0
"""A gap between two consecutive messages of a recording longer than this is said (a robot's recorder writes many a
second): a wall clock stepped, or one message's time is wrong, and the timeline stretches over it."""


def _numeric(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, str)


def open_recording(path: Path, max_bytes: int = MAX_BYTES) -> Recording:
    """The recording in ``path``; RecordingError when it cannot be replayed."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise RecordingError(f"cannot open {path}: {exc.strerror or exc}") from None
    if not path.is_file():
        raise RecordingError(f"{path} is not a file")
    if size > max_bytes:
        raise RecordingError(f"{path.name} has {size / 2**20:.0f} MB: larger than the {max_bytes / 2**20:.0f} MB a "
                             "replay holds in memory (split it with asm-record --max-bytes)")  # fmt: skip
    with path.open("rb") as stream:
        return read_recording(stream, path.name)


def read_bytes(data: bytes, name: str, max_bytes: int = MAX_BYTES) -> Recording:
    """A recording uploaded through the page (``data`` its bytes)."""
    if len(data) > max_bytes:
        raise RecordingError(f"{name} has {len(data) / 2**20:.0f} MB: larger than the {max_bytes / 2**20:.0f} MB a "
                             "replay holds in memory")  # fmt: skip
    return read_recording(io.BytesIO(data), name)


def utf8_name(name: str) -> bool:
    """Whether ``name`` can go to the page: a file name that is not UTF-8 comes from the OS with surrogates, and one
    such string in any message ends the page's connection for every tab, E-STOP included, on every reconnection."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def utf8_text(text: str) -> str:
    """``text`` with what is not UTF-8 in it (a file name's surrogates) shown as U+FFFD, fit for the page."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def read_recording(stream: IO[bytes], name: str) -> Recording:
    """Read every whole record of ``stream`` (see the module docstring)."""
    name = utf8_text(name)  # said on the page: see utf8_name
    from mcap.exceptions import McapError
    from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader, breakup_chunk

    head = stream.read(len(MAGIC))
    if head != MAGIC:
        raise RecordingError(f"{name} is not an MCAP file (it does not start with the MCAP magic)")
    stream.seek(0)
    recording = Recording(name)
    channels: dict[int, str] = {}
    first: int | None = None
    raw: list[tuple[int, str, bytes, int]] = []
    reader = StreamReader(stream, emit_chunks=True, record_size_limit=MAX_BYTES)
    expanded = 0

    def records() -> Iterator[Any]:
        """The file's records, a chunk's own in its place: decompressed only when it says it expands to a size
        within the budget (a small hostile file must not expand to gigabytes)."""
        nonlocal expanded
        for record in reader.records:
            if isinstance(record, Chunk):
                expanded += record.uncompressed_size
                if record.uncompressed_size > MAX_CHUNK or expanded > MAX_EXPANDED:
                    raise RecordingError(f"{name} expands to more than the {MAX_EXPANDED / 2**20:.0f} MB a replay "
                                         f"holds (or has a chunk over {MAX_CHUNK / 2**20:.0f} MB)")  # fmt: skip
                try:
                    inner = list(breakup_chunk(_expanded(record, name)))
                except RecordingError:
                    raise
                except (McapError, EOFError, ValueError, struct.error):
                    # its record was whole (the reader is past it), its contents are not: the next chunk stands.
                    # A torn last chunk of a killed writer ends here too, the file then ending without a footer.
                    recording.damaged += 1
                    continue
                yield from inner
            else:
                yield record

    try:
        for record in records():
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                topic = channels.get(record.channel_id)
                if topic is not None:
                    raw.append((record.log_time, topic, record.data, record.sequence))
                    first = record.log_time if first is None else min(first, record.log_time)
            elif isinstance(record, Attachment):
                if record.name == "robot.mjcf":
                    recording.mjcf = record.data.decode("utf-8", "replace")
                elif record.name.endswith(".toml"):
                    recording.gait = (record.name, record.data.decode("utf-8", "replace"))
            elif isinstance(record, Metadata) and record.name == "asm.recording":
                recording.metadata = dict(record.metadata)
            elif isinstance(record, DataEnd | Footer):
                recording.complete = True
                break
    except RecordingError:
        raise
    except (McapError, EOFError, ValueError, struct.error, MemoryError):
        pass  # a writer killed mid-record: everything before it stands
    if not raw:
        raise RecordingError(f"{name} holds no messages: nothing to replay")
    recording.start_ns = first or 0
    raw.sort(key=lambda m: m[0])  # chunks are in file order; a replay is in time order
    for before, after in itertools.pairwise(raw):
        if after[0] - before[0] > JUMP_SECONDS * 1e9:
            recording.jumps.append(((before[0] - recording.start_ns) / 1e9, (after[0] - before[0]) / 1e9))
    for log_ns, topic, data, seq in raw:
        _add(recording, (log_ns - recording.start_ns) / 1e9, topic, data, seq)
    if not recording.frames and not recording.series:
        raise RecordingError(f"{name} holds no poses and no attribute values: not a recording of a robot")
    return recording


def _expanded(chunk: Any, name: str) -> Any:
    """``chunk`` decompressed, never past the size it says it expands to: a hostile file's chunk may claim 1,000
    bytes and hold gigabytes of zeros (mcap's own reader trusted the data, not the claim: 1 GB and 100 s for a
    33 kB file)."""
    import lz4.frame
    import zstandard

    limit = chunk.uncompressed_size
    try:
        if chunk.compression == "zstd":
            with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data), read_across_frames=True) as stream:
                data = stream.read(limit + 1)
        elif chunk.compression == "lz4":
            data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=limit + 1)
        elif chunk.compression == "":
            data = chunk.data
        else:
            raise RecordingError(f"{name} has a chunk compressed with {chunk.compression[:40]!r} (zstd, lz4 or none)")
    except (zstandard.ZstdError, RuntimeError) as exc:  # lz4 says RuntimeError
        raise ValueError(f"a chunk does not decompress: {exc}") from None  # a torn last chunk: read up to it
    if len(data) != limit:
        raise RecordingError(f"{name} has a chunk that expands to {'more' if len(data) > limit else 'less'} than "
                             f"the {limit:,} bytes it says: not replayed")  # fmt: skip
    return replace(chunk, compression="", data=data)


def _add(recording: Recording, t: float, topic: str, data: bytes, seq: int) -> None:
    """One message into the recording; one that does not decode is skipped (the file is someone else's input)."""
    try:
        if topic == TOPIC_TRANSFORMS:
            positions, quaternions = decode_transforms(data)
            recording.frames.append(PoseFrame(seq, t, positions, quaternions, simulated=True))
        elif topic == TOPIC_ESTOP:
            view = json.loads(data)
            scope, source, reason = (
                _short(view.get(k, d)) for k, d in (("scope", "?"), ("source", "?"), ("reason", ""))
            )
            recording.events.append(Event(t, "e-stop", f"E-STOP ({scope}) by {source}: {reason}"))
        elif topic == TOPIC_GROUP:
            view = json.loads(data)
            text = (f"group message to {_short(view.get('group', '?'))} from {_short(view.get('source', '?'))} (a "
                    "deploy, a drive)")  # fmt: skip
            recording.events.append(Event(t, "group", text))
        elif topic == TOPIC_STATUS:
            _status(recording, t, json.loads(data))
        elif (attribute := attribute_of(topic)) is not None:
            view = json.loads(data)
            if isinstance(view, dict) and "value" in view:
                seq, stamp = int(view.get("seq", 0)), float(view.get("t", 0.0))
                recording.series.setdefault(attribute, Series()).append(t, view["value"], seq, stamp)
    except (ValueError, TypeError, IndexError, AttributeError, OverflowError, struct.error):
        return


EVENT_FIELD = 80
"""Characters of a name or a reason an event's text shows (an e-stop's reason is 64 bytes on the wire; a file is
anyone's: a 3 MB source filled the Replay tab with X)."""


def _short(value: Any) -> str:
    text = str(value)
    return text if len(text) <= EVENT_FIELD else text[: EVENT_FIELD - 1] + "…"


def _status(recording: Recording, t: float, status: Any) -> None:
    """A status whose latched e-stops differ from the previous one's is an event (latched, released)."""
    latched = status.get("estop") if isinstance(status, dict) else None
    previous = next((e for e in reversed(recording.events) if e.kind == "status"), None)
    text = f"e-stop latched on modules {latched}" if latched else "no e-stop latched"
    if (previous is None and latched) or (previous is not None and previous.text != text):
        recording.events.append(Event(t, "status", text))


# -- foxglove.FrameTransforms, by field number ------------------------------------------------------------------------


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        value |= (byte & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if not byte & 0x80:
            return value, i
        if shift > 63:
            raise ValueError("a varint longer than 64 bits")


def _fields(data: bytes) -> list[tuple[int, Any]]:
    """(field number, value) of a protobuf message: length-delimited as bytes, doubles as float, varints as int."""
    out: list[tuple[int, Any]] = []
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
            if i + length > len(data):
                raise ValueError("a field runs past the message")
            out.append((number, data[i : i + length]))
            i += length
        elif wire == 5:
            out.append((number, struct.unpack_from("<f", data, i)[0]))
            i += 4
        else:
            raise ValueError(f"protobuf wire type {wire}")
    return out


def decode_transforms(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The bodies' positions (n×3) and orientations (n×4, w first as MuJoCo's) of a ``foxglove.FrameTransforms``
    (FrameTransform: translation field 4, rotation field 5; Vector3 x, y, z and Quaternion x, y, z, w are fields
    1-4; zero fields are absent)."""
    positions, quaternions = [], []
    for number, each in _fields(data):
        if number != 1 or not isinstance(each, bytes):
            continue
        parts = dict(_fields(each))
        xyz = dict(_fields(parts.get(4, b"")))
        xyzw = dict(_fields(parts.get(5, b"")))
        positions.append([float(xyz.get(k, 0.0)) for k in (1, 2, 3)])
        quaternions.append([float(xyzw.get(k, 0.0)) for k in (4, 1, 2, 3)])
    if not positions:
        raise ValueError("a FrameTransforms without transforms")
    return np.array(positions, dtype=float), np.array(quaternions, dtype=float)
