"""The Modules tab's guided numbering (web/numbering_panel.py) without a browser: its controls stand in for viser's,
the robot's commissioning service is a scripted one. The page is shared by every tab, so a Find or a refused field
from another tab while the guide waits for a chain position must not hide the question (a user review found it
gone)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from web.numbering_panel import NumberingPanel

from ..helpers import wait_until

pytestmark = pytest.mark.timeout(60)
SERIALS = ["bb" * 12, "aa" * 12]


class Control:
    """What the panel uses of a viser control: its content or value, and its click callback."""

    def __init__(self, value: Any = None) -> None:
        self.content = value
        self.value = value
        self.options: list[str] = []
        self.clicked: Callable[[Any], None] = lambda _: None
        self.updated: Callable[[Any], None] = lambda _: None

    def on_click(self, callback: Callable[[Any], None]) -> None:
        self.clicked = callback

    def on_update(self, callback: Callable[[Any], None]) -> None:
        self.updated = callback

    def commit(self, value: Any) -> None:
        """A value typed and committed in the page (Enter, Tab)."""
        self.value = value
        self.updated(None)

    def click(self) -> None:
        self.clicked(None)


class Gui:
    def __init__(self) -> None:
        self.controls: dict[str, Control] = {}

    def _add(self, label: str, value: Any = None) -> Control:
        self.controls[label] = Control(value)
        return self.controls[label]

    def add_markdown(self, content: str) -> Control:
        return self._add(f"markdown {len(self.controls)}", content)

    def add_button(self, label: str) -> Control:
        return self._add(label)

    def add_dropdown(self, label: str, options: list[str]) -> Control:
        return self._add(label, options[0])

    def add_number(self, label: str, value: float, step: float) -> Control:
        return self._add(label, value)


class Robot:
    """A robot whose bus holds two fresh boards and Python modules m3..m8."""

    robot = "robot"
    session = None

    def __init__(self) -> None:
        self.ids = dict.fromkeys(SERIALS, 0)
        self.forgotten: list[str] = []

    def forget(self, names: list[str]) -> None:
        self.forgotten += names

    def alive_modules(self) -> list[str]:
        return [f"m{k}" for k in range(3, 9)] + [f"m{i}" for i in self.ids.values() if i]

    def commission(self, request: dict[str, Any]) -> dict[str, Any]:
        if request["op"] == "list":
            return {"modules": [{"serial": s, "id": i} for s, i in sorted(self.ids.items())], "conflicts": {}}
        if request["op"] == "wiggle":
            return {"serial": request["serial"], "id": 0, "temporary": 199, "moved": 10.0}
        self.ids[request["serial"]] = request["id"]
        return {"serial": request["serial"], "id": request["id"]}


class Page:
    def __init__(self) -> None:
        self.gui = Gui()
        self.robot = Robot()
        self.emitted: list[tuple[str, tuple[Any, ...]]] = []

    def emit(self, event: str, *args: Any) -> None:
        self.emitted.append((event, args))

    @contextlib.contextmanager
    def programmatic(self) -> Iterator[None]:
        yield


class Panel(NumberingPanel):
    def _ask(self, request: dict[str, Any]) -> dict[str, Any]:
        return self.page.robot.commission(request)  # type: ignore[attr-defined]


@pytest.fixture
def panel() -> Iterator[Panel]:
    panel = Panel(Page(), numbered=lambda: None)  # type: ignore[arg-type]
    try:
        yield panel
    finally:
        panel.close()


def _line(panel: Panel) -> str:
    return str(panel.line.content)


def _found(panel: Panel) -> None:
    assert wait_until(lambda: _line(panel).startswith("Found "), timeout=10), _line(panel)


def test_the_pending_question_stays_under_another_tabs_find_and_a_refused_field(panel) -> None:
    controls = panel.page.gui.controls
    controls["Number along the chain"].click()
    assert wait_until(lambda: "Which chain position moved?" in _line(panel), timeout=10)
    first = "aa" * 12  # the serials' order: the list is sorted by the robot
    assert f"`{first}` was wiggled (2 left)" in _line(panel)
    controls["Find modules"].click()  # another tab
    _found(panel)
    assert _line(panel).startswith("Found 2 modules, 2 without a node ID.") and f"`{first}` was wiggled" in _line(panel)
    panel.position.value = 9  # the robot has 8 modules
    controls["Confirm position"].click()
    assert _line(panel).startswith("⚠ a chain position is a whole number 1..8") and "Which chain position" in _line(
        panel
    )
    panel.position.value = 1
    controls["Confirm position"].click()
    assert wait_until(lambda: f"`{'bb' * 12}` was wiggled (1 left)" in _line(panel), timeout=10)
    assert first not in _line(panel), "the answered question is gone"
    panel.position.value = 2
    controls["Confirm position"].click()
    assert wait_until(lambda: _line(panel).startswith("Every module has a node ID: m1, m2"), timeout=10)
    controls["Find modules"].click()
    _found(panel)
    assert _line(panel) == "Found 2 modules, 0 without a node ID.", "no question once every module is numbered"
    assert panel.page.robot.ids == {first: 1, "bb" * 12: 2}  # type: ignore[attr-defined]


def test_a_module_numbered_by_hand_while_asked_about_ends_the_question(panel) -> None:
    controls = panel.page.gui.controls
    controls["Number along the chain"].click()
    assert wait_until(lambda: "Which chain position moved?" in _line(panel), timeout=10)
    panel.node_id.value = 1
    controls["Assign ID"].click()  # the picked module is the one asked about
    assert wait_until(lambda: _line(panel) == f"`{'aa' * 12}` is now m1.", timeout=10)
    controls["Confirm position"].click()
    assert wait_until(lambda: _line(panel).startswith("⚠ start with Number along the chain"), timeout=10)


def test_an_answer_to_an_earlier_question_never_numbers_the_next_module(panel) -> None:
    """A review: two tabs answered the same question (6, then 3) and the second answer numbered the next module,
    which nobody had looked at; a Confirm clicked while the next module was being found did the same."""
    controls = panel.page.gui.controls
    controls["Number along the chain"].click()
    assert wait_until(lambda: "Which chain position moved?" in _line(panel), timeout=10)
    first, second = "aa" * 12, "bb" * 12
    panel.position.value = 6
    controls["Confirm position"].click()  # tab A answers the question about the first module
    panel.position.value = 3
    controls["Confirm position"].click()  # tab B answers the same question, queued behind A's
    assert wait_until(lambda: "an earlier question" in _line(panel), timeout=10), _line(panel)
    assert panel.page.robot.ids == {first: 6, second: 0}, "the second module is not numbered by tab B's answer"  # type: ignore[attr-defined]
    assert f"`{second}` is the module asked about now" in _line(panel)
    panel.position.value = 1
    controls["Confirm position"].click()
    assert wait_until(lambda: _line(panel).startswith("Every module has a node ID"), timeout=10), _line(panel)
    assert panel.page.robot.ids == {first: 6, second: 1}  # type: ignore[attr-defined]
    # the ID each board was lent to be wiggled left the roster and the plots, not shown as a lost module
    assert panel.page.robot.forgotten == ["m199", "m199"]  # type: ignore[attr-defined]
    assert panel.page.emitted == [("modules_removed", (["m199"],))] * 2  # type: ignore[attr-defined]


def test_a_fraction_typed_into_node_id_or_chain_position_is_refused_when_committed(panel) -> None:
    """Issue 28's fourth review: 2.5 stayed in Node ID without a word until Assign ID was clicked."""
    controls = panel.page.gui.controls
    controls["Node ID"].commit(2.5)
    assert "a node ID is a whole number 1..253 (0 erases), not 2.5" in _line(panel)
    controls["Chain position that moved"].commit(7.5)
    assert "a chain position is a whole number 1.." in _line(panel) and "not 7.5" in _line(panel)
