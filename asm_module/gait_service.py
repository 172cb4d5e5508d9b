"""gait.service: the phase automaton a module runs its program with (the rules are in program.py).

A time-driven periodic mode is run exactly as :class:`~asm_py.automaton.PeriodicAutomaton` runs a table (phase
time τ = φ·T + d·t from an anchor, the reference from :func:`~asm_py.automaton.reference_at`), so a version-1 table
behaves as it always has. Any other mode is stepped state by state at each tick. Either way the output is the
reference the runtime turns into ``joint.goal``.
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from collections import Counter
from typing import TYPE_CHECKING, Any

from asm_py.attribute import Attribute, CheckedAttribute
from asm_py.automaton import PhaseAutomaton, reference_at, state_starts
from asm_py.codec import FLOAT32, FLOAT64, INT8, UINT8, UINT32, record
from asm_py.errors import EstopLatched, ServiceError
from asm_py.event import Event

from .program import SWITCH_BLEND, Mode, ModeState, Program

if TYPE_CHECKING:
    from .runtime import ModuleRuntime

SWITCH = record([("mode", UINT8), ("direction", INT8), ("after", FLOAT32)])
"""gait.switch: run program mode ``mode`` with direction ``direction`` (±1, times the mode's own) from the first
cycle boundary at or after ``after`` seconds of the module's clock."""
FINISHED, TIMED_OUT = 1, 2
"""gait.done values: the one-shot mode reached its last state's end; a state timed out with outcome ``stop``."""
_EPS = 1e-9


class ModuleGait(PhaseAutomaton):
    """gait.service; started without a phase, it starts at the module's gait.phase; refuses to start in e-stop."""

    def __init__(self, runtime: ModuleRuntime, tick: Event, program: Program, *, inline: bool) -> None:
        self._runtime = runtime
        clock = runtime.clock
        self.reference_out = Attribute("gait.reference", 0.0, codec=FLOAT64, clock=clock)
        super().__init__("gait.service", tick, program.modes[0].states, inline=inline, clock=clock)
        self.program = program
        self.switch = CheckedAttribute("gait.switch", {"mode": 0, "direction": 1, "after": 0.0}, codec=SWITCH,
                                       check=self._check_switch, reset=self._forget_switch, clock=clock)  # fmt: skip
        self.cycle = Attribute("gait.cycle", 0, codec=UINT32, clock=clock)
        self.mode = Attribute("gait.mode", 0, codec=UINT8, clock=clock)
        self.done = Event("gait.done", codec=UINT8, clock=clock)
        self.signal = CheckedAttribute("gait.signal", 0, codec=UINT8, check=self._heard_signal, clock=clock)
        """The last broadcast signal heard (a group SET from a module's emitting state, or from a tool)."""
        self._signals: dict[int, float] = {}  # signal → clock time it was last heard
        self.tau = 0.0
        self.ended: Counter[tuple[str, bool]] = Counter()
        """(event, timed out) → how many event-ended states ended so since the start: how a gait really ran."""
        self.switched_at: float | None = None
        """Clock time of the last switch (for measuring how together modules switch)."""
        self._neighbour_states: dict[int, tuple[int, float]] = {}  # relative ID → (state, clock time when heard)
        self._switch_request: tuple[int, int, float] | None = None
        self._lock = threading.Lock()
        self._since = threading.local()  # the latch count a start read, for its _starting (same thread)
        self._finished = False
        self._current = program.modes[program.first]
        self._index = 0
        self._blend = (0.0, 0.0)
        self._boundary = math.inf
        self._drive = 1
        self._sequence_at = 0
        self._cycles_left = 0
        self._base = (0.0, 1)
        self._paused_at = 0.0

    # -- loading and commands -----------------------------------------------------------------------------------

    def load(self, program: Program) -> None:
        """Replace the program; only while stopped, so a running gait never changes mid-cycle."""
        with self._mon:
            if self._started:
                raise ServiceError(f"{self.name!r} is started; stop it before loading new states")
            self.program = program
            self.states = program.modes[program.first].states

    def _check_switch(self, value: dict[str, Any]) -> dict[str, Any]:
        mode, direction, after = int(value["mode"]), int(value["direction"]), float(value["after"])
        if not 0 <= mode < len(self.program.modes):
            raise ValueError(f"this module's program has modes 0..{len(self.program.modes) - 1}, not {mode}")
        if direction not in (1, -1) or not math.isfinite(after):
            raise ValueError(f"a switch's direction is ±1 and its time finite, not {direction}, {after}")
        if self._runtime.latched:
            raise EstopLatched("the module's emergency stop is latched")
        with self._lock:
            self._switch_request = (mode, direction, after)
        return {"mode": mode, "direction": direction, "after": after}

    def _forget_switch(self) -> dict[str, Any]:
        """A RESET of gait.switch withdraws a switch not made yet (it schedules none)."""
        with self._lock:
            self._switch_request = None
        return {"mode": 0, "direction": 1, "after": 0.0}

    def _heard_signal(self, number: int) -> int:
        if not 1 <= int(number) <= 255:
            raise ValueError(f"a signal is numbered 1..255, not {number}")
        with self._lock:
            self._signals[int(number)] = self.clock.now()
        return int(number)

    def neighbour_state(self, offset: int, state: int) -> None:
        """A neighbour ``offset`` IDs away is now in ``state`` (from the bus, or a simulator's hub)."""
        with self._lock:
            self._neighbour_states[offset] = (state, self.clock.now())

    # -- starting -----------------------------------------------------------------------------------------------

    def start(self, *params: Any, wait: bool = True, since: int | None = None) -> None:  # pyright: ignore[reportIncompatibleMethodOverride]  # the module's START: no parameters, phase and direction are attributes
        """Start at the module's gait.phase and gait.direction. A START carries no parameters (docs/protocol.md
        §9): a phase and a direction are set first, each checked by its own attribute. Refused if an e-stop
        latched since the runtime's ``latches`` read ``since`` (now, if not given), looked at again once started:
        a latch during the start found nothing to stop."""
        if params:
            raise ValueError(f"gait.service starts without parameters (set gait.phase and gait.direction first), "
                             f"not {list(params)!r}"[:200])  # fmt: skip
        runtime = self._runtime
        since = runtime.latches if since is None else since
        if not runtime.unlatched_since(since):
            raise EstopLatched("the module is in emergency stop; set estop to false before starting the gait")
        if self.started and self.stop_requested:  # an e-stop's stop, its thread still ending: wait for it
            self._wait_stopped()
        self._since.value = since  # for _starting, in this thread: gait_since is the start's that goes ahead
        runtime._begin_ramp()
        super().start(float(runtime.phase.peek()))
        if not runtime.unlatched_since(since):
            self.request_stop()  # no tick runs it meanwhile; waited for briefly, so a start right after may start
            self._wait_stopped()
            raise EstopLatched("the module's emergency stop latched while the gait started")

    def _starting(self, phase: float = 0.0, direction: int | None = None) -> None:
        # after the already-started check: a start refused as started, or still waiting, never moves gait_since
        self._runtime.gait_since = self._since.value
        super()._starting(phase, direction)

    def _wait_stopped(self) -> None:
        """Up to 0.5 s of wall time, on any clock (the caller may be a bus's receive thread), for a stop asked."""
        ends = time.monotonic() + 0.5
        while self.started and time.monotonic() < ends:
            time.sleep(0.001)

    def initialize(self, phase: float) -> None:
        runtime = self._runtime
        if not runtime.unlatched_since(runtime.gait_since):  # latched since the start looked: no state, no signal
            raise EstopLatched("the module's emergency stop latched while the gait started")
        now = self.clock.now()
        self.ended = Counter()
        self._finished = False
        with self._lock:  # what neighbours said stays: they publish only when their state changes
            self._switch_request = None
        self.cycle.set(0)
        self._sequence_at = 0
        self._cycles_left = self.program.sequence[0][1] if self.program.sequence else 0
        self._drive = 1
        self._base = (phase, self.heading())
        self._enter_mode(self.program.first, now, phase, self.heading(), blend=False)
        self._output(now)

    def _enter_mode(self, index: int, at: float, phase: float, heading: int, *, blend: bool) -> None:
        old = float(self.reference_out.peek())
        mode: Mode = self.program.modes[index]
        self._current = mode
        self.states = mode.states
        self.mode.set(index)
        self.direction.set(heading)
        if mode.timed:
            self._phase_states = mode.phase_states()
            self._starts = state_starts(self._phase_states)
            self.period = math.fsum(s.duration for s in self._phase_states)
            self.tau = phase * self.period
            self._anchor = (self.tau, at, heading)
            self._last_tick = at
            self._boundary = at + self.period
            index_now = bisect.bisect_right(self._starts, self.tau) - 1
        else:
            index_now = min(int(phase * len(mode.states)), len(mode.states) - 1)
            self._boundary = math.inf
        self._enter_state(index_now, at)
        self._blend = (0.0, 0.0)
        if blend:
            self._blend = (old - self._reference(at), at)

    def _enter_state(self, index: int, at: float) -> None:
        self._index = index
        self._entered = at
        touching = bool(self._runtime.contact.peek())
        self._saw_free = not touching  # contact made / lost are edges within the state
        self._saw_touch = touching
        self.state.set(index)
        emit = self._current.states[index].emit
        if emit:
            self._runtime.emit_signal(emit)

    # -- each tick ----------------------------------------------------------------------------------------------

    def handle(self, value: Any) -> None:
        runtime = self._runtime
        if self._finished or not runtime.unlatched_since(runtime.gait_since):  # a tick racing an e-stop: nothing
            return
        now = self.clock.now()
        if self._current.timed:
            self._step_timed(now)
        else:
            self._step_states(now)
        if not self._finished:
            self._output(now)

    def _step_timed(self, now: float) -> None:
        while now >= self._boundary - _EPS and self._current.timed:
            quiet = self._quiet_boundaries(now)
            if quiet:  # boundaries that only count a cycle are crossed together: bounded work per tick, always
                self.cycle.set(int(self.cycle.peek()) + quiet)
                self._boundary += quiet * self.period
                if self._sequence_at + 1 < len(self.program.sequence):
                    self._cycles_left -= quiet
            boundary = self._boundary
            self._boundary = boundary + self.period
            if self._cross_boundary(boundary) and not self._current.timed:
                self._step_states(now)
                return
        tau0, t0, heading = self._anchor
        if self.heading() != heading:  # a direction set directly applies from the previous tick on
            tau0, t0, heading = self._anchor = (self.tau, self._last_tick, self.heading())
        self.tau = (tau0 + heading * (now - t0)) % self.period
        self._last_tick = now
        index = bisect.bisect_right(self._starts, self.tau) - 1
        if index != self._index:
            self._enter_state(index, now)

    def _quiet_boundaries(self, now: float) -> int:
        """How many of the cycle boundaries due by ``now``, before the last one, do nothing but count a cycle: none
        past a pending switch's time, none past the sequence's next step (as the C runtime does, firmware/src)."""
        crossed = int((now - self._boundary + _EPS) // self.period) + 1
        quiet = crossed - 1
        with self._lock:
            pending = self._switch_request
        if pending is not None:
            quiet = min(quiet, max(0, math.ceil((pending[2] - self._boundary) / self.period - _EPS)))
        if self._sequence_at + 1 < len(self.program.sequence):
            quiet = min(quiet, self._cycles_left - 1)
        return max(0, quiet)

    def _step_states(self, now: float) -> None:
        for _ in range(4 * len(self._current.states) + 1):  # several short states may end within one tick
            state: ModeState = self._current.states[self._index]
            contact = bool(self._runtime.contact.peek())
            self._saw_free |= not contact
            self._saw_touch |= contact
            elapsed = now - self._entered
            if state.until is not None and self._happened(state, contact):
                end = now
                self.ended[(state.until.event, False)] += 1
            elif state.duration is not None and elapsed >= state.duration - _EPS:
                if state.until is not None:
                    self.ended[(state.until.event, True)] += 1
                    if state.until.on_timeout == "stop":
                        self._end_run(TIMED_OUT)
                        return
                end = self._entered + state.duration
            else:
                return
            if not self._advance(end) or self._current.timed:
                return

    def _happened(self, state: ModeState, contact: bool) -> bool:
        until = state.until
        assert until is not None
        runtime = self._runtime
        if until.event == "contact":
            return contact and self._saw_free
        if until.event == "no_contact":
            return not contact and self._saw_touch
        if until.event == "at_goal":
            return abs(float(runtime.angle.peek()) - state.target) <= until.value
        if until.event == "torque":
            return abs(float(runtime.torque.peek())) >= until.value
        if until.event == "signal":  # heard since the state began, before this tick
            with self._lock:
                when = self._signals.get(until.state)
            return when is not None and self._entered - _EPS <= when < self.clock.now() - _EPS
        with self._lock:
            heard = self._neighbour_states.get(until.neighbour)
        return heard is not None and heard[0] == until.state and heard[1] < self.clock.now() - _EPS

    def _advance(self, at: float) -> bool:
        """Move to the next state in the current direction; False when the run ended or the mode changed."""
        count = len(self._current.states)
        index = self._index + self.heading()
        if not 0 <= index < count:
            if self._current.one_shot:
                if not self._after_end(at):
                    self._end_run(FINISHED)
                return False
            index %= count
            self._enter_state(index, at)
            return not self._cross_boundary(at)
        self._enter_state(index, at)
        return True

    def _cross_boundary(self, at: float) -> bool:
        """A cycle ended at ``at``: count it and switch if a switch or the sequence says so; True if switched."""
        self.cycle.set(int(self.cycle.peek()) + 1)
        if self._switch_due(at):
            return True
        if self._sequence_at + 1 < len(self.program.sequence):
            self._cycles_left -= 1
            if self._cycles_left <= 0:
                return self._next_step(at)
        return False

    def _after_end(self, at: float) -> bool:
        """A one-shot mode ended at ``at``: an event a program switches on. Go on with a switch asked for by then,
        or the sequence's next step; True if the run goes on."""
        return self._switch_due(at) or self._next_step(at)

    def _switch_due(self, at: float) -> bool:
        """Make the switch asked for (gait.switch) if ``at`` is at or after its time; True if it was made."""
        with self._lock:
            pending = self._switch_request
            if pending is None or at < pending[2] - _EPS:
                return False
            self._switch_request = None
        self._switch_to(pending[0], pending[1], at)
        return True

    def _next_step(self, at: float) -> bool:
        """Go on to the sequence's next step at ``at``; False when there is none."""
        sequence = self.program.sequence
        if self._sequence_at + 1 >= len(sequence):
            return False
        self._sequence_at += 1
        mode, self._cycles_left = sequence[self._sequence_at]
        self._switch_to(mode, self._drive, at)
        return True

    def _switch_to(self, index: int, drive: int, at: float) -> None:
        mode = self.program.modes[index]
        phase, direction = mode.phase, mode.direction
        if index == self.program.first:  # the start mode keeps the phase and direction the module was started with
            phase, direction = self._base
        self._drive = drive
        self.switched_at = at
        self._enter_mode(index, at, phase, direction * drive, blend=True)

    def _end_run(self, outcome: int) -> None:
        self._finished = True
        self.done.set(outcome)
        # stopping waits for this very handler to return: ask from another thread
        threading.Thread(target=self.stop, kwargs={"timeout": 5.0}, name="asm:gait.done", daemon=True).start()

    # -- the reference ------------------------------------------------------------------------------------------

    def _reference(self, now: float) -> float:
        if self._current.timed:
            value = reference_at(self._phase_states, self._starts, self.period, self.tau)
            assert not isinstance(value, tuple), "a module's joint is one angle"
            return float(value)
        states = self._current.states
        state = states[self._index]
        if state.interpolation == "step" or state.duration is None:
            return state.target
        previous = states[(self._index - self.heading()) % len(states)].target
        frac = min(1.0, max(0.0, (now - self._entered) / state.duration))
        return previous + frac * (state.target - previous)

    def _output(self, now: float) -> None:
        reference = self._reference(now)
        offset, since = self._blend
        if offset:
            left = 1.0 - (now - since) / SWITCH_BLEND
            if left <= 0:
                self._blend = (0.0, 0.0)
            else:
                reference += offset * left
        self.reference_out.set(reference)

    def on_suspend(self) -> None:
        self._paused_at = self.clock.now()

    def _resuming(self) -> None:
        super()._resuming()
        now = self.clock.now()
        pause = max(0.0, now - self._paused_at)
        self._entered += pause
        self._boundary += pause
        self._blend = (self._blend[0], self._blend[1] + pause)
        if self._current.timed:
            self._last_tick = now
            self._anchor = (self.tau, now, self.heading())
