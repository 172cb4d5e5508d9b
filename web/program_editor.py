"""The Gait tab's controls for what goes beyond a periodic, time-driven gait: what ends the selected state (an
event, its tolerance or threshold, the neighbour it waits on, what a timeout does), whether the automaton is
one-shot, and the program — its gaits (forward, left, …) and the sequence it runs by itself.

Every control edits the document as one undoable step, like the rest of the editor; a combination the loader
refuses (a neighbour that does not exist) shows as a problem at the field, never silently altered.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

from gaits.model import EVENTS, FORWARD

from .document import GaitDocument
from .inputs import number, whole

TIME = "time (its duration)"
"""The Ends-on choice of a state without an event."""


def parse_sequence(text: str) -> list[tuple[str, int | None]]:
    """``forward 5, left 5, forward`` → [(forward, 5), (left, 5), (forward, None)]; ValueError saying what is wrong.
    A step without cycles runs until its gait ends (one-shot); the loader says so if that gait never ends."""
    steps: list[tuple[str, int | None]] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        match = re.fullmatch(r"([A-Za-z0-9_-]{1,64})(?:\s*[x×*]?\s*(\d{1,5}))?", part)
        if match is None:
            raise ValueError(f"{part!r}: write a gait name and its cycles, e.g. 'forward 5, left 5, forward'")
        steps.append((match[1], int(match[2]) if match[2] else None))
    return steps


def format_sequence(steps: list[dict[str, Any]]) -> str:
    return ", ".join(f"{s.get('gait', '?')}" + (f" {s['cycles']}" if "cycles" in s else "") for s in steps)


_EVENT_FIELDS = ("until", "value", "neighbour", "state", "signal", "on_timeout")
"""The EventControls fields that together say what ends a state (written as one)."""


class EventControls:
    """What ends the selected state, and whether its automaton is one-shot (inside the Selected state folder)."""

    def __init__(
        self,
        gui: Any,
        doc: GaitDocument,
        *,
        selected: Callable[[], tuple[str, int, int | None]],
        edited: Callable[[], None],
        on_edit: Callable[..., Any],
    ) -> None:
        self.doc = doc
        self._selected = selected
        self.until = gui.add_dropdown("Ends on", [TIME, *EVENTS],
                                      hint="an event ends the state early; its duration is then a timeout")  # fmt: skip
        self.value = number(gui, "Tolerance / threshold", initial_value=2.0, step=0.5,
                            hint="at_goal: degrees; torque: N·m")  # fmt: skip
        self.neighbour = number(gui, "Neighbour (± IDs)", initial_value=-1, step=1,
                                hint="neighbour: which module, relative to this one")  # fmt: skip
        self.state = gui.add_text("Neighbour state", initial_value="",
                                  hint="neighbour: the state it waits for, by name or 1-based number")  # fmt: skip
        self.signal = number(gui, "Signal", initial_value=1, step=1,
                             hint="signal: the broadcast (1..255) that ends the state")  # fmt: skip
        self.emit = number(gui, "Emits signal", initial_value=0, step=1,
                           hint="sent to every module on entering the state (1..255; 0: none)")  # fmt: skip
        self.on_timeout = gui.add_dropdown("On timeout", ["next", "stop"],
                                           hint="with an event and a duration: go on, or end the gait")  # fmt: skip
        self.one_shot = gui.add_checkbox("One-shot automaton", initial_value=False,
                                         hint="the gait ends after the last state instead of repeating")  # fmt: skip

        def shown() -> tuple[tuple[str, int, int | None], dict[str, Any]]:
            # read on viser's loop as a value comes (the page's on_edit): the state selected and every field as the
            # user saw them; a resync for another state may have replaced both before the callback runs
            return self._selected(), {name: getattr(self, name).value for name in _EVENT_FIELDS}

        def write(_: Any, seen: tuple[tuple[str, int, int | None], dict[str, Any]]) -> None:
            self._write(*seen)
            edited()

        for name in _EVENT_FIELDS:
            on_edit(getattr(self, name), write, context=shown)

        def emit(value: Any, seen: tuple[tuple[str, int, int | None], dict[str, Any]]) -> None:
            automaton, index, layout = seen[0]
            self.doc.set_emit(automaton, index, whole(value, "Emits signal"), layout=layout)
            edited()

        def one_shot(value: Any, seen: tuple[tuple[str, int, int | None], dict[str, Any]]) -> None:
            self.doc.set_one_shot(seen[0][0], bool(value))
            edited()

        on_edit(self.emit, emit, context=shown)
        on_edit(self.one_shot, one_shot, context=shown)

    def _write(self, at: tuple[str, int, int | None], shown: dict[str, Any]) -> None:
        """What ends the state ``at``, from the fields as ``shown`` together (see ``shown`` above)."""
        automaton, index, layout = at
        self.doc.check_layout(layout)  # before the state is read: its index may name another state, or none
        until = None if shown["until"] == TIME else shown["until"]
        fields: dict[str, Any] = {}
        if until == "at_goal":
            fields["tolerance"] = float(shown["value"])
        elif until == "torque":
            fields["threshold"] = float(shown["value"])
        elif until == "signal":
            fields["signal"] = whole(shown["signal"], "Signal")
        elif until == "neighbour":
            text = str(shown["state"]).strip()
            fields["neighbour"] = whole(shown["neighbour"], "Neighbour")
            fields["state"] = int(text) if text.isdigit() else text
        state = self.doc.data()["automata"][automaton]["states"][index]
        if until is not None and "duration" in state and shown["on_timeout"] == "stop":
            fields["on_timeout"] = "stop"
        self.doc.set_event(automaton, index, until, layout=layout, **fields)

    def sync(self, data: dict[str, Any], automaton: str, index: int) -> None:
        """Show the selected state's event (called inside the dashboard's programmatic block)."""
        auto = data["automata"][automaton]
        state = auto["states"][index]
        until = state.get("until")
        self.until.value = until if until in EVENTS else TIME
        value = state.get("tolerance", state.get("threshold"))
        self.value.value = float(value) if isinstance(value, int | float) else (2.0 if until != "torque" else 1.0)
        self.value.disabled = until not in ("at_goal", "torque")
        neighbour = state.get("neighbour", -1)
        self.neighbour.value = float(neighbour) if isinstance(neighbour, int) else -1.0  # floats: see inputs.number
        self.state.value = str(state.get("state", ""))
        self.neighbour.disabled = self.state.disabled = until != "neighbour"
        signal = state.get("signal", 1)
        self.signal.value = float(signal) if isinstance(signal, int) else 1.0
        self.signal.disabled = until != "signal"
        emit = state.get("emit", 0)
        self.emit.value = float(emit) if isinstance(emit, int) else 0.0
        self.on_timeout.value = (
            state.get("on_timeout", "next") if state.get("on_timeout") in ("next", "stop") else "next"
        )
        self.on_timeout.disabled = until is None
        self.one_shot.value = bool(auto.get("one_shot", False))


class ProgramPanel:
    """The program: its gaits, which one the Module folder edits, and its sequence (a folder of the Gait tab)."""

    def __init__(self, gui: Any, doc: GaitDocument, *, edited: Callable[[], None], safe: Callable[..., Any],
                 syncing: Callable[[], bool], on_edit: Callable[..., Any]) -> None:  # fmt: skip
        self.doc = doc
        self.editing = gui.add_dropdown("Edit modules of", [FORWARD],
                                        hint="which gait of the program the Module folder edits")  # fmt: skip
        self.name = gui.add_text("New gait", initial_value="left", hint="e.g. left, right, turn_left")
        self.actions = gui.add_button_group("Program gaits", ["Add (copy of forward)", "Remove edited"])
        self.sequence = gui.add_text("Sequence", initial_value="",
                                     hint="run by itself: 'forward 5, left 5, forward' (cycles each)")  # fmt: skip
        self.problem = gui.add_markdown("")

        self._edited = edited
        on_edit(self.actions, self.on_action, click=True)  # (the page's: each with the value it arrived with)
        on_edit(self.sequence, self._on_sequence)
        self.editing.on_update(safe(lambda _: None if syncing() else edited()))

    def on_action(self, clicked: str) -> None:
        """The Program gaits buttons: add a copy of forward under the typed name, or remove the edited gait."""
        if clicked.startswith("Add"):
            name = self.name.value.strip()
            self.doc.add_program_gait(name)
            self._edited()
            self.editing.value = name
        elif self.editing.value == FORWARD:
            raise ValueError("forward is the gait every program has: it cannot be removed")
        else:
            self.doc.remove_program_gait(self.editing.value)
            self.editing.value = FORWARD
        self._edited()

    def _on_sequence(self, text: str) -> None:
        self.doc.set_sequence(parse_sequence(text))
        self._edited()

    def gait(self) -> str:
        """The gait of the program the Module folder edits."""
        return str(self.editing.value)

    def sync(self, data: dict[str, Any]) -> None:
        gaits = data.get("gaits", {})
        names = [FORWARD, *(gaits if isinstance(gaits, dict) else {})]
        if list(self.editing.options) != names:
            self.editing.options = names
        if self.editing.value not in names:
            self.editing.value = FORWARD
        steps = data.get("program", {}).get("sequence", [])
        text = format_sequence(steps if isinstance(steps, list) else [])
        if self.sequence.value.strip() != text:
            self.sequence.value = text
        problems = self.doc.problem_at("program") + self.doc.problem_at("gaits")
        self.problem.content = "".join(f"⚠ {p.message}  \n" for p in problems)
