"""What a module runs: a program of gaits, each a phase automaton that may be time-driven or sensor-driven,
periodic or one-shot, local or coordinated with a neighbour (paper section 4.3).

A :class:`Program` is a list of :class:`Mode` s — the gaits of the program as this module runs them (forward, turn
left, …) — and an optional sequence saying which mode runs for how many cycles. A mode is a list of
:class:`ModeState` s, the phase delay and direction this module starts it with, and whether it is one-shot.

A state lasts its ``duration`` (time-driven) or ends on an :class:`Until` event, the duration then being its
timeout: the module's contact made or lost, its joint within a tolerance of the target, its torque above a
threshold, or a neighbour module being in a given state (its ``gait.state`` publications, carried over the bus).
On a timeout the state either moves on (``next``) or ends the service (``stop``).

Timing rules, the same on every module so that modules agree without talking:

- The **cycle boundaries** of a time-driven mode are its start time plus whole periods; a sensor-driven mode
  crosses one when it wraps from its last state to its first. ``gait.cycle`` counts them.
- A **switch** (``gait.switch`` = {mode, direction, after}) happens at the first cycle boundary at or after
  ``after`` (seconds on the module's clock; 0: the next boundary). Every module of a robot started together has
  the same boundaries, so a switch sent to all of them with the same ``after`` happens at the same tick on each.
  A program's ``sequence`` switches by itself after the given number of cycles, or, for a one-shot mode, when the
  mode ends (switching on an event: "curl up, then …"); a switch asked for by then also happens at that end.
- Across a switch the joint does not jump: the difference between the old and the new reference at the switch
  decays linearly over ``SWITCH_BLEND`` seconds.
- Events are evaluated at the control tick; a neighbour's state counts from the tick after it arrived, whether it
  came over a bus or from a simulator's hub, so a preview and a deployed robot make the same decisions.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

from asm_py.automaton import Interpolation, PhaseState

EventName = Literal["contact", "no_contact", "at_goal", "torque", "neighbour", "signal"]
CONTROL_PERIOD = 0.02
"""Seconds between two control ticks of a module (50 Hz): the shortest state a module can execute."""
MIN_DURATION = struct.unpack("<f", struct.pack("<f", CONTROL_PERIOD))[0]
"""The shortest duration a table may carry: one control tick, as float32 (what the wire holds for 0.02)."""
MIN_DURATION_TEXT = f"{CONTROL_PERIOD:g} s"

EVENTS: tuple[EventName, ...] = ("contact", "no_contact", "at_goal", "torque", "neighbour", "signal")
"""contact: the contact sensor goes from free to touching during the state; no_contact: from touching to free;
at_goal: |joint.angle - target| <= value degrees; torque: |joint.torque| >= value N·m; neighbour: module
(own ID + neighbour) is in state ``state``; signal: broadcast signal number ``state`` (1..255) arrives during the
state — sent by a module entering a state that emits it, or by any tool (a group SET of ``gait.signal``)."""
OUTCOMES = ("next", "stop")
SWITCH_BLEND = 0.5
"""Seconds over which the reference's jump at a switch is blended out."""
MAX_MODES = 16
MAX_SEQUENCE = 32


@dataclass(frozen=True)
class Until:
    """The event that ends a state."""

    event: EventName
    value: float = 0.0
    """Tolerance in degrees (at_goal) or threshold in N·m (torque); unused otherwise."""
    neighbour: int = -1
    """neighbour: the watched module's ID relative to this one (-1: the previous module)."""
    state: int = 0
    """neighbour: the watched module's state (0-based index in its own automaton)."""
    on_timeout: Literal["next", "stop"] = "next"
    """What the state's duration running out does: move on, or end the service (``gait.done`` = TIMED_OUT)."""

    def __post_init__(self) -> None:
        if self.event not in EVENTS:
            raise ValueError(f"unknown event {self.event!r} (known: {', '.join(EVENTS)})")
        if self.on_timeout not in OUTCOMES:
            raise ValueError(f"on_timeout must be 'next' or 'stop', not {self.on_timeout!r}")
        if not (math.isfinite(self.value) and self.value >= 0):
            raise ValueError(f"an event's tolerance or threshold must be a finite number >= 0, not {self.value}")
        if self.event == "neighbour" and not (self.neighbour != 0 and -128 <= self.neighbour <= 127):
            raise ValueError(f"a neighbour is another module, -128..127 IDs away, not {self.neighbour}")
        if not 0 <= self.state <= 0xFFFF:
            raise ValueError(f"a neighbour's state is 0..65535, not {self.state}")
        if self.event == "signal" and not 1 <= self.state <= 255:
            raise ValueError(f"a signal is numbered 1..255, not {self.state}")


@dataclass(frozen=True)
class ModeState:
    """One state: a target angle reached by a step or a linear ramp over ``duration``, ended by time or event."""

    target: float
    duration: float | None
    """Seconds (time-driven), or the timeout of an event; None only with an event: no timeout."""
    interpolation: Interpolation = "step"
    until: Until | None = None
    emit: int = 0
    """Broadcast signal 1..255 on entering the state (0: none): a global event other modules' states can end on."""

    def __post_init__(self) -> None:
        if not 0 <= self.emit <= 255:
            raise ValueError(f"a state emits signal 1..255 (0: none), not {self.emit}")
        if self.duration is None:
            if self.until is None:
                raise ValueError("a state needs a duration, an event, or both")
        elif not (self.duration >= MIN_DURATION and math.isfinite(self.duration)):
            raise ValueError(f"state duration must be a finite number of seconds, at least one control tick "
                             f"({MIN_DURATION_TEXT}), not {self.duration}")  # fmt: skip
        if not math.isfinite(self.target):
            raise ValueError(f"state target must be a finite number, not {self.target}")
        if self.interpolation not in ("step", "linear"):
            raise ValueError(f"interpolation must be 'step' or 'linear', not {self.interpolation!r}")


@dataclass(frozen=True)
class Mode:
    """One gait of a program, as this module runs it."""

    states: tuple[ModeState, ...]
    phase: float = 0.0
    """Initial phase delay φ ∈ [0, 1) (mode 0 starts at ``gait.phase`` instead)."""
    direction: int = 1
    """±1 (mode 0 starts with ``gait.direction`` instead)."""
    one_shot: bool = False
    """Non-periodic: after its last state the service stops by itself (``gait.done`` = FINISHED)."""

    def __post_init__(self) -> None:
        if not self.states:
            raise ValueError("a mode needs at least one state")
        if not 0.0 <= self.phase < 1.0 or self.direction not in (1, -1):
            raise ValueError(f"phase must be in [0, 1) and direction ±1, not {self.phase}, {self.direction}")

    @cached_property
    def timed(self) -> bool:
        """Periodic and time-driven: run by the phase-time rule of PeriodicAutomaton (asked at every tick of every
        module, so worked out once: a mode never changes)."""
        return not self.one_shot and all(s.until is None for s in self.states)

    def _durations(self) -> list[float]:
        durations = [s.duration for s in self.states if s.duration is not None]
        if len(durations) != len(self.states):
            raise ValueError("a state that waits for an event without a timeout has no fixed duration")
        return durations

    def phase_states(self) -> list[PhaseState]:
        return [PhaseState(s.target, d, s.interpolation) for s, d in zip(self.states, self._durations(), strict=True)]

    @cached_property
    def period(self) -> float | None:
        return math.fsum(self._durations()) if self.timed else None


@dataclass(frozen=True)
class Program:
    """Everything a module runs: its modes and the sequence that switches between them by itself."""

    modes: tuple[Mode, ...]
    sequence: tuple[tuple[int, int], ...] = ()
    """(mode index, cycles) in order; the last entry runs until a switch is commanded (its cycles are ignored). A
    one-shot mode's step ends when the mode does (an event), whatever its cycles: 0 says so."""

    def __post_init__(self) -> None:
        if not 1 <= len(self.modes) <= MAX_MODES:
            raise ValueError(f"a program has 1..{MAX_MODES} modes, not {len(self.modes)}")
        if len(self.sequence) > MAX_SEQUENCE:
            raise ValueError(f"a program's sequence has at most {MAX_SEQUENCE} entries, not {len(self.sequence)}")
        for mode, cycles in self.sequence:
            if not 0 <= mode < len(self.modes) or not 0 <= cycles <= 0xFFFF:
                raise ValueError(f"sequence entry ({mode}, {cycles}): no such mode, or cycles outside 0..65535")

    @property
    def simple(self) -> bool:
        """One periodic time-driven mode, no sequence, no signal emitted: what a version-1 gait table holds."""
        return len(self.modes) == 1 and not self.sequence and self.modes[0].timed and not self.emits()

    @property
    def first(self) -> int:
        """The mode a start runs."""
        return self.sequence[0][0] if self.sequence else 0

    def targets(self) -> list[float]:
        return [s.target for m in self.modes for s in m.states]

    def emits(self) -> bool:
        return any(s.emit for m in self.modes for s in m.states)

    def neighbours(self) -> set[int]:
        """Relative IDs of the modules whose states this program waits on."""
        return {s.until.neighbour for m in self.modes for s in m.states
                if s.until is not None and s.until.event == "neighbour"}  # fmt: skip


def program_of(states: list[PhaseState]) -> Program:
    """A version-1 table's states as a program of one mode."""
    modes = []
    for s in states:
        if isinstance(s.target, tuple):
            raise ValueError(f"a module's table holds one angle per state, not {s.target!r}")
        modes.append(ModeState(float(s.target), s.duration, s.interpolation))
    return Program((Mode(tuple(modes)),))
