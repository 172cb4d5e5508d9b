"""The MuJoCo preview: a loop thread that owns the simulation, and a view that draws frames of it in viser.

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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import viser

from asm_py.cli import module_selection
from gaits.model import Gait
from gaits.sim import Metrics, Simulation, select_modules
from gaits.terrain import FLAT, Terrain

from .ground import GroundView
from .scene_geometry import BOX_FACES, box_vertices, geom_poses, hinge_anchors
from .trail import Trail

FRAME_RATE = 60.0
"""Recorded frames per simulated second: the timeline's resolution, and what the view draws at speed 1."""
HISTORY_SECONDS = 300.0
"""Five minutes of frames the timeline can go back to (bounded: a 128-module chain keeps about 70 MB)."""
GRID_CELL = 0.1
"""Metres between the ground grid's lines."""


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


LABEL_EVERY = 6
"""Module labels move with every sixth drawn frame (10 Hz at 60 frames a second): enough to read them, and 32
labels at full rate would double what the page receives."""


class SceneView:
    """Draws the robot in viser's scene, from the preview or from the live robot: one batched mesh per distinct
    module shape.

    ``source`` is "preview" (frames of a PreviewLoop) or "live" (the robot process's pose feed, a LiveFeed); a label
    in the scene says which one is shown. Lighting is plain by default — no shadows, no environment map: a browser
    without a GPU (software WebGL) draws a moving 32-module robot about 4× faster that way (bench/studio.py).
    ``rich=True`` turns both on.

    With ``follow`` (the default) the robot stays in the middle of the view and the ground moves under it: a gait
    crawls out of a fixed camera's view in seconds. The ground grid is shifted by the robot's position modulo one
    grid cell, so its lines move exactly as the floor would."""

    def __init__(self, server: viser.ViserServer, loop: PreviewLoop, live: Any = None, *, rich: bool = False) -> None:
        self.server = server
        self.loop = loop
        self.live = live
        self.replay: Any = None
        """A recording played (web/replay.py's ReplaySource): the Replay tab sets it, then shows "replay"."""
        self.source = "preview"
        self._data: mujoco.MjData | None = None
        self._model: mujoco.MjModel | None = None
        self._batches: list[tuple[Any, np.ndarray]] = []
        self._built: tuple[Any, ...] | None = None
        self._drawn: object = None
        self._redraw = threading.Event()
        self.rich = rich
        self.follow = True
        self.labels = True
        """Show each module's name at its joint."""
        self._labels: list[Any] = []
        self._label_joints = np.zeros(0, dtype=int)
        self._draws = 0
        self.on_pick: Callable[[int], None] | None = None
        """Called with a module ID when the user clicks that module in the 3D view (on viser's thread pool)."""
        self._terrain = GroundView(server)
        """A rough ground, a step, patches: drawn from the preview's model (the flat floor is the grid)."""
        self._ground = server.scene.add_grid("/ground", width=4.0, height=4.0, cell_size=GRID_CELL, plane="xy")
        self._label = server.scene.add_label("/source", "PREVIEW", position=(0.0, 0.0, 0.25))
        self.trail = Trail(server.scene)
        self.set_rich(rich)

    def set_rich(self, rich: bool) -> None:
        """Shadows and the environment map on or off (the meshes are rebuilt at the next draw)."""
        self.rich = rich
        self.server.scene.configure_default_lights(cast_shadow=rich)
        if rich:
            self.server.scene.configure_environment_map()
        else:
            self.server.scene.configure_environment_map(None)
        self._built = None

    def set_source(self, source: str) -> None:
        """Show the "preview", the "live" robot or a "replay" of a recording (rebuilt at the next draw)."""
        if source not in ("preview", "live", "replay") or (source != "preview" and getattr(self, source) is None):
            raise ValueError(f"no {source!r} source to show")
        self.source = source
        self._built = None

    def redraw(self) -> None:
        """Draw the newest frame again at the next draw (a browser connected after frames went undrawn)."""
        self._drawn = None
        self._redraw.set()

    def wait_changed(self, timeout: float) -> bool:
        """Wait until the shown source may have something new to draw."""
        if self._redraw.is_set():
            self._redraw.clear()
            return True
        if self.source in ("live", "replay"):
            return getattr(self, self.source).wait_changed(timeout)
        return self.loop.wait_changed(timeout)

    def _wanted(self) -> tuple[mujoco.MjModel | None, tuple[Any, ...]]:
        if self.source in ("live", "replay"):
            feed = getattr(self, self.source)
            return feed.model, (self.source, feed.generation, id(feed))
        return self.loop.sim.model, ("preview", self.loop.generation)

    def _build(self, model: mujoco.MjModel, key: tuple[Any, ...]) -> None:
        for handle, _ in self._batches:
            handle.remove()
        for label in self._labels:
            label.remove()
        self._batches, self._labels = [], []
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or "" for j in range(model.njnt)]
        hinges = sorted((int(n[1:]), j) for j, n in enumerate(names) if n[:1] == "m" and n[1:].isdigit())
        self._label_joints = np.array([j for _, j in hinges], dtype=int)
        if self.labels:
            self._labels = [self.server.scene.add_label(f"/robot/label{k}", f"m{k}", position=(0.0, 0.0, 0.0))
                            for k, _ in hinges]  # fmt: skip
        self._model = model
        self._data = mujoco.MjData(model)
        groups: dict[tuple[float, float, float], list[int]] = {}
        # capsule chains collide with capsules but show their modules as the boxes of their visual geoms
        visual_bodies = {int(model.geom_bodyid[g]) for g in range(model.ngeom) if model.geom_group[g] == 1}
        for g in range(model.ngeom):
            body, kind = int(model.geom_bodyid[g]), model.geom_type[g]
            if body == 0:
                continue  # the floor
            if model.geom_group[g] != 1 and body in visual_bodies:
                continue
            size = model.geom_size[g]
            if kind == mujoco.mjtGeom.mjGEOM_BOX:
                half = (float(size[0]), float(size[1]), float(size[2]))
            elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                half = (float(size[0]), float(size[0]), float(size[1] + size[0]))
            else:
                continue
            groups.setdefault((round(half[0], 5), round(half[1], 5), round(half[2], 5)), []).append(g)
        # live blue, a replay violet (apart from the green trail and the magenta heading arrow), the preview tan
        color = {"live": (60, 130, 200), "replay": (140, 70, 210)}.get(key[0], (217, 140, 38))
        for n, (half, geoms) in enumerate(groups.items()):
            ids = np.array(geoms)
            handle = self.server.scene.add_batched_meshes_simple(
                f"/robot/shape{n}", box_vertices(np.array(half)), BOX_FACES,
                batched_wxyzs=np.tile([1.0, 0, 0, 0], (len(ids), 1)), batched_positions=np.zeros((len(ids), 3)),
                batched_colors=color, cast_shadow=self.rich, receive_shadow=self.rich, lod="off",
            )  # fmt: skip
            self._batches.append((handle, ids))
            handle.on_click(lambda event, ids=ids, model=model: self._picked(model, ids, event.instance_index))
        self._terrain.build(model if key[0] == "preview" else None)
        self._ground.visible = not self._terrain.covers_start
        self._built = key
        self._drawn = None
        self.trail.reset()

    def _picked(self, model: mujoco.MjModel, ids: np.ndarray, instance: int | None) -> None:
        """A click on a piece of the robot: the module whose hinge starts that piece (``b<k>`` holds the half
        modules on either side of hinge k, so the piece b<k> belongs to module k, and b0 to module 1)."""
        if instance is None or self.on_pick is None or not 0 <= instance < len(ids):
            return
        body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[ids[instance]])) or ""
        if body.startswith("b") and body[1:].isdigit():
            joints = sum(1 for j in range(model.njnt) if (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or "")
                         .startswith("m"))  # fmt: skip
            self.on_pick(min(max(int(body[1:]), 1), max(joints, 1)))

    def _poses(self) -> tuple[object, np.ndarray, np.ndarray] | None:
        """(what is drawn, body positions, body orientations) of the shown source, bodies 1.. of its model."""
        if self.source in ("live", "replay"):
            frame = getattr(self, self.source).latest
            model = self._model
            if frame is None or model is None or len(frame.positions) != model.nbody - 1:
                return None
            return frame, frame.positions, frame.quaternions
        frame = self.loop.shown()
        data, model = self._data, self._model
        if frame is None or data is None or model is None or len(frame.qpos) != data.qpos.shape[0]:
            return None
        data.qpos[:] = frame.qpos
        mujoco.mj_kinematics(model, data)
        return frame, data.xpos[1:], data.xquat[1:]

    def draw(self) -> bool:
        """Draw the shown source's newest frame; False if there is none yet or it is the one already drawn."""
        model, key = self._wanted()
        if model is None:
            return False
        if self._built != key:
            self._build(model, key)
            twin = key[0] == "live" and self.live.latest is not None and not self.live.latest.simulated
            self._label.text = ("LIVE — real robot: kinematic twin from its joint angles, base fixed" if twin
                                else "LIVE — the robot" if key[0] == "live"
                                else f"REPLAY — {self.replay.recording.name}" if key[0] == "replay"
                                else "PREVIEW — simulation of the edited gait")  # fmt: skip
        poses, built = self._poses(), self._model
        if poses is None or built is None or poses[0] is self._drawn:
            return False
        self._drawn, xpos, xquat = poses
        shift = np.zeros(3)
        placed = [(handle, *geom_poses(built, xpos, xquat, ids)) for handle, ids in self._batches]
        middle = np.concatenate([pos for _, pos, _ in placed]).mean(axis=0) if placed else np.zeros(3)
        if self.follow:
            shift[:2] = middle[:2]
        with self.server.atomic():
            for handle, pos, wxyz in placed:
                handle.batched_positions = (pos - shift).astype(np.float32)
                handle.batched_wxyzs = wxyz.astype(np.float32)
            self._ground.position = (-(shift[0] % GRID_CELL), -(shift[1] % GRID_CELL), 0.0)
            self._terrain.move(shift)
            self.trail.add(middle, shift, float(getattr(self._drawn, "time", 0.0)))  # a preview frame's time
            if self._labels and self._draws % LABEL_EVERY == 0:
                anchors = hinge_anchors(built, xpos, xquat, self._label_joints) - shift
                for label, anchor in zip(self._labels, anchors, strict=True):
                    label.position = (float(anchor[0]), float(anchor[1]), float(anchor[2]) + 0.04)
        # Send it now: after each send viser waits out a 1/60 s window, and a frame drawn inside that window is
        # replaced by the next one (same redundancy key) before it goes out: 60 frames/s reached the page as 54.
        self.server.flush()
        self._draws += 1
        return True

    def set_labels(self, shown: bool) -> None:
        """Module labels on or off (rebuilt at the next draw)."""
        self.labels = shown
        self._built = None
