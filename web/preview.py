"""The MuJoCo preview: a loop thread that owns the simulation (the view that draws its frames in viser is
web/scene_view.py).

As in mjviser, the loop that owns MjData is the only code that touches it: GUI callbacks only queue requests
(:meth:`PreviewLoop.request`), and the loop records frames (time, qpos, goals, angles) into a bounded history that the
view and the timeline read. Scrubbing and stepping back show recorded frames; Play from a scrubbed point replays
the recorded frames from there at the chosen speed, and the simulation goes on once they are played.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from asm_py.cli import module_selection
from gaits.model import Gait
from gaits.sim import Metrics, Simulation, select_modules
from gaits.terrain import FLAT, Terrain

FRAME_RATE = 60.0
"""Recorded frames per simulated second: the timeline's resolution, and what the view draws at speed 1."""
HISTORY_SECONDS = 300.0
"""Five minutes of frames the timeline can go back to (bounded: a 128-module chain keeps about 70 MB)."""


@dataclass(frozen=True)
class Frame:
    time: float
    qpos: np.ndarray
    goals: tuple[float, ...]
    """Each module's joint.goal (degrees) at this time."""
    angles: tuple[float, ...]
    """Each module's measured joint angle (degrees)."""
    metrics: Metrics | None = None
    """Distance, speed, heading and peak torque since the gait (re)started, as they were at this frame: the metrics
    follow the timeline as the pose does."""
    running: int = -1
    """How many modules' gaits ran at this frame (0: a one-shot program ended, or the gaits were stopped)."""
    states: tuple[int, ...] = ()
    """Each module's automaton state at this frame, -1 where its gait did not run (gaits.sim.Simulation.states)."""


class PreviewLoop:
    """Runs a gait's Simulation in real time × ``speed`` on its own thread; see the module docstring."""

    def __init__(self, gait: Gait, *, c_modules: str | None = None) -> None:
        self.c_modules = c_modules
        """Modules the preview runs in C, as the robot does (``--c-modules``: "odd", "even", "all" or "1,3,5")."""
        self.terrain: Terrain = FLAT
        """The ground the preview runs on (the Preview tab's picker: ``request("terrain", …)``)."""
        self._requests: queue.Queue[tuple[str, Any]] = queue.Queue()
        self._lock = threading.Lock()
        self.frames: deque[Frame] = deque(maxlen=int(HISTORY_SECONDS * FRAME_RATE))
        self.cursor: int | None = None
        """Index into ``frames`` shown while scrubbing; None: the live end."""
        self.playing = True
        self.held = False
        """Nobody looks at the page (the dashboard sets it): the simulation waits where it is, as if paused, and goes
        on from there when a browser comes (it was half of an unwatched studio's CPU). Not the user's Play/Pause."""
        self.speed = 1.0
        self.error: str | None = None
        self.ended_at: float | None = None
        """Simulated time at which no module's gait ran any more (a one-shot program's end), None while one runs."""
        self.generation = 0
        """Incremented whenever a new gait is loaded (the view rebuilds its meshes)."""
        self.sim = self._new_sim(gait)
        self._next_frame = 0.0
        """Simulated time at which the next frame is due."""
        self._start_com = self.sim.center_of_mass()
        self._stop = threading.Event()
        self._changed = threading.Event()
        self._wake = threading.Event()
        """Set by a request, a hold or release, or close: a loop with nothing to simulate waits on it."""
        self._thread = threading.Thread(target=self._run, name="preview-loop", daemon=True)
        self._thread.start()

    def _new_sim(self, gait: Gait) -> Simulation:
        c_modules = select_modules(module_selection(self.c_modules), gait) if self.c_modules else ()
        sim = Simulation(gait, c_modules=c_modules, terrain=self.terrain)
        sim.start()
        return sim

    # -- what GUI callbacks call ----------------------------------------------------------------------------------

    @property
    def gait(self) -> Gait:
        """The gait the preview simulates now (the last valid edit)."""
        return self.sim.gait

    def request(self, kind: str, value: Any = None) -> None:
        """Queue ``load`` (a Gait), ``terrain`` (a Terrain: the same gait again on it), ``play`` (bool), ``speed``,
        ``seek`` (frame index), ``step`` (±1), ``reset``,
        ``drive`` ((program gait or "stop", direction)), ``signal`` (a broadcast signal number)."""
        self._requests.put((kind, value))
        self._wake.set()

    def hold(self, held: bool) -> None:
        """Hold the simulation while nobody watches (``held``), or let it go on (see ``held``)."""
        if held != self.held:
            self.held = held
            self._wake.set()

    def wait_changed(self, timeout: float) -> bool:
        """Wait until what :meth:`shown` returns may have changed (a frame recorded, a request handled)."""
        changed = self._changed.wait(timeout)
        self._changed.clear()
        return changed

    def shown(self) -> Frame | None:
        with self._lock:
            if not self.frames:
                return None
            index = len(self.frames) - 1 if self.cursor is None else min(self.cursor, len(self.frames) - 1)
            return self.frames[index]

    def metrics(self) -> Metrics:
        """Distance and speed since the gait (re)started, on the centre of mass, at the frame shown (the newest one
        while playing, the timeline's one when scrubbed or stepped)."""
        with self._lock:
            if self.cursor is not None and self.frames:
                frame = self.frames[min(self.cursor, len(self.frames) - 1)]
                if frame.metrics is not None:
                    return frame.metrics
            return self.sim.measure(self._start_com, self.sim.data.time)

    def series(self, module_index: int, seconds: float = 5.0) -> tuple[np.ndarray, ...]:
        """Time, commanded and measured angle (degrees) of one module over the ``seconds`` of frames up to the one
        shown (so the plot follows the timeline with the pose and the metrics)."""
        with self._lock:
            frames = list(self.frames)
            cursor = self.cursor
        if frames and cursor is not None:
            frames = frames[: min(cursor, len(frames) - 1) + 1]
        frames = [f for f in frames if f.time >= frames[-1].time - seconds] if frames else []
        if not frames:
            return (np.zeros(1), np.zeros(1), np.zeros(1))
        t = np.array([f.time for f in frames])
        goal = np.array([f.goals[module_index] if module_index < len(f.goals) else math.nan for f in frames])
        angle = np.array([f.angles[module_index] if module_index < len(f.angles) else math.nan for f in frames])
        return (t, goal, angle)

    def state_history(self, seconds: float) -> tuple[np.ndarray, np.ndarray]:
        """Times (n,) and each module's state (n, modules) over the ``seconds`` of frames up to the one shown: the
        states-over-time view follows the timeline as the plot does."""
        with self._lock:
            frames = list(self.frames)
            cursor = self.cursor
        if frames and cursor is not None:
            frames = frames[: min(cursor, len(frames) - 1) + 1]
        frames = [f for f in frames if f.time >= frames[-1].time - seconds and f.states] if frames else []
        width = len(frames[-1].states) if frames else 0
        frames = [f for f in frames if len(f.states) == width]
        return (np.array([f.time for f in frames], dtype=float),
                np.array([f.states for f in frames], dtype=int).reshape(len(frames), width))  # fmt: skip

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=10)
        self.sim.close()

    # -- the loop -------------------------------------------------------------------------------------------------

    def _run(self) -> None:
        last = time.monotonic()
        owed = 0.0
        while not self._stop.is_set():
            for kind, value in self._pending():
                self._handle(kind, value)
                self._changed.set()
            now = time.monotonic()
            if self.held or not self.playing or (self.error is not None and self.cursor is None):
                self._wake.wait(0.25)  # nothing to simulate or replay: wait for a request rather than poll
                self._wake.clear()
                last = time.monotonic()
                continue
            if self.cursor is not None:  # played from a scrubbed point: the recorded frames first
                owed = min(owed + (now - last) * self.speed, 0.25)
                owed = self._replay(owed)
            else:
                owed = min(owed + (now - last) * self.speed, 0.25)  # never try to catch up more than 0.25 s
                dt = self.sim.model.opt.timestep
                try:
                    while owed >= dt:
                        steps = min(self._steps_to_next_frame(), int(owed / dt + 1e-9))
                        self._advance(steps)
                        owed -= steps * dt
                except Exception as exc:  # a diverging model is shown, not fatal
                    self.error = f"simulation stopped: {exc}"
            last = now
            time.sleep(1 / 240)

    def _pending(self) -> list[tuple[str, Any]]:
        """The queued requests, of which only the newest ``load`` counts (typing 12 loads 1, then 12)."""
        requests: list[tuple[str, Any]] = []
        try:
            while True:
                requests.append(self._requests.get_nowait())
        except queue.Empty:
            pass
        loads = [k for k, (kind, _) in enumerate(requests) if kind == "load"]
        return [r for k, r in enumerate(requests) if r[0] != "load" or k == loads[-1]]

    def _replay(self, owed: float) -> float:
        """Move the cursor through the recorded frames by ``owed`` seconds of simulated time; at the newest frame
        the simulation takes over (the cursor goes). Returns the time still owed."""
        with self._lock:
            if self.cursor is None:
                return owed
            end = len(self.frames) - 1
            while owed >= 1 / FRAME_RATE and self.cursor < end:
                self.cursor += 1
                owed -= 1 / FRAME_RATE
            if self.cursor >= end:
                self.cursor = None
            self._changed.set()
        return owed

    def _steps_to_next_frame(self) -> int:
        due = self._next_frame - self.sim.data.time
        return max(1, math.ceil(due / self.sim.model.opt.timestep - 1e-6))

    def _advance(self, steps: int) -> None:
        sim = self.sim
        with self._lock:
            sim.step_physics(steps)
            if sim.data.time >= self._next_frame - 1e-9:  # frames on a 1/60 s grid of simulated time
                while self._next_frame <= sim.data.time + 1e-9:
                    self._next_frame += 1 / FRAME_RATE
                goals = tuple(sim.goal(a.id) for a in sim.gait.modules)
                angles = tuple(sim.angle(a.id) for a in sim.gait.modules)
                metrics = sim.measure(self._start_com, sim.data.time)
                running = sim.running()
                if running == 0 and self.ended_at is None:
                    self.ended_at = sim.data.time
                elif running:
                    self.ended_at = None
                self.frames.append(Frame(sim.data.time, sim.data.qpos.copy(), goals, angles, metrics, running,
                                         sim.states()))  # fmt: skip
                self._changed.set()

    def _handle(self, kind: str, value: Any) -> None:
        if kind in ("load", "reset", "terrain"):
            gait = value if kind == "load" else self.sim.gait
            before = self.terrain
            if kind == "terrain":
                self.terrain = value
            try:
                new = self._new_sim(gait)
            except Exception as exc:
                self.terrain = before
                self.error = f"cannot simulate this gait: {exc}"
                return
            with self._lock:
                old, self.sim = self.sim, new
                self.frames.clear()
                self._next_frame = 0.0
                self.cursor = None
                self.ended_at = None
                self._start_com = new.center_of_mass()
                self.error = None
                self.generation += 1
            old.close()
        elif kind == "drive":  # the Drive panel: (program gait or "stop", direction), as a robot would get it
            name, direction = value
            with self._lock:
                if name == "stop":
                    self.sim.stop_gaits()
                else:
                    self.sim.drive(name, direction)
            self.playing = True
            self.cursor = None
        elif kind == "signal":  # the Drive panel's broadcast signal, as every module on a bus would hear it
            with self._lock:
                self.sim.signal(int(value))
        elif kind == "play":  # from where the timeline is: a scrubbed point replays what was recorded from there
            self.playing = bool(value)
        elif kind == "speed":
            self.speed = max(0.05, min(float(value), 8.0))
        elif kind == "seek":
            self.playing = False
            with self._lock:
                self.cursor = max(0, min(int(value), len(self.frames) - 1))
        elif kind == "step":
            self.playing = False
            with self._lock:
                end = len(self.frames) - 1
                cursor = end if self.cursor is None else self.cursor
            if value > 0 and cursor >= end:  # at the live end: simulate until the next frame is recorded
                last = self.frames[-1].time if self.frames else None
                while not self.frames or self.frames[-1].time == last:
                    self._advance(self._steps_to_next_frame())
                self.cursor = None
            else:
                with self._lock:
                    self.cursor = max(0, min(cursor + (1 if value > 0 else -1), end))
