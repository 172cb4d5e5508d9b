"""The Replay source of the 3D view: a recording (web/recording.py) played on a clock of its own.

In the spirit of web/live.py: the view reads ``model``, ``latest`` and ``generation`` of a source and waits on
``wait_changed``; here ``latest`` is the recorded pose frame at the replay clock's time, the model the one attached
to the recording. One thread (``replay-loop``) owns the clock: the page's callbacks only ``request`` play, pause,
seek, step and speed, and the loop moves the frame shown. What the plots and the roster show is read from the
recording at :meth:`ReplaySource.time` (:func:`plot_data`, :func:`last_values`), so they follow a scrub as the
3D view does.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from bisect import bisect_left, bisect_right
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from asm_module.feed import PoseFrame

from .recording import Recording

log = logging.getLogger("asm_studio.replay")
SPEEDS = (0.25, 0.5, 1.0, 2.0, 4.0)
"""The replay speeds the page offers (and the only ones the clock takes)."""
MAX_WAIT = 0.25
"""The longest the loop sleeps while playing (s): the plots and the values move on between sparse frames."""


class ReplayClock:
    """Replay time in [0, duration]: runs at ``speed`` × the wall clock (``now``) while playing, stops at the end.

    Scrubbing (``seek``) keeps playing or paused as it was; Play at the end starts again from 0."""

    def __init__(self, duration: float, now: Callable[[], float] = time.monotonic) -> None:
        if not np.isfinite(duration) or duration < 0:
            raise ValueError(f"a replay lasts a finite, non-negative time, not {duration!r}")
        self.duration = float(duration)
        self._now = now
        self._base = 0.0
        """Replay time at ``_since``."""
        self._since = now()
        self.playing = False
        self.speed = 1.0

    def time(self) -> float:
        if not self.playing:
            return self._base
        t = self._base + (self._now() - self._since) * self.speed
        if t >= self.duration:  # the end: stays there, paused
            self._base, self.playing = self.duration, False
            return self.duration
        return t

    @property
    def ended(self) -> bool:
        return self.time() >= self.duration

    def _rebase(self, t: float) -> None:
        self._base, self._since = t, self._now()

    def play(self) -> None:
        t = self.time()
        self._rebase(0.0 if t >= self.duration else t)
        self.playing = self.duration > 0

    def pause(self) -> None:
        self._rebase(self.time())
        self.playing = False

    def seek(self, t: float) -> None:
        """Go to ``t`` (clamped to the recording: a scrub past the end shows the end)."""
        if not isinstance(t, int | float) or isinstance(t, bool) or not np.isfinite(t):
            raise ValueError(f"a replay time is a number of seconds, not {t!r}")
        self.time()  # an end reached meanwhile pauses first
        self._rebase(min(max(float(t), 0.0), self.duration))

    def set_speed(self, speed: float) -> None:
        """One of SPEEDS; anything else is refused (never clamped)."""
        if speed not in SPEEDS:
            raise ValueError(f"replay speed {speed!r} is not one of {', '.join(f'{s:g}x' for s in SPEEDS)}")
        self._rebase(self.time())
        self.speed = float(speed)


def step_time(times: list[float], t: float, direction: int) -> float:
    """The recorded time one frame after (``direction`` 1) or before (-1) ``t``; ``t`` itself at either end."""
    if direction > 0:
        index = bisect_right(times, t)
        return times[index] if index < len(times) else t
    index = bisect_left(times, t) - 1
    return times[index] if index >= 0 else (times[0] if times else t)


class ReplaySource:
    """Plays ``recording``: its own model and the frame at the clock's time (see the module docstring)."""

    def __init__(self, recording: Recording, now: Callable[[], float] = time.monotonic) -> None:
        self.recording = recording
        self.clock = ReplayClock(recording.duration, now)
        self.model: mujoco.MjModel | None = None
        self.error: str | None = None
        """Why the 3D view cannot show this recording (no model attached, a model that does not load)."""
        if recording.mjcf is None:
            self.error = "the recording has no robot model attached: plots and values only"
        else:
            try:
                model = mujoco.MjModel.from_xml_string(recording.mjcf)
            except ValueError as exc:
                self.error = f"the robot model attached does not load: {exc}"
            else:
                if recording.frames and model.nbody - 1 != len(recording.frames[0].positions):
                    self.error = (f"the model attached has {model.nbody - 1} bodies, the poses "
                                  f"{len(recording.frames[0].positions)}: not drawn")  # fmt: skip
                else:
                    self.model = model
        self.generation = 1
        self.status = None
        self.latest: PoseFrame | None = recording.frame_at(0.0)
        self._times = recording.frame_times
        self._now_t = 0.0
        self._now_playing = False
        """Whether the clock played when ``_now_t`` was shown: the page reads the two together (:meth:`shown`)."""
        self._lock = threading.Lock()
        self._requests: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        self._changed = threading.Event()
        self._changed.set()
        self._thread = threading.Thread(target=self._run, name="replay-loop", daemon=True)
        self._thread.start()

    # -- what GUI callbacks call ----------------------------------------------------------------------------------

    def request(self, kind: str, value: Any = None) -> None:
        """Queue ``play``, ``pause``, ``seek`` (seconds), ``step`` (±1 frame) or ``speed`` (one of SPEEDS)."""
        self._requests.put((kind, value))

    def time(self) -> float:
        """The replay time shown now (set by the loop)."""
        return self._now_t

    def shown(self) -> tuple[float, bool]:
        """The replay time shown now and whether it was shown playing, read together: the clock's own state changes
        before the loop shows its time, and a page that read them apart said "paused" beside the time before the
        pause (a fresh-clone run's page test read 2.22 s paused, then 2.23)."""
        with self._lock:
            return self._now_t, self._now_playing

    @property
    def playing(self) -> bool:
        return self.clock.playing

    def wait_changed(self, timeout: float) -> bool:
        changed = self._changed.wait(timeout)
        self._changed.clear()
        return changed

    # -- the loop -------------------------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            try:
                request = self._requests.get(timeout=self._until_next_frame())
            except queue.Empty:
                request = ()
            if request is None:
                return
            if request:
                try:
                    self._handle(*request)
                except (ValueError, TypeError) as exc:  # a request the page should not have sent: said, not fatal
                    self.error = str(exc)
                    log.info("replay request refused: %s", exc)
            self._show(self.clock.time())

    def _until_next_frame(self) -> float:
        """Wall-clock seconds until the next recorded frame is due: at 1x every frame is shown, at its time (a
        fixed tick beating against the recording's own rate would skip some)."""
        clock = self.clock
        if not clock.playing:
            return MAX_WAIT
        t = clock.time()
        index = bisect_right(self._times, t)
        due = self._times[index] if index < len(self._times) else clock.duration
        return min(MAX_WAIT, max(0.001, (due - t) / clock.speed))

    def _handle(self, kind: str, value: Any) -> None:
        clock = self.clock
        if kind == "play":
            clock.play() if value is None or value else clock.pause()
        elif kind == "pause":
            clock.pause()
        elif kind == "seek":
            clock.seek(value)
        elif kind == "step":
            clock.pause()
            clock.seek(step_time(self._times, clock.time(), 1 if value > 0 else -1))
        elif kind == "speed":
            clock.set_speed(value)
        else:
            raise ValueError(f"no replay request {kind!r}")

    def _show(self, t: float) -> None:
        frame = self.recording.frame_at(t)
        playing = self.clock.playing
        with self._lock:
            moved = frame is not self.latest or t != self._now_t or playing != self._now_playing
            self.latest, self._now_t, self._now_playing = frame, t, playing
        if moved:
            self._changed.set()

    def close(self) -> None:
        self._requests.put(None)
        self._thread.join(5)


def plot_samples(
    recording: Recording, keys: list[tuple[str, str]], t: float, window: float
) -> tuple[list[str], list[tuple[list[float], list[Any]]]]:
    """Labels and the recorded samples of ``keys`` from ``t - window`` up to ``t``: each series' own times and its
    values exactly as the file holds them (what the replay plot's exports write; :func:`plot_data` draws them).
    An attribute whose values are not all numbers (text, lists) is left out: it is not plotted."""
    labels, picked = [], []
    for node, obj in keys:
        series = recording.series.get((node, obj))
        if series is None or not all(isinstance(v, int | float) for v in series.values):  # text, lists: not plotted
            continue
        end = series.until(t)
        start = series.until(t - window) if window > 0 else 0
        labels.append(f"{node} {obj}")
        picked.append((list(series.times[start:end]), list(series.values[start:end])))
    return labels, picked


def plot_data(
    recording: Recording, keys: list[tuple[str, str]], t: float, window: float
) -> tuple[list[str], tuple[np.ndarray, ...]]:
    """Labels and uPlot data of ``keys``' recorded values from ``t - window`` up to ``t`` (:func:`plot_samples`):
    every series' own sample times, merged; a series is interpolated between its samples onto the others' times (at
    its own times its values are exactly the recorded ones) and held at its ends — as LivePlot.data draws live
    values. A series with nothing recorded up to ``t`` is all NaN: no value, no line drawn (SeriesPlot)."""
    labels, samples = plot_samples(recording, keys, t, window)
    picked = [(np.array(times, dtype=float), np.array([float(v) for v in values], dtype=float))
              for times, values in samples]  # fmt: skip
    times = np.unique(np.concatenate([t_ for t_, _ in picked])) if picked else np.zeros(0)
    if not len(times):  # nothing recorded up to t: one point at t, no value (SeriesPlot draws no line)
        return labels, (np.full(1, float(t)), *(np.full(1, np.nan) for _ in labels))
    columns = [np.interp(times, t_, v) if len(t_) else np.full(len(times), np.nan) for t_, v in picked]
    return labels, (times, *columns)


def last_values(recording: Recording, t: float) -> dict[str, dict[str, Any]]:
    """node → object → its last value recorded at or before ``t`` (objects with none yet are left out)."""
    out: dict[str, dict[str, Any]] = {}
    for (node, obj), series in sorted(recording.series.items()):
        n = series.until(t)
        if n:
            out.setdefault(node, {})[obj] = series.values[n - 1]
    return out
