"""The module runtime: the ASM node a PolyBot-like module runs, whether its joint is simulated or real.

What a module has is what it exposes (well-known classes, so groups and tools address them on every module):

    joint.goal      float32  the commanded angle, degrees — clamped to joint.limits whatever is sent
    joint.angle     float32  the measured angle, published
    joint.torque    float32  the measured torque, N·m, published
    joint.limits    float32[2]  (min, max) degrees; settable only within the calibration's soft limits
    joint.calibration  zero, direction, soft limits (asm_module/calibration.py): applied to every command and
                    reading, kept by ``calibration_store`` (a file) when given
    module.info     version, build, limits (read-only)
    module.type     str      the name of the module's type (read-only; "": not said)
    servo.service   the servo loop: running = joint powered and following joint.goal; stopped = limp
    gait.table      bytes    this module's automaton (asm_module.wire); settable only while the gait is stopped
    gait.checksum   uint32   CRC-32 of gait.table, for a deploying tool to verify the transfer
    gait.phase      float32  the initial phase delay φ ∈ [0, 1) used when the gait starts without one
    gait.direction  int8     +1 forward, -1 backward (the automaton's direction)
    gait.state      uint16   the automaton's current state
    gait.service    the PeriodicAutomaton running the table on gait.tick; its output drives joint.goal
    gait.tick       float64  the control tick event (a timer on a real module; the simulator's steps in preview)
    sensor.contact  bool     the module touches the ground, published
    estop           bool     latched emergency stop: the gait stops, the joint holds where it is, and every
                             remote request that would move it (goal, limits, tables, staging, activation, gait and
                             servo starts and stops) is refused with status ESTOP until estop is set back to false
    gait.staged, gait.staged_checksum, gait.activate, gait.lease
                             a deployment as a transaction (asm_module/staging.py)

Measurements and what only the module computes (joint.angle, joint.torque, sensor.contact, gait.checksum,
gait.staged_checksum, gait.state, gait.tick) are read-only from outside: a remote set is answered READ_ONLY.

The same class drives a simulated joint (a MuJoCo actuator, gaits.sim) or a real one behind :class:`JointDriver`;
:class:`FakeDriver` is a servo model for tests and for running without hardware.

When the gait starts, the goal ramps from where it was to the automaton's reference over ``ramp`` seconds: a jump to
full amplitude can throw a long chain about (SIMULATION.md). The ramp is part of the module, so a preview shows it.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from typing import Any, Literal

from asm_py.attribute import Attribute, CheckedAttribute
from asm_py.automaton import PhaseState
from asm_py.clock import WALL_CLOCK, Clock
from asm_py.codec import BOOL, BYTES, FLOAT32, FLOAT64, UINT32, float_array
from asm_py.codec_parse import parse_codec
from asm_py.eds import EventDrivenService
from asm_py.errors import EstopLatched
from asm_py.event import Event, TimerTrigger
from asm_py.node import Node
from asm_py.protocol import WRITES, Method

from ._profile import PROFILE
from .calibration import (
    CalibratedJoint,
    Calibration,
    CalibrationFile,
    check_calibration,
    check_module_type,
    python_info,
)
from .drivers import JointDriver
from .gait_service import ModuleGait
from .neighbours import BusNeighbours, LocalNeighbours, Neighbours
from .program import Program, program_of
from .staging import Staging
from .wire import checksum, decode_program, encode_table

log = logging.getLogger("asm_module.runtime")
HOLD = [PhaseState(0.0, 1.0, "step")]
"""The table of a module that has not been given a gait: hold 0°."""


class _Servo(EventDrivenService):
    """servo.service: on every control tick, read the joint into joint.angle/torque and sensor.contact."""

    def __init__(self, runtime: ModuleRuntime, tick: Event, *, inline: bool) -> None:
        super().__init__("servo.service", tick, inline=inline, clock=runtime.clock)
        self._runtime = runtime

    def handle(self, value: Any) -> None:
        self._runtime.sense()

    def start(self, *params: Any, wait: bool = True) -> None:
        if params:  # a module's services start without parameters, on every module (the C runtime's too)
            raise ValueError(f"servo.service starts without parameters, not {list(params)!r}"[:200])
        super().start(wait=wait)

    def on_start(self, *params: Any) -> None:
        self._runtime.joint.command(self._runtime.goal.peek())

    def on_stop(self) -> None:
        self._runtime.joint.relax()


class _Estop(CheckedAttribute):
    """``estop``: a set's latch or release and the value it stores, as one (emergency_stop stores its value under
    the same lock): a release storing false after an e-stop re-latched left the module latched with estop false."""

    __slots__ = ("setting",)

    def __init__(self, *args: Any, **options: Any) -> None:
        super().__init__(*args, **options)
        self.setting = threading.RLock()

    def set(self, value: Any, timeout: float | None = None, *, wait: bool = True) -> None:
        with self.setting:
            super().set(value, timeout, wait=wait)


class ModuleRuntime:
    """One module's objects and behaviour; see the module docstring. ``close`` stops everything it started."""

    def __init__(
        self,
        driver: JointDriver,
        *,
        node: Node | None = None,
        clock: Clock | None = None,
        limits: tuple[float, float] = (-90.0, 90.0),
        hardware_range: tuple[float, float] = (-90.0, 90.0),
        tick: Event | None = None,
        control_rate: float = 50.0,
        ramp: float = 1.0,
        inline: bool = False,
        refresh_rate: float = 2.0,
        publish_limit: float = 25.0,
        module_id: int = 1,
        neighbours: Neighbours | None = None,
        calibration_store: CalibrationFile | None = None,
        module_type: str = "",
    ) -> None:
        self.driver = driver
        """The joint's raw driver (the runtime drives it through :attr:`joint`, the calibration applied)."""
        self.hardware_range = hardware_range
        self._store = calibration_store
        stored = calibration_store.load(hardware_range) if calibration_store is not None else None
        initial = stored or Calibration(0.0, 1, *hardware_range)
        self.joint = CalibratedJoint(driver, initial)
        if stored is not None:  # the stored soft limits bound the limits given (a deploy's narrower ones stay)
            limits = (max(limits[0], stored.min), min(limits[1], stored.max))
            if not limits[0] < limits[1]:
                limits = (stored.min, stored.max)
        self.module_id = module_id
        """This module's ID (its CAN node ID): neighbour events name modules relative to it."""
        self.node = node
        self.clock = clock or (node.clock if node is not None else WALL_CLOCK)
        self.ramp = ramp
        self.latched = False
        """The e-stop is latched (set first: a racing tick's goal is never commanded after it)."""
        self.latches = 0
        """Latches begun, ever: a start reads it before it looks at ``latched``, and again once started
        (:meth:`unlatched_since`), so an e-stop and its release both landing in between are seen."""
        self._latching = 0  # latches begun and not ended: two e-stops on two threads may latch at once
        self._counting = threading.Lock()  # the counts' own, for nanoseconds: nothing a gait or a service holds
        self.gait_since = 0  # ``latches`` as the running gait's start read it: _follow, GaitService._starting
        self._held_at: float | None = None
        """The angle the e-stop holds (joint.goal reads it from the next tick on)."""
        self.calibration = CheckedAttribute("joint.calibration", initial.as_record(),
                                            codec=parse_codec(PROFILE["joint.calibration"].codec),
                                            check=self._calibrate, reset=self._uncalibrate,
                                            clock=self.clock)  # fmt: skip
        self._recalibrating = False
        self.info = Attribute("module.info", python_info(), codec=parse_codec(PROFILE["module.info"].codec),
                              clock=self.clock)  # fmt: skip
        self.module_type = Attribute("module.type", check_module_type(module_type),
                              codec=parse_codec(PROFILE["module.type"].codec), clock=self.clock)  # fmt: skip
        """What the module is, as a robot description names its type (the command line's, or the simulated robot's
        description): gaits/compatible.py compares it with the gait's."""
        self.limits = CheckedAttribute("joint.limits", self._check_limits(limits), codec=float_array(2),
                                       check=self._check_limits, reset=self._soft_limits,
                                       clock=self.clock)  # fmt: skip
        self.goal = CheckedAttribute("joint.goal", 0.0, codec=FLOAT32, check=self._clamp_goal, reset=self._reset_goal,
                                     clock=self.clock)  # fmt: skip
        self.angle = Attribute("joint.angle", 0.0, codec=FLOAT32, clock=self.clock)
        self.torque = Attribute("joint.torque", 0.0, codec=FLOAT32, clock=self.clock)
        self.contact = Attribute("sensor.contact", False, codec=BOOL, clock=self.clock)
        self.estop = _Estop("estop", False, codec=BOOL, check=self._check_estop, reset=self._refuse_reset,
                            clock=self.clock)  # fmt: skip
        self.phase = CheckedAttribute("gait.phase", 0.0, codec=FLOAT32, check=self._check_phase, clock=self.clock)
        self._own_timer: TimerTrigger | None = None
        if tick is None:
            tick = Event("gait.tick", codec=FLOAT64, clock=self.clock)
            self._own_timer = TimerTrigger(1.0 / control_rate, name="tick.timer", clock=self.clock)
            tick.add_trigger(self._own_timer)
        self.tick = tick
        self.gait = ModuleGait(self, tick, program_of(HOLD), inline=inline)
        if neighbours is None and node is not None:
            neighbours = BusNeighbours(node)
        self.neighbours = neighbours
        self._watching: list[Callable[[], None]] = []
        table = encode_table(HOLD)
        self.table = CheckedAttribute("gait.table", table, codec=BYTES, check=self._load_table, clock=self.clock)
        self.checksum = Attribute("gait.checksum", checksum(table), codec=UINT32, clock=self.clock)
        self.staging = Staging(self)
        self.servo = _Servo(self, tick, inline=inline)
        self._ramp_from = 0.0
        self._ramp_start = 0.0
        self._unlisten = [self.gait.reference_out.on_change(self._follow), self.limits.on_change(self._reclamp),
                          self.goal.on_change(self._command)]  # fmt: skip
        if isinstance(neighbours, LocalNeighbours):
            self._unlisten.append(self.gait.state.on_change(lambda state: neighbours.announce(module_id, state)))
            self._unlisten.append(neighbours.listen(self.gait.signal.set))
        if node is not None:
            self._register(node, refresh_rate, publish_limit)
        self.servo.start()
        if self._own_timer is not None:
            self._own_timer.start()

    # -- wiring -------------------------------------------------------------------------------------------------

    def _register(self, node: Node, refresh_rate: float, publish_limit: float) -> None:
        if self.tick.publish_policy is None:  # unless the tick's owner chose otherwise (before it is registered)
            # the tick fires 50 times a second; published at each firing (an event's default) it would take two
            # frames per firing per module, ~40 % of a 1 Mbit/s bus for 32 modules: once a second shows it ticks
            self.tick.publish(rate=1.0)
        staging = self.staging
        starts = (Method.START, Method.RESUME)
        gait = self.gait
        moving = {self.goal: WRITES, self.limits: WRITES, self.calibration: WRITES, self.servo: WRITES,
                  self.table: WRITES, gait: starts, staging.staged: WRITES, staging.activate: WRITES,
                  gait.switch: WRITES}  # fmt: skip

        def register(*objects: Any) -> None:
            for obj in objects:
                refused = moving.get(obj)
                node.register(obj, read_only=obj in self._read_only(),
                              guard=None if refused is None else self._refuse_in_estop(obj.name, refused))  # fmt: skip

        register(self.goal, self.angle, self.torque, self.limits, self.servo, self.table, self.checksum, self.phase,
                 self.gait, self.tick, self.contact, self.estop, staging.staged, staging.staged_checksum,
                 staging.activate, staging.lease)  # fmt: skip
        node.register(self.gait.direction, name="gait.direction")
        node.register(self.gait.state, name="gait.state", read_only=True)
        register(gait.switch, gait.cycle, gait.mode, gait.done, gait.signal)  # after version 1's objects: IDs stay
        register(self.info, self.calibration)  # and after those: the C runtime registers them in this order too
        register(self.module_type)  # and after those (module.type came later still)
        # changes beyond the deadband, at most ``publish_limit`` a second (a moving joint changes at every control
        # tick: 32 modules at 50 Hz would be 1 600 frames a second), and a refresh ``refresh_rate`` times a second
        # when nothing moves: a resting robot keeps the bus quiet
        self.angle.publish(rate=refresh_rate, deadband=0.1, limit=publish_limit)
        self.torque.publish(rate=refresh_rate / 2, deadband=0.05, limit=publish_limit / 2)
        self.contact.publish()
        self.gait.state.publish(deadband=0)  # every change: neighbours wait on it
        self.gait.mode.publish(deadband=0)
        self._unlisten.append(node.on_estop(lambda source, reason: self.emergency_stop(reason)))

    def _read_only(self) -> tuple[Attribute, ...]:
        gait = self.gait
        return (self.info, self.module_type, self.angle, self.torque, self.contact, self.checksum,
                self.staging.staged_checksum, self.tick, gait.cycle, gait.mode, gait.done)  # fmt: skip

    def _refuse_in_estop(self, name: str, methods: frozenset[int] | tuple[int, ...]) -> Callable[[int], None]:
        def guard(method: int) -> None:
            if method in methods and self.latched:
                raise EstopLatched(f"{name}: the module's emergency stop is latched (set estop to false to release)")

        return guard

    # -- behaviour ----------------------------------------------------------------------------------------------

    def _check_limits(self, value: Any) -> tuple[float, float]:
        lo, hi = (float(v) for v in value)
        soft = self.joint.calibration
        if not (soft.min <= lo < hi <= soft.max):
            raise ValueError(f"joint limits must satisfy {soft.min} <= min < max <= {soft.max} (the calibration's "
                             f"soft limits), not ({lo}, {hi})")  # fmt: skip
        return (lo, hi)

    def _soft_limits(self) -> tuple[float, float]:
        """A RESET of joint.limits: the calibration's soft limits (the C runtime's too), the goal re-clamped."""
        soft = self.joint.calibration
        self.goal.set(min(max(float(self.goal.peek()), soft.min), soft.max))
        return (soft.min, soft.max)

    def _calibrate(self, value: Any) -> dict[str, Any]:
        """joint.calibration set (or reset: none): checked, stored before it is taken (a value is answered OK only
        once it would survive a restart), applied. The joint stays where it is commanded: the goal becomes the same
        raw angle in the new calibration, clamped to its limits as a narrower joint.limits would clamp it."""
        calibration = check_calibration(value, self.hardware_range)
        if self._store is not None:
            self._store.save(calibration)
        raw = self.joint.calibration.raw(float(self.goal.peek()))
        self.joint.calibrate(calibration)
        self._recalibrating = True  # the old goal is not re-clamped and commanded in the new calibration
        try:
            self.limits.set((calibration.min, calibration.max))  # checked against the new soft limits
        finally:
            self._recalibrating = False
        self.goal.set(calibration.angle(raw))  # clamped, and commanded
        return calibration.as_record()

    def _uncalibrate(self) -> dict[str, Any]:
        """A RESET: no calibration (zero 0, direction +1, the hardware's range), stored as such."""
        return self._calibrate(Calibration(0.0, 1, *self.hardware_range))

    def _clamp_goal(self, value: float) -> float:
        if not math.isfinite(value):
            raise ValueError(f"joint.goal must be a finite number of degrees, not {value}")
        lo, hi = self.limits.peek()
        return min(max(value, lo), hi)

    def _reset_goal(self) -> float:
        goal = self._clamp_goal(0.0)
        self._command(goal)  # a reset of the goal commands it, as a set does
        return goal

    @staticmethod
    def _refuse_reset() -> bool:
        raise ValueError("estop is released by a SET to false, module by module: a RESET does not release it")

    def _check_phase(self, value: float) -> float:
        if not 0.0 <= value < 1.0:
            raise ValueError(f"gait.phase must be in [0, 1), not {value}")
        return value

    def _check_estop(self, value: bool) -> bool:
        if value:
            self._latch()
        else:
            self._unlatch()
        return value

    def check_table(self, data: bytes) -> Program:
        """The program in table ``data`` if this module can run it; ValueError saying why not."""
        program = decode_program(data)
        lo, hi = self.limits.peek()
        outside = [t for t in program.targets() if not lo <= t <= hi]
        if outside:
            raise ValueError(f"gait table angles {outside[:4]} lie outside the joint limits ({lo}, {hi})")
        missing = [k for k in program.neighbours() if not 1 <= self.module_id + k <= 254]
        if missing:
            raise ValueError(f"module {self.module_id} has no neighbour {missing[0]:+d} IDs away (IDs are 1..254)")
        return program

    def _load_table(self, data: bytes) -> bytes:
        program = self.check_table(data)
        if (program.neighbours() or program.emits()) and self.neighbours is None:
            raise ValueError("this module has no bus to its neighbours: it cannot run neighbour events or signals")
        self.gait.load(program)  # ServiceError while the gait runs: a table never changes mid-cycle
        self._watch(program)
        self.checksum.set(checksum(data))
        Attribute.set(self.staging.activate, 0)  # the gait is no longer a deployment's (the base set: no activation)
        return data

    def emit_signal(self, signal: int) -> None:
        """Broadcast ``signal`` to every module (a state that emits it was entered); this module hears it too."""
        if isinstance(self.neighbours, LocalNeighbours):
            self.neighbours.broadcast(signal)  # every module of the hub, this one included
            return
        self.gait.signal.set(signal)  # a group message does not come back to its sender
        if self.neighbours is not None:
            try:
                self.neighbours.broadcast(signal)
            except Exception:  # a tick must go on whatever the bus does: the signal is lost, as a frame can be
                log.exception("module %d could not broadcast signal %d", self.module_id, signal)

    def _watch(self, program: Program) -> None:
        for remove in self._watching:
            remove()
        self._watching = []
        if self.neighbours is None:
            return
        for offset in sorted(program.neighbours()):

            def heard(state: int, offset: int = offset) -> None:
                self.gait.neighbour_state(offset, state)

            self._watching.append(self.neighbours.watch(self.module_id + offset, heard))

    def unlatched_since(self, since: int) -> bool:
        """No e-stop latched, or latching, since ``latches`` read ``since`` (read it before looking at ``latched``)."""
        return not self.latched and self._latching == 0 and self.latches == since

    def switch_gait(self, table: bytes, phase: float, direction: int, *, since: int | None = None) -> None:
        """Stop the gait, make ``table``/``phase``/``direction`` the module's gait and start it (an activation),
        unless an e-stop latched since ``latches`` read ``since`` (now, if not given): see ``latches``."""
        since = self.latches if since is None else since
        if not self.unlatched_since(since):
            raise EstopLatched("the module's emergency stop is latched")
        self.check_table(table)
        self.gait.stop(timeout=1.0)
        self.table.set(table)
        self.phase.set(phase)
        self.gait.direction.set(direction)
        self.gait.start(since=since)

    def _follow(self, reference: float) -> None:
        """The automaton's reference becomes the goal, ramped in from the goal held when the gait started."""
        if not self.unlatched_since(self.gait_since):
            return  # a tick that raced the e-stop, or a gait whose start one raced: the hold wins
        s = 1.0 if self.ramp <= 0 else min(1.0, (self.clock.now() - self._ramp_start) / self.ramp)
        self.goal.set(self._ramp_from + s * (reference - self._ramp_from))

    def _reclamp(self, limits: Any) -> None:
        if self._recalibrating:
            return
        self.goal.set(self.goal.peek())

    def _command(self, goal: float) -> None:
        if self.servo.running and not self.latched:
            self.joint.command(goal)

    def sense(self) -> None:
        held = self._held_at
        if self.latched and held is not None and self.goal.peek() != held:  # the e-stop's goal, set by the tick
            self.goal.set(held)
        reading = self.joint.read()
        self.angle.set(reading.angle)
        self.torque.set(reading.torque)
        if reading.contact != self.contact.peek():
            self.contact.set(reading.contact)

    def _begin_ramp(self) -> None:
        self._ramp_from = float(self.goal.peek())
        self._ramp_start = self.clock.now()

    def _latch(self) -> None:
        """The e-stop's own path, run on the thread the stop arrived on (a bus's receive thread): flags and the
        driver's hold, nothing a gait, a service or a simulation step can hold — a gait however busy cannot delay
        it. The gait service is asked to stop (its thread ends by itself, no tick handles anything meanwhile), and
        joint.goal reads the held angle (a tick that raced the latch and wrote its own goal is corrected by the
        next tick)."""
        with self._counting:
            self.latches += 1
            self._latching += 1
        self.latched = True
        try:
            if self.servo.running:
                self._held_at = self.joint.hold()
        finally:  # a hold that failed still stops the gait and drops the staged one (and leaves starts possible)
            try:
                self.gait.request_stop()
                self.staging.discard()  # no deployment begun before the stop may start after it
                if self._held_at is not None:
                    self.goal.set(self._held_at)  # the goal's own lock, for microseconds: commands nothing latched
            finally:
                with self._counting:
                    self._latching -= 1

    def _unlatch(self) -> None:
        """Released: commands reach the joint again, which stays where it holds until a new goal or gait."""
        if self.latched:
            self.latched = False
            held, self._held_at = self._held_at, None
            self.joint.release()
            if held is not None:
                self.goal.set(held)

    def emergency_stop(self, reason: str = "") -> None:
        """Stop the gait and hold the joint where it is; latched until ``estop`` is set to false (see _latch)."""
        self._latch()  # at once: nothing a set of estop holds
        with self.estop.setting:  # then the value, with no release between it and the latch it says
            Attribute.set(self.estop, True)  # the value only: _latch has done what a set would
            if not self.latched:  # a release came between the two: the value says latched, so it is again
                self._latch()

    # -- the in-process interface every module has (asm_module.module.Module) -----------------------------------

    language: Literal["python", "c"] = "python"

    def load_gait(self, table: bytes, phase: float, direction: int) -> None:
        self.table.set(table)
        self.phase.set(phase)
        self.gait.direction.set(direction)

    def start_gait(self) -> None:
        if not self.gait.started:
            self.gait.start()

    def switch_mode(self, mode: int, direction: int, after: float) -> None:
        self.gait.switch.set({"mode": mode, "direction": direction, "after": after})

    def hear_signal(self, number: int) -> None:
        self.gait.signal.set(number)

    def stop_gait(self) -> None:
        self.gait.stop(timeout=5.0)

    def gait_running(self) -> bool:
        return self.gait.started

    def goal_now(self) -> float:
        return float(self.goal.peek())

    def angle_now(self) -> float:
        return float(self.angle.peek())

    def close(self) -> None:
        if self._own_timer is not None:
            self._own_timer.stop(timeout=5)
        self.gait.stop(timeout=5)
        self.servo.stop(timeout=5)
        for unlisten in (*self._unlisten, *self._watching):
            unlisten()
