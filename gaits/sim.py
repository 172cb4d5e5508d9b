"""A gait in MuJoCo, run by the modules' own runtime on the simulation clock.

Every module is a :class:`asm_module.ModuleRuntime` — the program a real module runs — with a MuJoCo actuator as
its joint driver. Its gait table arrives as the bytes a deploying tool would send, and its PeriodicAutomaton runs on
a :class:`~asm_py.clock.SimClock` that this loop advances: one ``gait.tick`` per control period (every module's
automaton and servo react to it, inline, before the physics continues), then the physics steps of that period. The
joint goals MuJoCo sees are therefore exactly what the modules command; nothing here computes a trajectory.

:class:`Simulation` owns the model, the data and the loop; drawing it (viser, MuJoCo's viewer) only reads ``data``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Collection, Mapping
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import mujoco
import numpy as np

from asm_module import JointDriver, JointReading, LocalNeighbours, ModuleRuntime
from asm_module.board_batch import BoardBatch
from asm_module.c_module import CModule
from asm_module.module import Module
from asm_module.names import module_name
from asm_py import Event, Node, SimulationStalled
from asm_py.canbus.simbus import SimBus
from asm_py.clock import SimClock

from .deploy import module_tables
from .metrics import Metrics
from .mjcf import Physics, build_mjcf
from .model import Gait
from .programs import mode_index
from .servo import Servo
from .terrain import FLAT, Terrain

log = logging.getLogger("gaits.sim")


def _warned(text: str) -> None:
    """MuJoCo's warnings go to the log: its own handler printed them and wrote MUJOCO_LOG.TXT into whatever folder
    the command ran in (a divergence is said anyway, as a FloatingPointError)."""
    log.warning("MuJoCo: %s", text.strip())


mujoco.set_mju_user_warning(_warned)


EMULATED_SERIAL = b"ASM-EMU\0"
"""The first 8 bytes of the serial of an emulated board kept for one run only; its chain position the last 4."""


class MujocoJoint(JointDriver):
    """A module's joint as a MuJoCo position actuator (degrees in, radians to MuJoCo)."""

    def __init__(self, sim: Simulation, module_id: int) -> None:
        self._sim = sim
        model = sim.model
        self._actuator = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"m{module_id}")
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"m{module_id}")
        self._qpos = model.jnt_qposadr[joint]
        data = sim.data
        self._positions, self._forces, self._controls = data.qpos, data.actuator_force, data.ctrl
        """Views of MjData's arrays, made once (the data lives as long as the simulation; making a view on every
        read and command was a tenth of a joint's cost at 128 modules × 50 ticks a second; issue 31)."""
        self._module = module_id
        self._gains = (
            float(model.actuator_gainprm[self._actuator, 0]),
            float(model.actuator_biasprm[self._actuator, 2]),
        )
        self._relaxed = False
        self._held: float | None = None
        """The control value (radians) an e-stop holds, or None."""

    def command(self, degrees: float) -> None:
        with self._sim.lock:
            if self._held is not None:
                return
            self._controls[self._actuator] = math.radians(degrees)
            if self._relaxed:
                self._power(*self._gains)
            if self._held is not None:  # an e-stop held the joint meanwhile (it takes no lock): the hold wins
                self._controls[self._actuator] = self._held

    def hold(self) -> float:
        """Hold the joint where it is, without the simulation's lock: a step or a tick in progress never delays an
        e-stop (one float written, as a servo's register would be)."""
        data = self._sim.data
        held = float(data.qpos[self._qpos])
        self._held = held
        data.ctrl[self._actuator] = held
        if self._relaxed:
            self._power(*self._gains)
        return math.degrees(held)

    def release(self) -> None:
        self._held = None

    def read(self) -> JointReading:
        with self._sim.lock:
            return JointReading(math.degrees(self._positions[self._qpos]), float(self._forces[self._actuator]),
                                self._module in self._sim.touching)  # fmt: skip

    def relax(self) -> None:
        with self._sim.lock:
            self._power(0.0, 0.0)

    def _power(self, kp: float, damping: float) -> None:
        """A position actuator with zero gains exerts no torque: the servo is off."""
        model = self._sim.model
        model.actuator_gainprm[self._actuator, 0] = kp
        model.actuator_biasprm[self._actuator, 1] = -kp
        model.actuator_biasprm[self._actuator, 2] = damping
        self._relaxed = kp == 0.0


@dataclass
class Trace:
    """Every module's joint goal at every control tick (for comparing preview and deployment)."""

    times: list[float] = field(default_factory=list)
    goals: list[list[float]] = field(default_factory=list)


def select_modules(selection: Collection[int] | str, gait: Gait) -> tuple[int, ...]:
    """The module IDs of the gait's robot a ``--c-modules`` selection names: "odd", "even", "all" or IDs (those it
    does not have are ignored)."""
    ids = [a.id for a in gait.modules]
    if isinstance(selection, str):
        parity = {"odd": 1, "even": 0, "all": None}[selection]
        return tuple(i for i in ids if parity is None or i % 2 == parity)
    return tuple(i for i in ids if i in selection)


class Simulation:
    """A gait's robot in MuJoCo, driven by one ModuleRuntime per module; see the module docstring.

    ``direction`` -1 runs every module's automaton backwards (the gait's own directions, negated). ``node_of``
    gives each module runtime its ASM node (a robot process puts them on a bus); without it they have none.
    ``c_modules`` (IDs) run the C runtime instead (asm_module.c_module), on the python-can bus ``bus_options`` opens —
    or, without one, on the in-process hub the Python modules of a preview share — ticked by the same tick event.
    ``emulated_modules`` (IDs) run the board image in the emulator (asm_module.emulated), its joint the same MuJoCo
    actuator, on that bus (they need one: a board has no in-process hub), run up to the simulation's time at every
    tick; an ID in both is emulated; ``board_flash`` (asm_module.board_batch) keeps boards that boot with no ID.
    ``modules`` holds every kind by chain position (its joint), driven through one interface (asm_module.module).
    Each Python or C module reports its type's name from the gait's robot description (``module.type``); an
    emulated board reports its own port's.
    ``lock`` guards the model and data: the stepping thread holds it per control period, and a module's joint
    driver takes it, so a request arriving on a bus thread never touches MjData in the middle of a step.
    """

    def __init__(
        self,
        gait: Gait,
        *,
        physics: Physics | None = None,
        control_rate: float = 50.0,
        ramp: float = 1.0,
        direction: int = 1,
        trace: bool = False,
        node_of: Callable[[int], Node] | None = None,
        c_modules: Collection[int] = (),
        emulated_modules: Collection[int] = (),
        bus_options: Mapping[str, Any] | None = None,
        terrain: Terrain = FLAT,
        board_flash: BoardBatch | None = None,
    ) -> None:
        if emulated_modules and bus_options is None:
            raise ValueError("emulated modules need a bus (a robot process's), not a preview's hub")
        self.gait = gait
        self.lock = threading.RLock()
        self.physics = physics or Physics(friction=gait.ground.friction, anisotropic=gait.ground.anisotropic)
        self.terrain = terrain
        self.mjcf = build_mjcf(gait.robot, self.physics, name=gait.name, terrain=terrain)
        self.model = mujoco.MjModel.from_xml_string(self.mjcf)
        self.data = mujoco.MjData(self.model)
        self._servo = None if gait.robot.ideal_servo else Servo(self.model, gait.robot)
        """The torque-speed lines and deadbands (gaits/servo.py); None for ideal servos: MuJoCo's actuators alone."""
        self.clock = SimClock()
        self.tick = Event("gait.tick", codec="float64", clock=self.clock)
        self.steps_per_tick = max(1, round(1.0 / (control_rate * self.model.opt.timestep)))
        self._into_tick = 0
        """Physics steps taken since the last control tick."""
        self.direction = direction
        self.touching: set[int] = set()
        self.trace = Trace() if trace else None
        self._floor = np.array([mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, name)
                                for name in terrain.ground(self.physics.friction).names])  # fmt: skip
        """The ground's geoms (a terrain may have several): what the contact sensors count as touching."""
        self._module_of_body = self._module_bodies()
        self._root = int(self.model.joint("root").bodyid[0])  # the body with the free joint (mjcf chose it)
        self.modules: dict[int, Module] = {}
        """Every module by ID, Python or C: driven through the one interface (asm_module.module)."""
        self._nodes: list[Node] = []
        self._push: tuple[float, np.ndarray] | None = None
        self.peak_torque = 0.0
        self.peak_load = 0.0
        """The largest |torque| / stall torque of its module's servo since the last measurement began."""
        self._stall = np.array([t.stall_torque for t in gait.robot.every_module()])
        self.fell_seen = False
        """The robot has fallen (see ``fell``) at some instant since the last measurement began."""
        self.energy = 0.0
        """Joint work since the last measurement began, J (see Metrics.energy)."""
        self.turned = 0.0
        """Heading turned since the last measurement began, degrees (see Metrics.turned)."""
        ends = ("b0", f"b{gait.robot.modules}") if gait.robot.shape == "chain" else ()
        self._ends = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name) for name in ends]
        """A chain's first and last bodies: its heading is the line between them."""
        self._started = False
        on_sim_bus = (bus_options or {}).get("interface") == "asm_sim"
        # the channel the modules' buses open (SimBus's own default when none is given)
        self._sim_channel = str((bus_options or {}).get("channel") or "asm_sim") if on_sim_bus else None
        self._burst: Callable[[], AbstractContextManager[None]] = (
            partial(SimBus.holding, self._sim_channel) if self._sim_channel is not None else nullcontext
        )
        hub = LocalNeighbours() if node_of is None else None  # without a bus, neighbours are heard in-process
        self._states = {a.id: 0 for a in gait.modules}
        """Each module's automaton state as it announced it on the in-process hub (Python and C alike)."""
        for assignment in gait.modules:
            if hub is not None:
                hub.watch(assignment.id, lambda state, i=assignment.id: self._states.__setitem__(i, state))
        for assignment in gait.modules:
            driver = MujocoJoint(self, assignment.id)
            span = gait.robot.module_type(assignment.id).range
            hardware = (-span, span)  # its type's hinge, as the MJCF's joint: the loader keeps [limits] within it
            if assignment.id in emulated_modules:
                from asm_module.emulated import EmulatedModule  # Unicorn is loaded only when a board is emulated

                serial, flash = board_flash.board(assignment.id) if board_flash is not None else (None, None)
                # boards flashed for this run only: each its own serial too (all zeros, two boards answered the
                # commissioning scan as one, and an ID given to that serial went to both)
                serial = serial if serial is not None else EMULATED_SERIAL + assignment.id.to_bytes(4, "big")
                self.modules[assignment.id] = EmulatedModule(module_name(assignment.id), 0 if flash else assignment.id,
                    driver=driver, clock=self.clock, tick=self.tick, hardware_range=hardware, serial=serial,
                    settings=flash, **dict(bus_options or {}))  # fmt: skip
                continue
            kind = gait.robot.type_name(assignment.id)  # what the module reports as its module.type
            if assignment.id in c_modules:
                self.modules[assignment.id] = CModule(module_name(assignment.id), assignment.id, driver=driver,
                                                      clock=self.clock, tick=self.tick, hardware_range=hardware,
                                                      hub=hub if bus_options is None else None, module_type=kind,
                                                      **dict(bus_options or {}))  # fmt: skip
                continue
            node = node_of(assignment.id) if node_of is not None else None
            if node is not None:
                self._nodes.append(node)
            self.modules[assignment.id] = ModuleRuntime(driver, node=node, clock=self.clock, tick=self.tick,
                                                        limits=gait.limits, hardware_range=hardware, ramp=ramp,
                                                        inline=True,
                                                        module_id=assignment.id, neighbours=hub,
                                                        module_type=kind)  # fmt: skip
        mujoco.mj_forward(self.model, self.data)
        self._yaw = self.yaw()

    def _module_bodies(self) -> np.ndarray:
        """Body id → the module it belongs to (0: none), for the contact sensors."""
        owner = np.zeros(self.model.nbody, dtype=np.int32)
        shape = self.gait.robot.shape
        for i in range(1, self.gait.robot.modules + 1):
            owner[self.model.body(f"b{i}").id] = i  # the distal half of module i (and the proximal of i + 1)
        if shape != "legged":
            owner[self.model.body("b0").id] = 1
        return owner

    # -- running ------------------------------------------------------------------------------------------------

    def start(self) -> None:
        """Load every module's table, phase and direction as a deployment would, then start all gaits at t."""
        tables = module_tables(self.gait)
        for assignment in self.gait.modules:
            self.modules[assignment.id].load_gait(tables[assignment.id], assignment.phase,
                                                  assignment.direction * self.direction)  # fmt: skip
        for module in self.modules.values():
            module.start_gait()
        self.clock.settle()
        self._started = True

    def settle(self) -> None:
        """Wait until nothing the modules sent is in flight (every frame on an ``asm_sim`` bus handed on, every
        service thread back at its wait, and what those sent in turn): ticks stepped so make a deployment command
        what the preview does whatever the load (tests/gaits/test_program_sim.py), where pacing them on the wall
        clock hoped the frames had arrived. Frames read by threads of their own (``virtual``, an emulated board) are
        not waited for. ``SimulationStalled`` when still busy after the clock's ``settle_timeout`` (modules answering
        each other for ever); ``TimeoutError`` when a frame's handler blocks."""
        handed, deadline = -1, time.monotonic() + self.clock.settle_timeout
        while True:
            now = SimBus.flush(self._sim_channel) if self._sim_channel is not None else 0
            self.clock.settle()
            if now == handed:
                return
            if time.monotonic() > deadline:
                raise SimulationStalled(f"the bus of the simulation at t={self.clock.now()} was not quiet after "
                                        f"{self.clock.settle_timeout}s of real time ({now} frames handed)")  # fmt: skip
            handed = now

    def drive(self, gait: str, direction: int = 1) -> None:
        """Switch every module to program gait ``gait`` (``direction`` -1: backwards) at the next cycle boundary,
        as a deployed robot's Drive does (one ``gait.switch`` per module, the same on each)."""
        mode, after = mode_index(self.gait, gait), self.clock.now()
        for module in self.modules.values():  # driving a stopped robot starts it (in its first gait) first
            module.start_gait()
        for module in self.modules.values():
            module.switch_mode(mode, direction, after)

    def signal(self, number: int) -> None:
        """Broadcast signal ``number`` to every module, as a tool's group SET of ``gait.signal`` does on a bus."""
        for module in self.modules.values():
            module.hear_signal(number)

    def running(self) -> int:
        """How many modules' gaits run now (none, once a one-shot program has ended on every module)."""
        return sum(1 for module in self.modules.values() if module.gait_running())

    def states(self) -> tuple[int, ...]:
        """Each module's automaton state now (0-based, as ``gait.state``), -1 where its gait does not run: what the
        preview's states-over-time view draws. Heard on the in-process hub: all 0 for modules on a bus."""
        return tuple(self._states[i] if m.gait_running() else -1 for i, m in self.modules.items())

    def stop_gaits(self) -> None:
        """Stop every module's gait: the joints hold their last goals (the Drive panel's stop)."""
        for module in self.modules.values():
            module.stop_gait()

    def push(self, force: tuple[float, float, float], seconds: float) -> None:
        """Apply ``force`` (N, world frame) at the root body's centre of mass for ``seconds`` from now."""
        self._push = (self.data.time + seconds, np.asarray(force, dtype=float))
        self.data.xfrc_applied[self._root, :3] = self._push[1]

    @property
    def pushing(self) -> bool:
        """A push (``push``) is being applied."""
        return self._push is not None

    def skip_periods(self, periods: int, *, tick: bool = False) -> None:
        """Let ``periods`` control periods pass with the physics standing still (a robot at rest: server.rest):
        time (the modules' clock too) moves on along the tick grid; with ``tick`` the modules tick once, at the
        first period's start (they read the joints as they stand). Only at a period's start."""
        if self._into_tick != 0:
            raise RuntimeError("periods are skipped only at a period's start")
        if periods > 0:
            if tick:
                self._control_tick()
            self.data.time += periods * self.steps_per_tick * self.model.opt.timestep
            self.clock.advance_to(self.data.time)  # what modules read as now (a tick would have said so)

    def steps_to_tick(self) -> int:
        """Physics steps from now to the next control tick (a whole period when at a period's start)."""
        return self.steps_per_tick - self._into_tick

    def step_tick(self) -> None:
        """The rest of the current control period (a whole one when at a period's start)."""
        self.step_physics(self.steps_to_tick())

    def step_physics(self, steps: int) -> None:
        """``steps`` physics steps; each control period begins with the tick (every module reacts).

        Stepping by fewer steps than a period is what lets the preview record frames at 60 Hz while the modules
        keep their own 50 Hz tick: the modules see exactly the same ticks either way."""
        while steps > 0:
            if self._into_tick == 0:
                self._control_tick()
            n = min(steps, self.steps_per_tick - self._into_tick)
            with self.lock:
                if self._servo is None:
                    mujoco.mj_step(self.model, self.data, n)
                else:
                    self._servo.step(self.model, self.data, n)
            self._into_tick = (self._into_tick + n) % self.steps_per_tick
            steps -= n
            force = self.data.actuator_force
            self.peak_torque = max(self.peak_torque, float(np.abs(force).max(initial=0.0)))
            self.peak_load = max(self.peak_load, float((np.abs(force) / self._stall).max(initial=0.0)))
            self.fell_seen = self.fell_seen or self.fell()
            dt = n * self.model.opt.timestep
            self.energy += float(np.abs(force * self.data.actuator_velocity).sum()) * dt
            yaw = self.yaw()
            self.turned += math.degrees(math.remainder(yaw - self._yaw, 2 * math.pi))
            self._yaw = yaw
            if self._push is not None and self.data.time >= self._push[0]:
                self.data.xfrc_applied[self._root, :3] = 0.0
                self._push = None
            if not np.isfinite(self.data.qpos).all():
                raise FloatingPointError(f"the simulation diverged at t = {self.data.time:.3f} s")
            if self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
                # MuJoCo resets an unstable state to the start and goes on: time went back and a run never ended
                raise FloatingPointError("the simulation diverged (MuJoCo reset an unstable state: a servo too "
                                         "stiff or too strong for the timestep?)")  # fmt: skip

    def _control_tick(self) -> None:
        self._sense_contacts()
        self.clock.advance_to(self.data.time)
        with self._burst():  # what the modules send in one tick goes on the bus in one hand-off (asm_py.canbus.simbus)
            self.tick.set(self.data.time)
        if self.trace is not None:
            self.trace.times.append(self.data.time)
            self.trace.goals.append([self.goal(a.id) for a in self.gait.modules])

    def goal(self, module_id: int) -> float:
        """What module ``module_id`` commands its joint to now."""
        return self.modules[module_id].goal_now()

    def angle(self, module_id: int) -> float:
        """Module ``module_id``'s joint.angle, as the module last read it."""
        return self.modules[module_id].angle_now()

    def advance(self, seconds: float) -> None:
        end = self.data.time + seconds - 1e-9
        while self.data.time < end:
            self.step_tick()

    def _sense_contacts(self) -> None:
        ncon = self.data.ncon
        if ncon == 0:
            self.touching = set()
            return
        geoms = self.data.contact.geom[:ncon]
        on_floor = np.isin(geoms, self._floor)
        floor = on_floor.any(axis=1)
        other = np.where(on_floor[:, 0], geoms[:, 1], geoms[:, 0])[floor]
        self.touching = set(self._module_of_body[self.model.geom_bodyid[other]].tolist()) - {0}

    def yaw(self) -> float:
        """The robot's heading, radians: a chain's tail-to-head line, a loop's rolling direction (across its
        hinges), a legged body's front, projected on the ground."""
        robot, data = self.gait.robot, self.data
        if robot.shape == "chain":
            tail, head = data.xpos[self._ends[0]], data.xpos[self._ends[1]]
            return math.atan2(head[1] - tail[1], head[0] - tail[0])
        xmat = data.xmat[self._root].reshape(3, 3)
        if robot.shape == "loop":
            return math.atan2(xmat[1, 1], xmat[0, 1]) - math.pi / 2  # the hinge axis (body y), turned back 90°
        return math.atan2(xmat[1, 0], xmat[0, 0])

    def center_of_mass(self) -> np.ndarray:
        return self.data.subtree_com[0].copy()

    def measure(self, start: np.ndarray, seconds: float, real_time_factor: float = 0.0) -> Metrics:
        """Metrics of the ``seconds`` since the centre of mass was at ``start``."""
        end = self.center_of_mass()
        robot = self.gait.robot
        return Metrics(seconds, (float(end[0] - start[0]), float(end[1] - start[1])),
                       robot.length, self.peak_torque, self.fell_seen or self.fell(),
                       real_time_factor,
                       self.energy, float(self.model.body_mass.sum()), self.turned, self.peak_load)  # fmt: skip

    def fell(self) -> bool:
        xmat = self.data.xmat[self._root].reshape(3, 3)
        if self.gait.robot.shape == "legged":
            return bool(xmat[2, 2] < 0.5)  # the body's up axis no longer points up
        return bool(abs(xmat[2, 1]) > 0.7)  # the pitch axis (body y) stands up: lying on its side

    def run(self, seconds: float, *, warmup: float = 2.0, push_at: float | None = None,
            push: tuple[float, float, float] = (0.0, 1.0, 0.0), push_seconds: float = 0.1) -> Metrics:  # fmt: skip
        """Start (if needed), run ``warmup`` + ``seconds``, and measure the last ``seconds`` — as simulated: the
        physics runs whole control ticks, so a time off the tick grid is measured over the ticks it took (0.001 s
        asked ran one 0.02 s tick, and dividing its distance by 0.001 s said 4 m/s: a user review); at least one
        tick is measured."""
        wall = time.perf_counter()
        if not self._started:
            self.start()
        self.advance(warmup)
        began = self.data.time
        start = self.center_of_mass()
        self.peak_torque = self.peak_load = self.energy = self.turned = 0.0
        self.fell_seen = False
        if push_at is not None and push_at > warmup:
            self.advance(push_at - warmup)
            self.push(push, push_seconds)
            self.advance(seconds - (push_at - warmup))
        else:
            self.advance(seconds)
        if self.data.time <= began:  # a time under a tick's (1e-9 s): one tick is measured, never zero seconds
            self.step_tick()
        wall = time.perf_counter() - wall
        simulated = round(self.data.time - began, 9)  # the tick grid's time, without the sum's rounding dust
        return self.measure(start, simulated, (warmup + seconds) / wall if wall > 0 else 0.0)

    def latched(self) -> list[int]:
        """The modules whose e-stop is latched."""
        return sorted(i for i, module in self.modules.items() if module.latched)

    def close(self) -> None:
        for module in self.modules.values():
            module.close()
        for node in self._nodes:
            node.close()

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
