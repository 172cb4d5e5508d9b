"""Phase automata (paper section 4.3): event-driven state machines that start at a phase and run either way.

:class:`PhaseAutomaton` is the paper's pattern: an event-driven service with a ``state``, a ``direction``, an
initialization routine run by ``start(phase)`` that sets the initial state and first actions from the initial phase
delay φ ∈ [0, 1), and an event handler made of ``next_state`` then ``action``. Supply the three routines as
callables or override them. ``state`` and ``direction`` are attributes, so they can be read, set and published
remotely; a negative direction means backward, anything else forward.

:class:`PeriodicAutomaton` is the gait case: N states, each with a target and a duration (period T = their sum),
driven by a periodic tick event. Each tick advances the phase time τ by the clock time elapsed since the previous
tick, times the direction, and sets ``output`` to the reference trajectory at τ. Started with phase φ at time t0,
its output at time t is ``reference(φ·T + d·(t - t0))``: the trajectory shifted by φ·T, sampled at the ticks.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from .attribute import Attribute, CheckedAttribute
from .clock import Clock
from .codec import FLOAT64, INT8, UINT16, float_array
from .eds import EventDrivenService, SuspendedPolicy
from .errors import ServiceError


def _check_direction(direction: int) -> int:
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 (forward) or -1 (backward), not {direction!r}")
    return int(direction)


class PhaseAutomaton(EventDrivenService):
    """The paper's phase automaton; see the module docstring."""

    def __init__(
        self,
        name: str,
        event: Attribute,
        states: Sequence[Any],
        *,
        direction: int = 1,
        initialize: Callable[[PhaseAutomaton, float], None] | None = None,
        next_state: Callable[[PhaseAutomaton, int, Any], int] | None = None,
        action: Callable[[PhaseAutomaton, int, Any], None] | None = None,
        while_suspended: SuspendedPolicy = "drop",
        max_pending: int = 64,
        inline: bool = False,
        clock: Clock | None = None,
    ) -> None:
        if not states:
            raise ValueError(f"phase automaton {name!r} needs at least one state")
        if len(states) > UINT16.max:
            raise ValueError(f"phase automaton {name!r} has {len(states)} states; at most {UINT16.max}")
        super().__init__(
            name, event, while_suspended=while_suspended, max_pending=max_pending, inline=inline, clock=clock
        )
        self.states: tuple[Any, ...] = tuple(states)
        self.state = Attribute(f"{name}.state", 0, codec=UINT16, clock=self.clock)
        self.direction = CheckedAttribute(f"{name}.direction", _check_direction(direction), codec=INT8,
                                          check=_check_direction, clock=self.clock)  # fmt: skip
        self.phase = 0.0
        self._initialize = initialize
        self._next_state = next_state
        self._action = action

    def start(self, phase: float = 0.0, direction: int | None = None, *, wait: bool = True) -> None:  # pyright: ignore[reportIncompatibleMethodOverride]  # a phase automaton's start parameters are its phase and direction (paper §4)
        """Start with initial phase delay ``phase`` ∈ [0, 1) and, if given, a new direction (±1)."""
        super().start(phase, direction)

    def heading(self) -> int:
        """The current direction as +1 or -1."""
        return -1 if self.direction.peek() < 0 else 1

    def initialize(self, phase: float) -> None:
        """Set the initial state and do the first actions; default: state ⌊φ·N⌋, then ``action``."""
        if self._initialize is not None:
            self._initialize(self, phase)
            return
        index = min(int(phase * len(self.states)), len(self.states) - 1)
        self.state.set(index)
        self.action(index, None)

    def next_state(self, state: int, value: Any) -> int:
        """The state after a firing; default: one step in the current direction, cyclically."""
        if self._next_state is not None:
            return self._next_state(self, state, value)
        return (state + self.heading()) % len(self.states)

    def action(self, state: int, value: Any) -> None:
        """What entering ``state`` on a firing with ``value`` does (``value`` is None at initialization)."""
        if self._action is not None:
            self._action(self, state, value)

    def handle(self, value: Any) -> None:
        state = self.next_state(self.state.peek(), value)
        self.state.set(state)
        self.action(state, value)

    def _starting(self, phase: float = 0.0, direction: int | None = None) -> None:  # pyright: ignore[reportIncompatibleMethodOverride]  # see start
        phase = float(phase)
        if not 0.0 <= phase < 1.0:
            raise ValueError(f"initial phase of {self.name!r} must be in [0, 1), not {phase}")
        if direction is not None:
            self.direction.set(_check_direction(direction))
        super()._starting()
        self.phase = phase
        self.initialize(phase)


Interpolation = Literal["step", "linear"]
INTERPOLATIONS: tuple[Interpolation, ...] = ("step", "linear")


def interpolation_of(name: str) -> Interpolation:
    """``name`` as an interpolation; ValueError for any other text (gait files are checked before this)."""
    for known in INTERPOLATIONS:
        if known == name:
            return known
    raise ValueError(f"interpolation is one of {', '.join(INTERPOLATIONS)}, not {name!r}")


@dataclass(frozen=True)
class PhaseState:
    """One state of a periodic automaton."""

    target: float | tuple[float, ...]
    """The output value of this state (a float, or a tuple of floats for several joints)."""
    duration: float
    """Seconds spent in this state per period; > 0."""
    interpolation: Interpolation = "step"
    """``step`` holds ``target`` for the whole state; ``linear`` ramps from the previous state's target to it."""

    def __post_init__(self) -> None:
        if not (self.duration > 0 and math.isfinite(self.duration)):
            raise ValueError(f"state duration must be a positive number of seconds, not {self.duration}")
        if self.interpolation not in ("step", "linear"):
            raise ValueError(f"interpolation must be 'step' or 'linear', not {self.interpolation!r}")
        values = self.target if isinstance(self.target, tuple) else (self.target,)
        if not all(isinstance(v, int | float) and math.isfinite(v) for v in values):
            raise ValueError(f"state target must be finite numbers, not {self.target!r}")


def state_starts(states: Sequence[PhaseState]) -> list[float]:
    """Phase time at which each state begins (seconds into the period)."""
    return [math.fsum(s.duration for s in states[:i]) for i in range(len(states))]


def reference_at(
    states: Sequence[PhaseState], starts: Sequence[float], period: float, tau: float
) -> float | tuple[float, ...]:
    """The reference trajectory of periodic states at phase time ``tau``: what a PeriodicAutomaton outputs, and
    what a gait table is expanded from (one function, so preview and modules agree)."""
    tau %= period
    index = bisect.bisect_right(starts, tau) - 1
    state = states[index]
    if state.interpolation == "step":
        return state.target
    previous = states[index - 1].target
    frac = (tau - starts[index]) / state.duration
    target = state.target
    if isinstance(target, tuple) and isinstance(previous, tuple):
        return tuple(p + frac * (t - p) for p, t in zip(previous, target, strict=True))
    if isinstance(target, tuple) or isinstance(previous, tuple):
        raise TypeError(f"states of one automaton mix scalar and vector targets: {previous!r}, {target!r}")
    return previous + frac * (target - previous)


def scalar_reference_at(states: Sequence[PhaseState], starts: Sequence[float], period: float, tau: float) -> float:
    """:func:`reference_at` for one joint: gait tables and module programs hold one angle per state."""
    value = reference_at(states, starts, period, tau)
    if isinstance(value, tuple):
        raise TypeError(f"a joint's states have scalar targets, not {value!r}")
    return float(value)


class PeriodicAutomaton(PhaseAutomaton):
    """A time-driven phase automaton over :class:`PhaseState` s; see the module docstring."""

    def __init__(
        self,
        name: str,
        event: Attribute,
        states: Sequence[PhaseState],
        *,
        output: Attribute | None = None,
        direction: int = 1,
        while_suspended: SuspendedPolicy = "drop",
        inline: bool = False,
        clock: Clock | None = None,
    ) -> None:
        super().__init__(
            name, event, states, direction=direction, while_suspended=while_suspended, inline=inline, clock=clock
        )
        width = self._check_shape(self.states)
        self.period = math.fsum(s.duration for s in self.states)
        self._starts = state_starts(self.states)
        codec = FLOAT64 if width is None else float_array(width, FLOAT64)
        self.output = output if output is not None else Attribute(f"{name}.output", codec=codec, clock=self.clock)
        self.tau = 0.0
        # τ is computed from an anchor (τ, time, direction), re-set on resume and direction changes, rather than
        # summed tick by tick, so rounding does not accumulate over long runs.
        self._anchor = (0.0, 0.0, 1)
        self._last_tick = 0.0

    def _check_shape(self, states: Sequence[PhaseState]) -> int | None:
        widths = {len(s.target) if isinstance(s.target, tuple) else None for s in states}
        if len(widths) != 1:
            raise ValueError(f"all states of {self.name!r} need targets of the same shape")
        return widths.pop()

    def load(self, states: Sequence[PhaseState]) -> None:
        """Replace the states (a new gait table); only while stopped, so a running gait never changes mid-cycle.

        ServiceError while started; ValueError if the new targets differ in shape from the output's.
        """
        states = tuple(states)
        if not states:
            raise ValueError(f"phase automaton {self.name!r} needs at least one state")
        with self._mon:
            if self._started:
                raise ServiceError(f"{self.name!r} is started; stop it before loading new states")
            old = self._check_shape(self.states)
            if self._check_shape(states) != old:
                raise ValueError(f"the new states of {self.name!r} must have targets of the same shape as before")
            self.states = states
            self.period = math.fsum(s.duration for s in states)
            self._starts = state_starts(states)

    def state_at(self, tau: float) -> int:
        """The index of the state in effect at phase time ``tau`` (seconds into the period)."""
        return bisect.bisect_right(self._starts, tau % self.period) - 1

    def reference(self, tau: float) -> float | tuple[float, ...]:
        """The reference trajectory: the output at phase time ``tau``."""
        return reference_at(self.states, self._starts, self.period, tau)

    def initialize(self, phase: float) -> None:
        self.tau = phase * self.period
        self._last_tick = self.clock.now()
        self._anchor = (self.tau, self._last_tick, self.heading())
        index = self.state_at(self.tau)
        self.state.set(index)
        self.action(index, None)

    def next_state(self, state: int, value: Any) -> int:
        now = self.clock.now()
        tau0, t0, heading = self._anchor
        if self.heading() != heading:  # the new direction applies from the previous tick on
            tau0, t0, heading = self._anchor = (self.tau, self._last_tick, self.heading())
        self.tau = (tau0 + heading * (now - t0)) % self.period
        self._last_tick = now
        return self.state_at(self.tau)

    def action(self, state: int, value: Any) -> None:
        self.output.set(self.reference(self.tau))

    def _resuming(self) -> None:
        super()._resuming()
        self._last_tick = self.clock.now()
        self._anchor = (self.tau, self._last_tick, self.heading())
