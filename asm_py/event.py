"""Events and triggers (paper section 4.1).

An :class:`Event` is an attribute with sync_get on and sync_set off, so ``get`` still waits for a valid value and
consumes it exactly as the paper's attribute does. ``waiting()`` refines the paper's single ``valid`` flag: it waits
for the next *firing* (a ``set`` after the call began), counted by a firing counter rather than by ``valid``, so
every thread blocked in ``waiting()`` at a firing wakes once for it, and ``waiting()`` does not consume the value
(a concurrent ``get`` still sees it valid). With the paper's flag alone, the first waiter to wake would clear
``valid`` and the others would sleep through the firing.

A trigger fires its events. Kinds: :class:`Trigger` fired from a callback (the interrupt case),
:class:`TimerTrigger` (periodic or one-shot, a service), :class:`ThresholdTrigger` (edge crossings of an
attribute's value, driven by its change notification), :class:`ConditionTrigger` (a polling service).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any

from .attribute import Attribute
from .clock import Clock
from .codec import Codec
from .errors import AsmTimeout
from .service import Service


def _check_seconds(seconds: float, what: str) -> None:
    if not (seconds > 0 and math.isfinite(seconds)):
        raise ValueError(f"{what} must be a positive number of seconds, not {seconds}")


class Event(Attribute):
    """An attribute that triggers set; see the module docstring."""

    __slots__ = ("_triggers",)

    def __init__(
        self, name: str, initial: Any = None, *, codec: Codec | str | None = None, clock: Clock | None = None
    ) -> None:
        super().__init__(name, initial, sync_get=True, sync_set=False, codec=codec, clock=clock)
        self._triggers: tuple[Trigger, ...] = ()

    def waiting(self, timeout: float | None = None) -> Any:
        """Block until the next firing and return its value; TimeoutError after ``timeout`` clock seconds."""
        mon = self._mon
        with mon.lock:
            seen = self._changes
            if not mon.wait_for(lambda: self._changes != seen, timeout):
                raise AsmTimeout(f"waiting on event {self._name!r} timed out after {timeout}s")
            return self._value

    def add_trigger(self, trigger: Trigger) -> None:
        """Let ``trigger`` fire this event (a trigger can feed several events)."""
        trigger._attach(self)
        with self._mon.lock:
            self._triggers = (*self._triggers, trigger)

    def remove_trigger(self, trigger: Trigger) -> None:
        trigger._detach(self)
        with self._mon.lock:
            self._triggers = tuple(t for t in self._triggers if t is not trigger)

    @property
    def triggers(self) -> tuple[Trigger, ...]:
        return self._triggers


class Trigger:
    """Fires its events; call ``fire`` from any thread or callback (an interrupt handler, a driver callback)."""

    def __init__(self, name: str | None = None) -> None:
        self._trigger_name = name or f"trigger@{id(self):x}"
        self._events: tuple[Event, ...] = ()
        self._fire_lock = threading.Lock()
        self._fired = 0

    @property
    def fired(self) -> int:
        """How many times this trigger has fired."""
        return self._fired

    @property
    def events(self) -> tuple[Event, ...]:
        return self._events

    def fire(self, value: Any = None) -> None:
        """Set every event of this trigger to ``value``, waking their waiters."""
        with self._fire_lock:
            self._fired += 1
        for event in self._events:
            event.set(value)

    def _attach(self, event: Event) -> None:
        with self._fire_lock:
            if event not in self._events:
                self._events = (*self._events, event)

    def _detach(self, event: Event) -> None:
        with self._fire_lock:
            self._events = tuple(e for e in self._events if e is not event)


class TimerTrigger(Service, Trigger):
    """Fires every ``period`` seconds of its clock (once, with ``one_shot``), with the due time as value.

    Firings stay on the grid start + k·period, so they do not drift. Suspended, the timer holds; on resume it fires
    the overdue tick once and continues on the grid, skipping ticks missed in between.
    """

    def __init__(
        self, period: float, one_shot: bool = False, *, name: str | None = None, clock: Clock | None = None
    ) -> None:
        _check_seconds(period, "a timer period")
        name = name or f"timer({period:g}s)"
        Service.__init__(self, name, clock=clock)
        Trigger.__init__(self, name)
        self.period = float(period)
        self.one_shot = one_shot

    def run(self, *params: Any) -> None:
        clock = self.clock
        origin = clock.now()
        tick = 1
        while self.sleep_until(due := origin + tick * self.period):
            self.fire(due)
            if self.one_shot:
                return
            tick = max(tick + 1, math.ceil((clock.now() - origin) / self.period))


class ThresholdTrigger(Trigger):
    """Fires when ``attribute`` rises above ``above`` or falls below ``below``; no polling.

    Edge-triggered with hysteresis: after firing above ``above`` it re-arms once the value is back at or below
    ``above - hysteresis`` (and symmetrically for ``below``). A value already past a threshold when the trigger is
    made does not fire until it has re-armed. The firing value is the attribute's new value.
    """

    def __init__(
        self,
        attribute: Attribute,
        above: float | None = None,
        below: float | None = None,
        hysteresis: float = 0.0,
        *,
        name: str | None = None,
    ) -> None:
        if above is None and below is None:
            raise ValueError("a ThresholdTrigger needs 'above', 'below' or both")
        if not hysteresis >= 0:
            raise ValueError(f"hysteresis must be >= 0, not {hysteresis}")
        super().__init__(name or f"threshold({attribute.name})")
        self.above = above
        self.below = below
        self.hysteresis = float(hysteresis)
        self._state_lock = threading.Lock()
        current = attribute.peek()
        self._above_armed = above is not None and (current is None or current <= above)
        self._below_armed = below is not None and (current is None or current >= below)
        self._remove = attribute.on_change(self._observe)

    def _observe(self, value: Any) -> None:
        fire = False
        with self._state_lock:
            if self.above is not None:
                if self._above_armed and value > self.above:
                    self._above_armed, fire = False, True
                elif not self._above_armed and value <= self.above - self.hysteresis:
                    self._above_armed = True
            if self.below is not None:
                if self._below_armed and value < self.below:
                    self._below_armed, fire = False, True
                elif not self._below_armed and value >= self.below + self.hysteresis:
                    self._below_armed = True
        if fire:
            self.fire(value)

    def close(self) -> None:
        """Stop watching the attribute."""
        self._remove()


class ConditionTrigger(Service, Trigger):
    """A polling service: evaluates ``predicate()`` every ``poll_period`` and fires when it becomes true.

    Edge-triggered: it fires on a false→true change (including a predicate already true at the first poll), not on
    every poll while true. An exception in the predicate stops the service (see ``Service.last_error``).
    """

    def __init__(
        self,
        predicate: Callable[[], Any],
        poll_period: float,
        *,
        name: str | None = None,
        clock: Clock | None = None,
    ) -> None:
        _check_seconds(poll_period, "a poll period")
        name = name or f"condition({getattr(predicate, '__name__', 'predicate')})"
        Service.__init__(self, name, clock=clock)
        Trigger.__init__(self, name)
        self.predicate = predicate
        self.poll_period = float(poll_period)

    def run(self, *params: Any) -> None:
        was_true = False
        while self.checkpoint():
            now_true = bool(self.predicate())
            if now_true and not was_true:
                self.fire(True)
            was_true = now_true
            if not self.sleep(self.poll_period):
                return
