"""What one recorded message costs the recorder in CPU, apart from the robot (issue 29, ``record_overhead_rtf_128``).

    .venv/bin/python bench/record_cpu.py

``record_overhead_rtf_128`` (bench/record.py) needs the recorder to take little of the 2 cores the 128-module robot
shares with it: under 0.2 CPU seconds a second at its ~6,000 messages a second, so about 33 µs a message. Its own
figures (CPU seconds a second) follow how many messages the robot manages to publish, which the machine's load
decides. Here a publisher process sends 30,000 publications of 128 objects (``joint.angle``, float32) at 3,000 a
second, stamped as the bridge stamps them, to a :class:`server.record.Recorder` in this process writing an MCAP file;
the figure is this process's CPU (user + system) over the messages it wrote while they came. Target <= 33 µs.

Until 2026-11-27 the publisher sent JSON views, which the recorder then subscribed to (the figures of
docs/benchmarks.md before that date); it now takes the binary publications and writes each as its view.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from asm_py.protocol import Kind, Method, first_byte
from server.child import free_port
from server.mcap_files import McapFiles, RecordingInfo
from server.record import CHUNK_SIZE, Recorder
from server.zenoh_args import ZenohOptions

MESSAGES, RATE = 30_000, 3_000
HEAD = first_byte(Kind.PUBLICATION, Method.PUBLISH)

PUBLISHER = r"""
import json, struct, sys, time, zenoh
config = zenoh.Config()
config.insert_json5("mode", '"peer"')
config.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
config.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(config)
time.sleep(2.0)  # the recorder's subscriptions reach this peer
publishers = [session.declare_publisher(f"asm/robot/m{i}/pub/joint.angle") for i in range(128)]
count, rate = int(sys.argv[2]), int(sys.argv[3])
began = time.monotonic()
head = int(sys.argv[4])  # byte 0 of a publication
for k in range(count):  # joint.angle's publication (class 0x11, object 2), stamped as the bridge puts it
    publishers[k % 128].put(bytes((head, k & 0x7F, 0x11, 2)) + struct.pack("<f", k * 0.001),
                            timestamp=session.new_timestamp())
    if k % 100 == 99 and (ahead := began + (k + 1) / rate - time.monotonic()) > 0:
        time.sleep(ahead)
session.close()
"""


def _cpu() -> float:
    used = resource.getrusage(resource.RUSAGE_SELF)
    return used.ru_utime + used.ru_stime


def main() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = ZenohOptions(listen=(endpoint,)).open()
    try:
        with tempfile.TemporaryDirectory() as folder:
            files = McapFiles(Path(folder) / "cpu.mcap", RecordingInfo({}), chunk_size=CHUNK_SIZE)  # asm-record's
            recorder = Recorder(session, "robot", files, None)
            publisher = subprocess.Popen(
                [sys.executable, "-c", PUBLISHER, endpoint, str(MESSAGES), str(RATE), str(HEAD)]
            )
            try:
                written = lambda: sum(recorder.counts.values())  # noqa: E731
                deadline = time.monotonic() + 60
                while written() < 100 and time.monotonic() < deadline:
                    time.sleep(0.01)
                cpu, first, began = _cpu(), written(), time.monotonic()
                while written() < MESSAGES - 200 and time.monotonic() < deadline + 60:
                    time.sleep(0.05)
                cpu, count, seconds = _cpu() - cpu, written() - first, time.monotonic() - began
                publisher.wait(60)
            finally:
                publisher.kill()
                publisher.wait()
                recorder.close()
    finally:
        session.close()
    each = cpu / max(1, count) * 1e6
    print(f"the recorder wrote {count} messages in {seconds:.1f} s using {cpu / seconds:.2f} CPU seconds a second "
          f"({recorder.dropped} dropped); load average {os.getloadavg()[0]:.1f}", flush=True)  # fmt: skip
    miss = "" if each <= 33 else " MISS: at 6,000 messages a second the recorder would take more than 0.2 of a core"
    print(f"ratio record_cpu_us_per_message {each:.1f} (target <= 33){miss}", flush=True)


if __name__ == "__main__":
    main()
