"""Replay in the studio: does a replay show every recorded frame at 1x, and how long does opening a recording take?

    .venv/bin/python bench/replay.py

- ``replay_frames_shown_1x``: a 10 s recording of the 8-module caterpillar's bodies at 60 frames a second (written
  by the recorder's own file writer and encoders), played at 1x by a ReplaySource on the wall clock; a consumer
  waiting on ``wait_changed`` as the studio's render thread does counts the distinct frames it sees, over the frames
  recorded. Target >= 0.95: the replay is as smooth as the recording.
- ``replay_open_s_per_recorded_min``: wall-clock seconds ``open_recording`` takes to read a recording of one minute
  (poses at 60 Hz, every module's joint.angle at 25 Hz, a status a second), per recorded minute. Target <= 2.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np

from asm_module.feed import PoseFrame
from gaits.mjcf import build_mjcf
from gaits.model import LIBRARY, load
from server import foxglove_msgs as fx
from server.mcap_files import Attachment, McapFiles, RecordingInfo
from server.record import ATTRIBUTE, STATUS, TRANSFORMS
from web.recording import open_recording
from web.replay import ReplaySource


def write(path: Path, seconds: float) -> int:
    """A recording of ``seconds`` (see the module docstring); its number of pose frames."""
    gait = load(LIBRARY / "caterpillar.toml")
    mjcf = build_mjcf(gait.robot, name=gait.name)
    bodies = fx.bodies(mjcf)
    files = McapFiles(path, RecordingInfo({"robot": "robot"}, [Attachment("robot.mjcf", "application/xml",
                                                                            mjcf.encode())]))  # fmt: skip
    rng = np.random.default_rng(1)
    start = time.time_ns()
    frames = int(seconds * 60)
    for k in range(frames):
        ns = start + k * 1_000_000_000 // 60
        frame = PoseFrame(k + 1, k / 60, rng.normal(size=(len(bodies), 3)), rng.normal(size=(len(bodies), 4)))
        files.write(fx.TOPIC_TRANSFORMS, TRANSFORMS, fx.frame_transforms(frame, bodies, ns).encode(), ns, seq=k + 1)
        if k % 12 in (0, 2, 5, 7, 10):  # 25 a second
            for m in range(1, 9):
                view = {"node": f"m{m}", "object": "joint.angle", "seq": k, "t": k / 60, "value": float(rng.normal())}
                files.write(f"/m{m}/joint.angle", ATTRIBUTE, json.dumps(view).encode(), ns + m)
        if k % 60 == 0:
            status = {"robot": "robot", "mode": "simulated", "modules": 8, "estop": []}
            files.write(fx.TOPIC_STATUS, STATUS, json.dumps(status).encode(), ns + 9)
    files.close()
    return frames


def frames_shown(path: Path) -> tuple[int, int, float]:
    """(distinct frames seen, frames recorded, seconds played) for a play at 1x."""
    recording = open_recording(path)
    source = ReplaySource(recording)
    seen: set[int] = set()
    try:
        source.request("play")
        began = time.monotonic()
        deadline = began + recording.duration + 10
        while time.monotonic() < deadline:
            if source.wait_changed(0.1) and source.latest is not None:
                seen.add(source.latest.seq)
            if not source.playing and source.time() >= recording.duration:
                break
        played = time.monotonic() - began
    finally:
        source.close()
    return len(seen), len(recording.frames), played


def main() -> None:
    load_avg = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as folder:
        short = Path(folder) / "short.mcap"
        write(short, 10.0)
        shown, recorded, played = frames_shown(short)
        print(f"played {played:.2f} s: {shown} distinct frames shown of {recorded} recorded (load {load_avg:.2f})")
        print(f"ratio replay_frames_shown_1x {shown / recorded:.3f} (target >= 0.95)")
        minute = Path(folder) / "minute.mcap"
        write(minute, 60.0)
        began = time.perf_counter()
        recording = open_recording(minute)
        took = time.perf_counter() - began
        size = minute.stat().st_size / 2**20
        print(f"opened {size:.1f} MB, {len(recording.frames)} frames, {len(recording.series)} series in {took:.2f} s")
        print(f"ratio replay_open_s_per_recorded_min {took / (recording.duration / 60):.3f} (target <= 2)")


if __name__ == "__main__":
    main()
