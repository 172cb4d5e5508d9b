"""``asm-record``: record one robot's Zenoh traffic to MCAP, the file format Foxglove and the ``mcap`` tools open.

    asm-record --robot a --zenoh-connect tcp/127.0.0.1:7447 --output run.mcap
    asm-record --robot a --zenoh-connect tcp/127.0.0.1:7447 --output run.mcap --max-bytes 50M --max-files 10 \\
               --max-seconds 3600 --gait gaits/library/caterpillar.toml

Why a separate process: a recorder is a tool that joins a robot's network like a studio does (a robot is a
namespace, docs/protocol.md §6) and only listens — it needs no lease, sends nothing, and can be started and killed
without touching the robot. What it records (channels and schemas: docs/protocol.md §11):

- every attribute and event publication, decoded: the binary publication ``asm/<robot>/<node>/pub/<object>``
  written as its JSON view (server/record_values.py: taking the views would make the robot format them), one
  channel per object (``/m3/joint.angle``);
- the pose feed as ``foxglove.FrameTransforms`` and the bodies as a ``foxglove.SceneUpdate`` (server/foxglove_msgs.py),
  so Foxglove's 3D panel shows the robot moving;
- the robot's status, its e-stops and the lab's, and group messages (a deploy's activation, a drive's goals);
- in every file: metadata naming the robot, and as attachments the robot's MJCF model and, with ``--gait``, the gait.

It refuses at once (one line, exit 1) when no robot of that name answers within ``--wait`` seconds, and as a usage
error (exit 2) when the output cannot be written. SIGINT or SIGTERM finishes the file; SIGKILL leaves every chunk
finished so far readable (server/mcap_files.py). It prints ``RECORDING robot <name> to <file>`` once it listens and,
at the end, one line saying what it wrote.
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from asm_module.feed import RobotStatus, decode_poses, mjcf_key, poses_key, status_key
from asm_py.cli import bounded, input_file, name, run, stop_requested, summary
from asm_py.keys import RobotKeys, lab_estop, split
from asm_py.protocol import ProtocolError, decode

from . import foxglove_msgs as fx
from .bridge_outlets import stamp_seconds
from .mcap_files import Attachment, McapFiles, RecordingInfo, SchemaDef, existing_files
from .record_values import SEQUENCE, Objects, Publications, values_key
from .zenoh_args import ZenohOptions, add_zenoh_arguments, zenoh_options

QUEUE_BOUND = 50_000
"""Samples waiting for the writer; beyond it a sample is dropped and counted (a stalled disk must not grow memory)."""
CHANNEL = 10_000
"""Publications Zenoh holds for the receiving thread (a FIFO: when full, Zenoh waits). That thread only moves them
into the writer's queue, where the bound above is kept and counted."""
RECEIVE_PERIOD = 0.002
"""Seconds the receiving thread waits between batches: at 6,000 publications a second, a dozen a batch."""
CHUNK_SIZE = 1 << 20
"""asm-record's chunks, uncompressed (mcap's default; McapFiles' is 64 KiB): a 128-module robot publishes on ~640
channels, and a chunk ends with an index record per channel in it — at 64 KiB, about one a message. A killed
recorder still loses at most ``--flush-seconds``: the chunk in progress is closed that often."""
WRITER_PERIOD = 0.02
"""Seconds the writer sleeps when nothing waits: it takes what arrived meanwhile in one batch. Waking it per sample
(a queue.Queue's condition) cost a lock hand-off per message, at 6,000 a second a large part of the recorder's CPU;
a sample waits at most this long, far less than ``flush_seconds`` before it is on disk anyway."""

TRANSFORMS = SchemaDef("foxglove.FrameTransforms", "protobuf", fx.FrameTransforms.get_schema().data, "protobuf")
SCENE = SchemaDef("foxglove.SceneUpdate", "protobuf", fx.SceneUpdate.get_schema().data, "protobuf")
ATTRIBUTE = SchemaDef.json(fx.ATTRIBUTE_SCHEMA)
STATUS = SchemaDef.json(fx.STATUS_SCHEMA)
ESTOP = SchemaDef.json(fx.ESTOP_SCHEMA)
GROUP = SchemaDef.json(fx.GROUP_SCHEMA)


class RobotNotFound(RuntimeError):
    """No robot of the name answered on the network in time."""


def find_robot(session: zenoh.Session, robot: str, wait: float) -> tuple[RobotStatus, str | None]:
    """The robot's status and MJCF model (None: a real robot), asked until ``wait`` seconds have passed: a peer
    that has just connected needs a moment before its queries reach anyone."""
    deadline = time.monotonic() + wait
    while True:
        for reply in session.get(status_key(robot), timeout=min(1.0, max(0.1, wait))):
            if reply.ok is not None:
                try:
                    status = RobotStatus.from_json(reply.ok.payload.to_bytes())
                except ValueError:
                    continue
                if status.robot == robot:
                    return status, _mjcf(session, robot)
        if time.monotonic() >= deadline:
            raise RobotNotFound(f"no robot named {robot!r} answered on the Zenoh network within {wait:g} s "
                                "(is asm-robot running there, and --zenoh-connect its endpoint?)")  # fmt: skip
        time.sleep(0.2)


def _mjcf(session: zenoh.Session, robot: str) -> str | None:
    for reply in session.get(mjcf_key(robot), timeout=2.0):
        if reply.ok is not None:
            return reply.ok.payload.to_string() or None
    return None


class Recorder:
    """Subscribes to ``robot``'s keys on ``session`` and writes what arrives to ``files`` on its own thread."""

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        files: McapFiles,
        mjcf: str | None,
        on_error: Callable[[], None] | None = None,
    ) -> None:
        self.session = session
        self.error: OSError | None = None
        """Why the files could not be written (a full disk, a file removed): the recording stopped there."""
        self.on_error = on_error
        self.robot = robot
        self.files = files
        self.bodies = fx.bodies(mjcf)
        self.counts: Counter[str] = Counter()
        """Messages written, per topic."""
        self._overflow = 0
        """Samples dropped because the queue was full (counted by the receiving threads)."""
        self._refused = 0
        """Samples that were not what their key says (counted by the writer)."""
        self.missed = 0
        """Publications missing between those recorded: short gaps in their objects' sequence numbers (counted by
        the writer; Publications.missed). Lost on the way, or dropped by the recorder's full queue or a lookup's
        held bound — those are in ``dropped`` too; a refused one is not a gap."""
        self._pending: deque[tuple[Any, ...]] = deque()
        """(handler, its arguments…, the arrival time in ns) per sample, or per batch of publications: appended on
        the receiving threads, taken by the writer (a deque's append and popleft are atomic, no lock)."""
        self._received = 0
        self._taken = 0
        """Publications queued by the receiving thread and taken by the writer, each counted by its one thread: the
        difference is what waits."""
        self._closing = False
        self._scene_file = -1
        self.objects = Objects(session, robot, self._post, self._write_value)
        files.on_new_file = self._new_file
        self._new_file()
        keys = RobotKeys(robot)
        # The publications, by far the most frequent, through a channel that one thread of ours empties in batches:
        # zenoh-python's default handler runs a Python thread per subscriber that takes the GIL once per sample.
        # The rest through that default handler (a callback only appends to the deque and never blocks).
        values = session.declare_subscriber(values_key(robot), zenoh.handlers.FifoChannel(CHANNEL))
        self._receiver = threading.Thread(target=self._receive, args=(values.handler,), name="asm-record-receive",
                                          daemon=True)  # fmt: skip
        self._subs = [
            values,
            session.declare_subscriber(poses_key(robot), self._on_poses),
            session.declare_subscriber(status_key(robot), self._on_status),
            session.declare_subscriber(keys.estop("*"), lambda s: self._on_estop(s, "robot")),
            session.declare_subscriber(lab_estop("*"), lambda s: self._on_estop(s, "lab")),
            session.declare_subscriber(keys.group("*", "*"), self._on_group),
        ]
        self._writer = threading.Thread(target=self._write_loop, name="asm-record-writer", daemon=True)
        self._writer.start()
        self._receiver.start()

    @property
    def queued(self) -> int:
        """Publications waiting for the writer."""
        return self._received - self._taken

    @property
    def dropped(self) -> int:
        """Samples not recorded: the queue was full, or a payload was not what its key says."""
        return self._overflow + self._refused + self.objects.dropped

    # -- receiving threads: take the sample, nothing more ---------------------------------------------------------

    def _enqueue(self, handler: Callable[..., None], *args: Any) -> None:
        if len(self._pending) >= QUEUE_BOUND:
            self._overflow += 1
        else:
            self._pending.append((handler, *args, time.time_ns()))

    def _post(self, handler: Callable[..., None], *args: Any) -> None:
        """Run ``handler(*args)`` on the writer thread, after what is queued (not bounded: lookups' answers)."""
        self._pending.append((handler, *args))

    def _receive(self, channel: zenoh.handlers.Handler[zenoh.Sample]) -> None:
        """Moves the publications into the writer's queue, all that waits at once: one wake-up and one queue entry
        for a batch. Ends when the subscriber is undeclared (the channel says it is closed once empty)."""
        recv, try_recv, pending, time_ns = channel.recv, channel.try_recv, self._pending, time.time_ns
        while True:
            try:
                batch = [recv()]
            except zenoh.ZError:
                return
            times = [time_ns()]  # each its own: the replay orders and places a series' values by their log times
            try:
                while (sample := try_recv()) is not None:
                    batch.append(sample)
                    times.append(time_ns())
            except zenoh.ZError:  # closed while emptying: what was taken is still queued below, then the end
                closed = True
            else:
                closed = False
            room = max(0, QUEUE_BOUND - (self._received - self._taken))
            if len(batch) > room:
                self._overflow += len(batch) - room
                del batch[room:], times[room:]
            if batch:
                self._received += len(batch)
                pending.append((self._write_values, batch, times))
            if closed:
                return
            time.sleep(RECEIVE_PERIOD)

    def _on_poses(self, sample: zenoh.Sample) -> None:
        self._enqueue(self._write_poses, sample.payload.to_bytes())

    def _on_status(self, sample: zenoh.Sample) -> None:
        self._enqueue(self._write_plain, fx.TOPIC_STATUS, STATUS, sample.payload.to_bytes())

    def _on_estop(self, sample: zenoh.Sample, scope: str) -> None:
        reason = sample.payload.to_bytes().decode("utf-8", "replace")
        text = json.dumps({"scope": scope, "source": split(sample.key_expr)[-1], "reason": reason})
        self._enqueue(self._write_plain, fx.TOPIC_ESTOP, ESTOP, text.encode())

    def _on_group(self, sample: zenoh.Sample) -> None:
        chunks = split(sample.key_expr)  # asm/<robot>/@group/<group>/msg/<source>
        self._enqueue(self._write_group, chunks[3], chunks[-1], sample.payload.to_bytes())

    # -- the writer thread ----------------------------------------------------------------------------------------

    def _write_loop(self) -> None:
        pending, files = self._pending, self.files
        while True:
            if not pending:
                if self._closing:  # set after the last subscriber was undeclared: nothing more arrives
                    return
                time.sleep(WRITER_PERIOD)
                files.flush_if_due()  # a quiet robot: what arrived is on disk within flush_seconds all the same
                continue
            item = pending.popleft()
            try:
                item[0](*item[1:])
            except (ValueError, KeyError, IndexError, ProtocolError):
                self._refused += 1  # a payload that is not what its key says: not recorded, counted
            except OSError as exc:  # the disk: nothing more can be written, so say so and end the recording
                self.error = exc
                if self.on_error is not None:
                    self.on_error()
                return

    def _put(self, topic: str, schema: SchemaDef, data: bytes, ns: int, publish_ns: int = 0, seq: int = 0) -> None:
        self.files.write(topic, schema, data, ns, publish_ns, seq)
        self.counts[topic] += 1

    def _write_values(self, batch: list[zenoh.Sample], times: list[int]) -> None:
        """A batch of publications (and the times they were taken, ns), each written as its JSON view; ``t`` is the
        publication's Zenoh timestamp (the bridge's time when it put it), or when it was taken here if it has none."""
        self._taken += len(batch)
        resolve, write = self.objects.resolve, self._write_value
        for sample, ns in zip(batch, times, strict=True):
            stamp = sample.timestamp
            t = ns / 1e9 if stamp is None else stamp_seconds(stamp)
            key, data = str(sample.key_expr), sample.payload.to_bytes()
            publications = resolve(key, data, t, ns)
            if publications is not None:
                write(publications, data, t, ns)

    def _write_value(self, publications: Publications, data: bytes, t: float, ns: int) -> None:
        try:
            view = publications.view(data, t)
        except ValueError:
            self._refused += 1  # a payload that is not what its key says: not recorded, counted
            if len(data) > 1 and data[1] <= SEQUENCE:
                publications.missed(data[1])  # its number seen: counted as refused, so not as missed too
            return
        self.missed += publications.missed(data[1])
        self._put(publications.topic, ATTRIBUTE, view, ns, int(t * 1e9), data[1])

    def _new_file(self, ns: int = 0) -> None:
        """Every file starts with the bodies it draws (when the robot's model is known)."""
        if self.bodies:
            self._scene_file = self.files.index
            ns = ns or time.time_ns()
            self._put(fx.TOPIC_SCENE, SCENE, fx.scene_update(self.bodies, ns).encode(), ns)

    def _write_poses(self, data: bytes, ns: int) -> None:
        frame = decode_poses(data)
        if len(self.bodies) < len(frame.positions):  # no model (or a smaller one): numbered bodies
            self.bodies = fx.bodies(None, len(frame.positions))
            self._new_file(ns)
        elif self._scene_file != self.files.index:
            self._new_file(ns)
        self._put(fx.TOPIC_TRANSFORMS, TRANSFORMS, fx.frame_transforms(frame, self.bodies, ns).encode(), ns,
                  seq=frame.seq)  # fmt: skip

    def _write_plain(self, topic: str, schema: SchemaDef, data: bytes, ns: int) -> None:
        self._put(topic, schema, data, ns)

    def _write_group(self, group: str, source: str, data: bytes, ns: int) -> None:
        message = decode(data)
        text = json.dumps({"group": group, "source": source, "kind": message.kind, "method": message.method,
                           "class_id": message.class_id, "object_id": message.object_id,
                           "data": message.data.hex()})  # fmt: skip
        self._put(fx.TOPIC_GROUP, GROUP, text.encode(), ns)

    def close(self, end: dict[str, str] | None = None) -> None:
        """Stop listening, write what is queued, finish the file."""
        for sub in self._subs:
            try:
                sub.undeclare()
            except zenoh.ZError:
                pass
        self._subs.clear()
        self._receiver.join(10)  # the channel emptied into the queue
        self._closing = True  # the writer writes what is pending, then ends (at once if it stopped on an error)
        self._writer.join(10)
        if self.error is not None:
            raise OSError(self.error.errno, f"the recording stopped: cannot write {self.files.paths[-1]}: "
                          f"{self.error.strerror or self.error}")  # fmt: skip
        self.files.close(
            {
                **(end or {}),
                "messages": str(sum(self.counts.values())),
                "dropped": str(self.dropped),
                "missed": str(self.missed),
            }
        )


def byte_size(text: str) -> int:
    """``50M``, ``200k``, ``1G`` or a plain number of bytes (powers of 1024)."""
    scale = {"k": 1 << 10, "m": 1 << 20, "g": 1 << 30}.get(text[-1:].lower(), 1)
    try:
        value = int(float(text[:-1] if scale > 1 else text) * scale)
    except (ValueError, OverflowError):  # inf, 1e400: no number of bytes (it was a traceback)
        raise argparse.ArgumentTypeError(f"a size in bytes such as 50M or 200k, not {text!r}") from None
    if value < 16 * 1024:
        raise argparse.ArgumentTypeError(f"{text}: at least 16k (a file holds its schemas and attachments too)")
    return value


def gait_file(text: str) -> Path:
    """An existing gait file that reads as a gait: what a recording attaches is shared and replayed as the run's
    gait (any file was embedded: /etc/shadow, a binary named .toml)."""
    from gaits.errors import GaitError
    from gaits.model import load

    path = input_file(text)
    try:
        load(path)
    except GaitError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else "not a gait"
        raise argparse.ArgumentTypeError(f"{text} is not a gait file: {first[:200]}") from None
    return path


def mcap_output(text: str) -> Path:
    """A file the recorder can create: its directory exists and is writable, and it is not a directory."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, not a file name")
    if not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: the directory {path.parent} does not exist")
    if not os.access(path.parent, os.W_OK):
        raise argparse.ArgumentTypeError(f"{text}: the directory {path.parent} is not writable")
    return path


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-record", description=summary(__doc__))
    cli.add_argument("--robot", type=name, required=True, help="the robot to record (its name on the network)")
    cli.add_argument("--output", "-o", type=mcap_output, default=Path("run.mcap"), metavar="FILE",
                     help="the MCAP file (default run.mcap; numbered run-000.mcap, … with --max-bytes)")  # fmt: skip
    cli.add_argument("--max-seconds", type=bounded(float, above=0, high=10 * 365 * 86400, what="seconds"),
                     help="stop after this many seconds (default: on SIGINT/SIGTERM)")  # fmt: skip
    cli.add_argument("--max-bytes", type=byte_size, help="start the next numbered file when one holds this many "
                     "bytes (50M, 200k)")  # fmt: skip
    cli.add_argument("--max-files", type=bounded(int, 1, what="files"), default=0,
                     help="with --max-bytes: keep only the newest N files (default: all)")  # fmt: skip
    cli.add_argument("--gait", type=gait_file, metavar="FILE", help="a gait file to embed (as an attachment)")
    cli.add_argument(
        "--wait",
        type=bounded(float, 0, 3600, what="seconds"),
        default=5.0,
        help="seconds to wait for the robot to answer (default 5)",
    )
    cli.add_argument("--flush-seconds", type=bounded(float, above=0, high=3600, what="seconds"), default=1.0,
                     help="close a chunk at least this often (default 1): what a SIGKILL can lose")  # fmt: skip
    add_zenoh_arguments(cli)
    args = cli.parse_args(argv)
    if args.max_files and args.max_bytes is None:
        cli.error("--max-files counts rotated files: use it with --max-bytes")
    there = existing_files(args.output, args.max_bytes is not None)
    if there:
        shown = ", ".join(str(p) for p in there[:3]) + (f" and {len(there) - 3} more" if len(there) > 3 else "")
        cli.error(f"{shown} already there: a recording is never written over (give another --output, or move "
                  "them)")  # fmt: skip
    network = zenoh_options(cli, args)
    done = stop_requested()
    return run(cli.prog, lambda: _record(args, network, done))


def _record(args: argparse.Namespace, network: ZenohOptions, done: threading.Event) -> int:
    session = network.open()
    try:
        status, mjcf = find_robot(session, args.robot, args.wait)
        info = RecordingInfo({"robot": args.robot, "mode": status.mode, "modules": str(status.modules),
                              "recorder": "asm-record", "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                              "gait": args.gait.name if args.gait else ""})  # fmt: skip
        if mjcf:
            info.attachments.append(Attachment("robot.mjcf", "application/xml", mjcf.encode()))
        if args.gait:
            info.attachments.append(Attachment(args.gait.name, "application/toml", args.gait.read_bytes()))
        files = McapFiles(args.output, info, max_bytes=args.max_bytes, max_files=args.max_files,
                          chunk_size=CHUNK_SIZE, flush_seconds=args.flush_seconds)  # fmt: skip
        recorder = Recorder(session, args.robot, files, mjcf, on_error=done.set)
        started = time.monotonic()
        print(f"RECORDING robot {args.robot} to {files.paths[0]}", flush=True)
        done.wait(args.max_seconds)
        recorder.close({"seconds": f"{time.monotonic() - started:.3f}"})
    finally:
        session.close()
    total = sum(recorder.counts.values())
    print(f"asm-record: {total} messages of robot {args.robot} in {time.monotonic() - started:.1f} s "
          f"({recorder.dropped} dropped) to {', '.join(str(p) for p in files.paths)}", flush=True)  # fmt: skip
    if recorder.missed:
        print(
            f"asm-record: {recorder.missed} publications missing between those recorded (gaps in their objects' "
            "sequence numbers: lost on the way, or among those dropped here)",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
