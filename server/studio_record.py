"""The studio's Record button: the robot the page shows, recorded to MCAP by the same Recorder ``asm-record`` uses
(server/record.py), on the studio's own Zenoh session — channels, schemas, metadata and attachments as
docs/protocol.md §11 describes, the edited gait embedded.

Starting looks the robot up (a round trip, up to ``wait`` seconds) and stopping finishes the file (up to the
writer's queue): both run on this object's own thread, so the page's callbacks only queue a request.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from .mcap_files import Attachment, McapFiles, RecordingInfo
from .record import CHUNK_SIZE, Recorder, find_robot

Said = Callable[[str, bool], None]
"""What a request ended with: (one line for the page, whether it is an error)."""


def recording_path(folder: Path, robot: str, when: float | None = None) -> Path:
    """``<robot>-<date>-<time>.mcap`` in ``folder``, to the second; ``-2``, ``-3``… when that name is taken (a Stop
    and a Record within one second): a recording is never written over."""
    stamp = f"{robot}-{time.strftime('%Y%m%d-%H%M%S', time.localtime(when))}"
    for k in range(1, 10_000):
        path = folder / (f"{stamp}.mcap" if k == 1 else f"{stamp}-{k}.mcap")
        if not path.exists():
            return path
    raise FileExistsError(f"{folder}: every name of {stamp}.mcap is taken")


class StudioRecording:
    """Start and stop recordings of a robot into ``folder`` (one file each, named by the time it started)."""

    def __init__(self, session: zenoh.Session, folder: Path, wait: float = 5.0) -> None:
        self.session = session
        self.folder = folder
        self.wait = wait
        self.recorder: Recorder | None = None
        self.path: Path | None = None
        """The file being written, or the last one written."""
        self._started = 0.0
        self._requests: queue.Queue[tuple[str, tuple[object, ...], Said] | None] = queue.Queue()
        self._thread = threading.Thread(target=self._run, name="studio-record", daemon=True)
        self._thread.start()

    @property
    def recording(self) -> bool:
        return self.recorder is not None

    def request_start(self, robot: str, gait_name: str, gait_text: str, said: Said) -> None:
        self._requests.put(("start", (robot, gait_name, gait_text), said))

    def request_stop(self, said: Said) -> None:
        self._requests.put(("stop", (), said))

    def _run(self) -> None:
        while (request := self._requests.get()) is not None:
            kind, args, said = request
            try:
                said(self._start(*args) if kind == "start" else self._stop(), False)  # type: ignore[arg-type]
            except Exception as exc:
                said(f"{kind} refused: {exc}", True)

    def _start(self, robot: str, gait_name: str, gait_text: str) -> str:
        if self.recorder is not None:
            return f"already recording to {self.path}"
        status, mjcf = find_robot(self.session, robot, self.wait)
        self.folder.mkdir(parents=True, exist_ok=True)
        path = recording_path(self.folder, robot)
        info = RecordingInfo({"robot": robot, "mode": status.mode, "modules": str(status.modules),
                              "recorder": "asm-studio", "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                              "gait": f"{gait_name}.toml"})  # fmt: skip
        if mjcf:
            info.attachments.append(Attachment("robot.mjcf", "application/xml", mjcf.encode()))
        if gait_text:
            info.attachments.append(Attachment(f"{gait_name}.toml", "application/toml", gait_text.encode()))
        self.recorder = Recorder(self.session, robot, McapFiles(path, info, chunk_size=CHUNK_SIZE), mjcf)
        self.path, self._started = path, time.monotonic()
        return f"recording robot {robot} to {path}"

    def _stop(self) -> str:
        recorder = self.recorder
        if recorder is None:
            return "not recording"
        self.recorder = None
        seconds = time.monotonic() - self._started
        recorder.close({"seconds": f"{seconds:.3f}"})
        missed = f", {recorder.missed} missing from their sequences" if recorder.missed else ""
        return (f"recorded {sum(recorder.counts.values())} messages in {seconds:.1f} s ({recorder.dropped} dropped"
                f"{missed}) to {self.path}")  # fmt: skip

    def close(self) -> None:
        """Finish a recording still running, and end the thread."""
        self._requests.put(("stop", (), lambda _text, _error: None))
        self._requests.put(None)
        self._thread.join(15)
