"""The recorder's fast paths (issue 29, ``record_overhead_rtf_128``): they must write what the slow ones wrote.

- ``FastWriter.add_message`` packs a Message record itself instead of mcap's field-by-field Writer: the file must be
  the same bytes, whatever the messages (many channels, log times out of order, empty and chunk-sized payloads,
  extreme times and sequence numbers);
- the Recorder takes samples on Zenoh's threads into a bounded deque a writer drains in batches: closing writes
  everything taken, and beyond the bound samples are dropped and counted, not held (the publications, written as
  their JSON views: tests/server/test_record_values.py).
"""

from __future__ import annotations

import io
import json
import random
import struct
import threading
from itertools import pairwise
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from asm_py.protocol import Kind, Method, first_byte
from server import record
from server.mcap_files import FastWriter, McapFiles, RecordingInfo
from server.record import Recorder
from server.zenoh_args import ZenohOptions

from ..helpers import wait_until
from ..transports import free_port


def _write(cls: type[Writer], messages: list[tuple[int, int, bytes, int, int]], chunk_size: int) -> bytes:
    out = io.BytesIO()
    writer = cls(out, chunk_size=chunk_size)
    writer.start(profile="", library="test")
    schema = writer.register_schema("s", "jsonschema", b"{}")
    channels = [writer.register_channel(f"/c{i}", "json", schema) for i in range(5)]
    for channel, log_ns, data, publish_ns, seq in messages:
        writer.add_message(channels[channel], log_ns, data, publish_ns, seq)
        if log_ns % 97 == 0:
            writer.flush()  # a chunk closed early, as flush_seconds does
    writer.finish()
    return out.getvalue()


@pytest.mark.parametrize("chunk_size", [1024, 64 * 1024])
def test_the_fast_writer_writes_the_same_bytes_as_mcaps(chunk_size: int) -> None:
    rng = random.Random(29)
    messages = [(rng.randrange(5), rng.randrange(1, 10**12), rng.randbytes(rng.choice([0, 1, 50, 300])),
                 rng.randrange(10**12), rng.randrange(1 << 32)) for _ in range(3000)]  # fmt: skip
    messages += [(0, 0, b"", 0, 0), (1, (1 << 64) - 1, b"x" * (3 * chunk_size), (1 << 64) - 1, (1 << 32) - 1),
                 (2, 1, b"{}", 1, 1)]  # fmt: skip
    fast, slow = _write(FastWriter, messages, chunk_size), _write(Writer, messages, chunk_size)
    assert fast == slow
    read = [(m.log_time, m.data, m.sequence) for _, _, m in make_reader(io.BytesIO(fast)).iter_messages()]
    assert sorted(read) == sorted((log, data, seq) for _, log, data, _, seq in messages)


def _publication(seq: int, value: float) -> bytes:
    """joint.angle's publication (class 0x11, float32) as a module puts it."""
    return bytes((first_byte(Kind.PUBLICATION, Method.PUBLISH), seq & 0x7F, 0x11, 3)) + struct.pack("<f", value)


@pytest.fixture
def session():
    opened = ZenohOptions(listen=(f"tcp/127.0.0.1:{free_port()}",)).open()
    yield opened
    opened.close()


def test_closing_writes_every_sample_taken_in_order(session, tmp_path: Path) -> None:
    out = tmp_path / "all.mcap"
    recorder = Recorder(session, "robot", McapFiles(out, RecordingInfo({})), None)
    try:
        for k in range(3000):
            session.put(f"asm/robot/m{k % 7}/pub/joint.angle", _publication(k, float(k)))
        session.put("asm/robot/m1/pub/joint.angle", b"\xff not a publication")  # hostile: counted as dropped
        session.put("asm/robot/m1/pub/joint.angle", _publication(1, 1.0)[:-1])  # a float32 of 3 bytes
        assert wait_until(lambda: sum(recorder.counts.values()) + recorder.dropped >= 3002, timeout=60)
    finally:
        recorder.close()
    assert recorder.dropped == 2
    with out.open("rb") as f:
        messages = [m for _, c, m in make_reader(f).iter_messages(log_time_order=False) if c.topic.startswith("/m")]
    views = [json.loads(m.data) for m in messages]
    assert [v["value"] for v in views] == list(range(3000))
    times = [m.log_time for m in messages]  # taken in batches, yet each its own: the replay places values by them
    assert all(a < b for a, b in pairwise(times)), "log times repeat or go back"
    assert [v["seq"] for v in views] == [k & 0x7F for k in range(3000)]


def test_beyond_the_bound_samples_are_dropped_and_counted_not_held(
    session, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A stalled disk: the writer blocks in its first write; what arrives past QUEUE_BOUND is counted and let go."""
    monkeypatch.setattr(record, "QUEUE_BOUND", 50)
    release, entered = threading.Event(), threading.Event()

    class Stalled(McapFiles):
        def write(self, *args, **kwargs) -> None:
            entered.set()
            release.wait(60)
            super().write(*args, **kwargs)

    recorder = Recorder(session, "robot", Stalled(tmp_path / "s.mcap", RecordingInfo({})), None)
    try:
        session.put("asm/robot/m1/pub/joint.angle", _publication(0, 0.0))
        assert entered.wait(30)
        for k in range(1, 501):
            session.put("asm/robot/m1/pub/joint.angle", _publication(k, float(k)))
        assert wait_until(lambda: recorder.dropped + recorder.queued >= 500, timeout=60)
        assert recorder.queued == 50 and recorder.dropped == 450
    finally:
        release.set()
        recorder.close()
    assert recorder.counts["/m1/joint.angle"] == 51
