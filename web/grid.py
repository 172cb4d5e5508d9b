"""The state grid: every automaton's states as rows of inputs, so a 16-module × 8-state gait is edited in place.

viser has no table widget. Each automaton gets a folder; each of its states one row, a pair of number inputs
(target angle in degrees, duration in seconds). The grid is rebuilt only when the table's shape changes (an
automaton or a state added or removed, another gait opened); otherwise only the inputs whose values changed are
sent, so the page does not flicker while someone types.

An input shows a rounded number (viser formats it to a fixed precision). When the page sends a row back, a component
that still equals the document's value as shown is kept as the document has it, so editing an angle never rounds the
duration of the same state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import viser

from .inputs import DIGITS, precise

PRECISION = DIGITS
"""Decimal places shown and taken, as every number field of the page (0.0625 s survives; more decimals typed are
refused by the page's script, so a change smaller than half a unit of the last place is none a user made)."""
STEP = 1e-4
"""What a step arrow adds."""
UNCHANGED = 10.0**-PRECISION / 2
"""A component of a row within this of the value shown is the value shown: not changed."""


class StateGrid:
    """One folder per automaton, one (angle, duration) row per state, inside ``parent``."""

    def __init__(
        self,
        server: viser.ViserServer,
        parent: viser.GuiFolderHandle,
        *,
        edited: Callable[[str, int, dict[str, float], int | None], None],
        on_edit: Callable[..., Callable[[], None]],
        layout: Callable[[], int | None] = lambda: None,
    ) -> None:
        self.server = server
        self.parent = parent
        self._edited = edited
        """Called with (automaton, state index, {field: value}, layout) for what the user changed."""
        self._layout = layout
        """The document's layout (GaitDocument.layout): read as a row's value comes, the index it was typed at."""
        self._on_edit = on_edit
        """The page's (web/page.py): each row's value as it came, with the value shown then, applied in order."""
        self._shape: tuple[tuple[str, tuple[str, ...]], ...] = ()
        self._folders: list[Any] = []
        self._forget: list[Callable[[], None]] = []
        self.rows: dict[tuple[str, int], Any] = {}
        """(automaton, state index) → its row's input handle."""
        self._shown: dict[tuple[str, int], tuple[float, float]] = {}

    def sync(self, data: dict[str, Any], selected: str) -> None:
        """Show ``data``'s automata (the document's plain data); the ``selected`` automaton's folder is open."""
        automata = data["automata"]
        # the rows and their labels: a state's event is in its label, so a new event rebuilds the rows too
        shape = tuple((name, tuple(_label(name, k, st) for k, st in enumerate(a["states"])))
                      for name, a in automata.items())  # fmt: skip
        if shape != self._shape:
            self._rebuild(automata, selected)
            self._shape = shape
            return
        for name, automaton in automata.items():
            for k, state in enumerate(automaton["states"]):
                value = _row_value(state)
                if self._shown.get((name, k)) != value:
                    self.rows[(name, k)].value = value
                    self._shown[(name, k)] = value

    def _rebuild(self, automata: dict[str, Any], selected: str) -> None:
        for folder in self._folders:
            folder.remove()
        for forget in self._forget:
            forget()
        self._folders, self.rows, self._shown, self._forget = [], {}, {}, []
        gui = self.server.gui
        with self.parent:
            for name, automaton in automata.items():
                folder = gui.add_folder(f"{name} ({len(automaton['states'])} states)",
                                        expand_by_default=name == selected or len(automata) <= 2)  # fmt: skip
                self._folders.append(folder)
                with folder:
                    for k, state in enumerate(automaton["states"]):
                        value = _row_value(state)
                        row = precise(gui.add_vector2(_label(name, k, state), value, step=STEP,
                                                      hint="target angle in degrees, duration in seconds (with an "
                                                           "event: its timeout, 0 for none)"))  # fmt: skip
                        key = (name, k)
                        self._forget.append(self._on_edit(row, self._callback(name, k),
                                                          context=lambda key=key: (self._shown.get(key),
                                                                                   self._layout())))  # fmt: skip
                        self.rows[key] = row
                        self._shown[(name, k)] = value

    def _callback(self, name: str, index: int) -> Callable[[Any, Any], None]:
        def update(value: Any, seen: tuple[tuple[float, float] | None, int | None]) -> None:
            """``value`` and the row as ``shown``, both as the value came: a component still as shown is one the
            user did not change (another edit's resync may have changed it since; that stays)."""
            angle, duration = (float(v) for v in value)
            shown, layout = seen
            shown_angle, shown_duration = shown if shown is not None else (None, None)
            changes: dict[str, float] = {}
            if shown_angle is None or abs(angle - shown_angle) >= UNCHANGED:
                changes["angle"] = angle
            if shown_duration is None or abs(duration - shown_duration) >= UNCHANGED:
                changes["duration"] = duration
            # what the page shows now: the resync sends only what differs
            self._shown[(name, index)] = (angle, duration)
            if changes:
                self._edited(name, index, changes, layout)

        return update


def _label(name: str, index: int, state: dict[str, Any]) -> str:
    """``wave S4 (°, s)``; a state that ends on an event says which: ``lead S8 ⇥contact (°, s)``."""
    until = state.get("until")
    return f"{name} S{index + 1}{f' ⇥{until}' if isinstance(until, str) else ''} (°, s)"


def _row_value(state: dict[str, Any]) -> tuple[float, float]:
    """What a row shows: the angle and the duration (0 for a state that waits for its event)."""
    return (round(float(state.get("angle", 0.0)), PRECISION), round(float(state.get("duration") or 0.0), PRECISION))
