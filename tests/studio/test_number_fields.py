"""The page's number fields without a browser (web/inputs.py): a field takes a fraction as the page sends it, and the
readers of whole-number fields refuse it by name — viser cast what the page sent to the type of the value the field
held, so a field made with an int took 2.5 as 2 (tests/studio/test_number_precision_page.py types it in Chromium)."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Any

import pytest

from asm_py import Attribute
from asm_py.node import Node
from asm_py.transport import MemoryNetwork, MemoryTransport
from gaits.model import LIBRARY, load
from web.document import GaitDocument
from web.inputs import DIGITS, ValueInput, number, whole
from web.program_editor import EventControls

from ..transports import free_port

pytestmark = pytest.mark.timeout(60)


def test_whole_refuses_a_fraction_naming_the_field_and_takes_a_whole_float_as_an_int() -> None:
    for value in (2.5, -0.5, 1e-9 + 3, float("inf"), float("nan")):
        with pytest.raises(ValueError, match=r"^Node ID must be a whole number, not "):
            whole(value, "Node ID")
    assert whole(2.0, "x") == 2 and type(whole(2.0, "x")) is int
    assert whole(-3, "x") == -3
    assert whole(2**64 - 1, "x") == 2**64 - 1  # exact, wider than a float holds
    with pytest.raises(ValueError):
        whole("two", "x")


@pytest.fixture
def viser_server() -> Iterator[Any]:
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield server
    server.stop()


def _typed(server: Any, handle: Any, value: float) -> None:
    """What viser does with a number the page sends for ``handle``."""
    from viser import _messages

    message = _messages.GuiUpdateMessage(handle._impl.uuid, {"value": value})
    asyncio.run(server.gui._handle_gui_updates("page", message))


def test_a_number_field_takes_a_fraction_whole_and_shows_every_decimal_typed(viser_server) -> None:
    bare = viser_server.gui.add_number("bare", 1, step=1)
    _typed(viser_server, bare, 2.5)
    assert bare.value == 2  # what viser does to a field made with an int: the reason for number()
    field = number(viser_server.gui, "Node ID", 1, step=1)
    assert field.precision == DIGITS and field.value == 1.0
    _typed(viser_server, field, 2.5)
    assert field.value == 2.5
    angle = number(viser_server.gui, "Angle (deg)", 0.0, step=0.5)
    assert angle.precision == DIGITS  # viser's own: 1 (12.25 was sent as 12.2)
    _typed(viser_server, angle, 12.25)
    assert angle.value == 12.25


class Control:
    """What the inputs use of a viser control: a value, callbacks kept and called by hand."""

    def __init__(self, value: Any = None) -> None:
        self.value = value
        self.disabled = False
        self.callbacks: list[Any] = []

    def on_update(self, callback: Any) -> None:
        self.callbacks.append(callback)

    def typed(self, value: Any) -> None:
        self.value = value
        for callback in self.callbacks:
            callback(type("Event", (), {"target": self})())


class Gui:
    def __init__(self) -> None:
        self.controls: dict[str, Control] = {}

    def _add(self, label: str, value: Any) -> Control:
        self.controls[label] = Control(value)
        return self.controls[label]

    def add_number(self, label: str, initial_value: float, **_: Any) -> Control:
        return self._add(label, initial_value)

    def add_dropdown(self, label: str, options: list[str], **_: Any) -> Control:
        return self._add(label, options[0])

    def add_text(self, label: str, initial_value: str, **_: Any) -> Control:
        return self._add(label, initial_value)

    def add_checkbox(self, label: str, initial_value: bool, **_: Any) -> Control:
        return self._add(label, initial_value)


def _on_edit(handle: Control, apply: Any, *, context: Any = None) -> Any:
    """The page's on_edit for these hand-called controls: the value and its context as the value comes (here, at
    once: no pool runs callbacks late), an error raised to the test instead of shown as a toast."""
    handle.on_update(lambda event: apply(event.target.value, *(() if context is None else (context(),))))
    return lambda: None


def test_the_attribute_browser_refuses_a_fraction_for_an_integer_attribute_and_writes_nothing() -> None:
    network = MemoryNetwork()
    module = Node("m2", MemoryTransport(network))
    client = Node("studio", MemoryTransport(network))
    try:
        module.register(Attribute("gait.signal", 1, codec="uint8"))
        remote = client.lookup("m2", "gait.signal", timeout=5)
        gui = Gui()
        value = ValueInput(gui, remote)  # type: ignore[arg-type]
        field = gui.controls["gait.signal (uint8)"]
        assert value.kind == "int" and field.value == 1.0  # a float: a fraction typed comes as one
        field.value = 2.5
        with pytest.raises(ValueError, match=r"^gait\.signal must be a whole number, not 2\.5$"):
            value.write()
        assert remote.get() == 1  # nothing written (it was 2)
        field.value = 7.0  # a whole number typed after a fraction comes as a float
        assert value.write() == 7 and remote.get() == 7
        value.refresh()
        assert field.value == 7.0 and type(field.value) is float
    finally:
        client.close()
        module.close()


def test_the_event_fields_refuse_a_fraction_by_name_and_leave_the_gait_as_it_was() -> None:
    doc = GaitDocument(load(LIBRARY / "caterpillar.toml"))
    automaton = next(iter(doc.data()["automata"]))
    gui = Gui()
    edits: list[str] = []
    EventControls(
        gui, doc, selected=lambda: (automaton, 0, None), edited=lambda: edits.append("edited"), on_edit=_on_edit
    )
    before = doc.text()
    with pytest.raises(ValueError, match=r"^Emits signal must be a whole number, not 2\.5$"):
        gui.controls["Emits signal"].typed(2.5)
    gui.controls["Ends on"].value = "signal"
    with pytest.raises(ValueError, match=r"^Signal must be a whole number, not 3\.5$"):
        gui.controls["Signal"].typed(3.5)
    gui.controls["Signal"].value = 3.0
    gui.controls["Ends on"].value = "neighbour"
    with pytest.raises(ValueError, match=r"^Neighbour must be a whole number, not -1\.5$"):
        gui.controls["Neighbour (± IDs)"].typed(-1.5)
    assert doc.text() == before and not edits
    gui.controls["Emits signal"].typed(2.0)  # a whole number: taken, as an int
    assert doc.data()["automata"][automaton]["states"][0]["emit"] == 2 and edits == ["edited"]


def test_an_edit_by_index_names_the_layout_it_was_made_in_and_one_made_in_another_changes_nothing() -> None:
    """GaitDocument.layout moves whenever a state's index may have: an insert, a removal, another gait, undo, redo;
    an edit of a value does not move it."""
    doc = GaitDocument(load(LIBRARY / "caterpillar.toml"))
    automaton = next(iter(doc.data()["automata"]))
    seen = doc.layout
    doc.set_state(automaton, 2, "angle", 12.0, layout=seen)
    doc.set_emit(automaton, 2, 3, layout=seen)
    assert doc.layout == seen
    moves = [lambda: doc.add_state(automaton, 0), lambda: doc.remove_state(automaton, 0), doc.undo, doc.redo,
             lambda: doc.replace(load(LIBRARY / "caterpillar.toml"))]  # fmt: skip
    for move in moves:
        before, text = doc.layout, doc.text()
        move()
        assert doc.layout != before
        text = doc.text()
        stale_edits = ((doc.set_state, (automaton, 2, "angle", 30.0), {}),
                       (doc.update_state, (automaton, 2, {"duration": 0.5}), {}),
                       (doc.set_event, (automaton, 2, "at_goal"), {"tolerance": 1.0}),
                       (doc.set_emit, (automaton, 2, 4), {}),
                       (doc.add_state, (automaton, 2), {}),
                       (doc.remove_state, (automaton, 2), {}))  # fmt: skip
        for edit, args, fields in stale_edits:
            with pytest.raises(ValueError, match="make it again"):
                edit(*args, layout=before, **fields)
            assert doc.text() == text
