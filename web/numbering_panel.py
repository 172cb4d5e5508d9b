"""The Modules tab's numbering: a freshly flashed batch of modules — no node IDs, told apart only by their serials —
found, wiggled and numbered along the chain from the page, through the robot's commissioning service
(server/commission_service.py, asked with asm_module.commission_link).

- **Find modules** lists every module of the bus by serial with its ID ("none" for a new one), and any ID two
  modules share (reported, never silently kept).
- **Wiggle** moves the picked module's joint a few degrees and back, so a person sees which joint it sits on.
- **Assign ID** gives the picked module an ID (0 erases it); the robot refuses an ID another module holds.
- **Number along the chain** is the guided way: it wiggles the next module without an ID and asks which chain
  position moved (a guess filled in: the lowest free one); **Confirm position** gives it that ID and wiggles the
  next, until every module has one. The roster (Read modules) then shows them as m1..mN with their firmware.

The callbacks only queue work: one thread (``studio-numbering``) asks the robot, so a long scan never holds viser's
thread pool; it writes the list and the line under the buttons when it is done.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from asm_module.commission_link import commission

from .inputs import number

if TYPE_CHECKING:
    from .page import Page

NONE = "-"
ALIVE_WAIT = 60.0
"""Seconds numbered modules have to appear as m<ID> before the roster is read anyway."""


def modules_markdown(modules: list[dict[str, Any]], clash: dict[str, list[str]]) -> str:
    """The modules found as a markdown table, serial and ID ("none" for a module without one), and the shared IDs."""
    if not modules:
        return "No module answers commissioning (a robot of Python modules only, or none powered)."
    rows = ["| serial | node ID |", "|---|---|"]
    rows += [f"| `{m['serial']}` | {m['id'] or 'none'} |" for m in modules]
    lines = [f"⚠ node ID {node_id} is held by {len(serials)} modules: {', '.join(serials)}"
             for node_id, serials in clash.items()]  # fmt: skip
    return "\n".join(rows) + ("\n\n" + "  \n".join(lines) if lines else "")


class NumberingPanel:
    """The numbering part of the Modules tab of ``page``; ``numbered()`` is called when modules got IDs (the
    roster is read again). ``close`` stops its thread."""

    def __init__(self, page: Page, numbered: Callable[[], None]) -> None:
        self.page = page
        self.numbered = numbered
        gui = page.gui
        gui.add_markdown("**Number the modules**: a new batch has no node IDs. Find them by serial, wiggle each to "
                         "see which joint moves, and number them along the chain (stored in each module).")  # fmt: skip
        self.find_button = gui.add_button("Find modules")
        self.list_md = gui.add_markdown("Not searched yet.")
        self.serial = gui.add_dropdown("Module (serial)", [NONE])
        self.wiggle_button = gui.add_button("Wiggle")
        # no min/max: the browser would clamp a typed -1 to 0 (erase!) or 300 to 253; _id_value refuses instead
        self.node_id = number(gui, "Node ID", 1, step=1)
        self.assign_button = gui.add_button("Assign ID")
        self.guide_button = gui.add_button("Number along the chain")
        self.position = number(gui, "Chain position that moved", 1, step=1)
        self.confirm_button = gui.add_button("Confirm position")
        self.line = gui.add_markdown("")
        self._modules: list[dict[str, Any]] = []
        self._guided: str | None = None
        """The serial the guided numbering wiggled last and asks the position of (None: not numbering)."""
        self._question = ""
        """What the guided numbering asks while ``_guided`` is set: kept under whatever the line says next."""
        self._jobs: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        self.find_button.on_click(self._said(lambda: self._jobs.put(("find", None))))
        self.wiggle_button.on_click(self._said(lambda: self._jobs.put(("wiggle", self._picked()))))
        self.assign_button.on_click(self._said(lambda: self._jobs.put(("assign", self._assignment()))))
        self.guide_button.on_click(self._said(lambda: self._jobs.put(("guide", None))))
        # the answer is to the question shown when it was clicked: the module then asked about goes with it
        self.confirm_button.on_click(self._said(lambda: self._jobs.put(("confirm", (self._position_value(),
                                                                                    self._guided)))))  # fmt: skip
        # a typed value is checked when it is committed, not only when its button is clicked (issue 28's fourth
        # review: 2.5 stayed in the field without a word until Assign ID)
        self.node_id.on_update(self._said(lambda: self._id_value()))
        self.position.on_update(self._said(lambda: self._position_value()))
        self._thread = threading.Thread(target=self._run, name="studio-numbering", daemon=True)
        self._thread.start()

    # -- the callbacks: they only read the fields and queue work --------------------------------------------------

    def _said(self, queue_it: Callable[[], object]) -> Callable[[Any], None]:
        """A button's callback: a refused field is said on the panel's own line, which the next step overwrites
        (said on the page's status line, an error stayed there after every later success)."""

        def clicked(_: Any) -> None:
            try:
                queue_it()
            except ValueError as exc:
                self._say(f"⚠ {exc}")

        return clicked

    def _say(self, text: str) -> None:
        """``text`` on the panel's line, with the guided numbering's pending question under it: the page is shared
        by every tab, and another tab's Find or Wiggle must not hide what this one was asked."""
        self.line.content = text + (f"  \n{self._question}" if self._guided is not None else "")

    def _picked(self) -> str:
        serial = str(self.serial.value)
        if serial == NONE:
            raise ValueError("find the modules first (Find modules lists them)")
        return serial

    def _assignment(self) -> tuple[str, int]:
        """(the picked serial, the typed ID): the ID checked first, so a refused one is said even before a module
        is found (2.5 is refused, never taken as 2)."""
        node_id = self._id_value()
        return self._picked(), node_id

    def _id_value(self) -> int:
        value = float(self.node_id.value)
        if not value.is_integer() or not 0 <= value <= 253:
            raise ValueError(f"a node ID is a whole number 1..253 (0 erases), not {value:g}")
        return int(value)

    def _position_value(self) -> int:
        value = float(self.position.value)
        chain = max(self._chain()[0], 1)
        if not value.is_integer() or not 1 <= value <= chain:
            raise ValueError(f"a chain position is a whole number 1..{chain} (the robot's modules), not {value:g}")
        return int(value)

    # -- the worker ---------------------------------------------------------------------------------------------

    def _ask(self, request: dict[str, Any]) -> dict[str, Any]:
        robot = self.page.robot
        return commission(robot.session, robot.robot, request)

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            kind, argument = job
            try:
                if kind == "find":
                    self._find()
                elif kind == "wiggle":
                    self._wiggle(argument)
                elif kind == "assign":
                    self._assign(*argument)
                elif kind == "guide":
                    self._find()
                    self._next()
                elif kind == "confirm":
                    self._confirm(*argument)
            except Exception as exc:  # a refusal, a silent module: said under the buttons, the worker goes on
                self._say(f"⚠ {exc}")

    def _find(self) -> None:
        self._say("Finding modules …")
        answer = self._ask({"op": "list"})
        self._modules = list(answer["modules"])
        self.list_md.content = modules_markdown(self._modules, answer["conflicts"])
        serials = [m["serial"] for m in self._modules]
        with self.page.programmatic():
            chosen = self.serial.value
            self.serial.options = serials or [NONE]
            self.serial.value = chosen if chosen in serials else (serials[0] if serials else NONE)
        unnumbered = sum(1 for m in self._modules if not m["id"])
        self._say(f"Found {len(serials)} modules, {unnumbered} without a node ID.")

    def _wiggle(self, serial: str) -> None:
        self._say(f"Wiggling `{serial}` …")
        answer = self._ask({"op": "wiggle", "serial": serial})
        if answer.get("temporary"):  # the ID it was lent to move is free again: not a module lost
            self._gone(f"m{answer['temporary']}")
        self._say(f"`{serial}` wiggled: its joint moved {answer['moved']:g}°.")

    def _renumbered(self, serial: str, node_id: int) -> None:
        """Ask the service to give ``serial`` ``node_id``; the name it had before leaves the roster (it shows
        LOST otherwise: that module is now another name, not lost)."""
        before = next((int(m["id"]) for m in self._modules if m["serial"] == serial), 0)
        self._ask({"op": "assign", "serial": serial, "id": node_id})
        if before and before != node_id:
            self._gone(f"m{before}")

    def _gone(self, name: str) -> None:
        """``name`` left on purpose (the board now answers under another ID, or none): off the roster, the plots."""
        self.page.robot.forget([name])
        self.page.emit("modules_removed", [name])

    def _assign(self, serial: str, node_id: int) -> None:
        self._renumbered(serial, node_id)
        if serial == self._guided:  # numbered by hand while the guide asked about it: the question is answered
            self._guided = None
        self._find()
        self._say(f"`{serial}` is now " + (f"m{node_id}" if node_id else "without a node ID") + ".")
        if node_id:
            self._after_numbering([f"m{node_id}"])

    def _chain(self) -> tuple[int, set[int]]:
        """(how many modules the robot has, the node IDs they hold): the boards the list found, numbered or not,
        and the modules alive on the robot that the list does not hold (its Python modules)."""
        found = {int(m["id"]) for m in self._modules}
        alive = {int(n[1:]) for n in self.page.robot.alive_modules()} - found
        return len(self._modules) + len(alive), (found | alive) - {0}

    def _guess(self) -> int:
        """The lowest ID no module has (listed, or alive on the robot): the next chain position, most often."""
        taken = {m["id"] for m in self._modules} | {int(n[1:]) for n in self.page.robot.alive_modules()}
        return next(i for i in range(1, 254) if i not in taken)

    def _next(self) -> None:
        """Wiggle the next module without an ID and ask where it sits; or say that every module has one."""
        todo = [m["serial"] for m in self._modules if not m["id"]]
        if not todo:
            self._guided = None
            names = sorted((f"m{m['id']}" for m in self._modules), key=lambda n: int(n[1:]))
            count, held = self._chain()
            missing = [f"m{k}" for k in range(1, count + 1) if k not in held]
            gap = (f" — but no module is {', '.join(missing)}: a gait deploys to m1..m{count} "
                   "(Assign ID renumbers one)") if missing else ""  # fmt: skip
            self.line.content = f"Every module has a node ID: {', '.join(names) or 'none found'}{gap}."
            self._after_numbering(names)
            return
        serial = todo[0]
        self._guided = None  # a question is asked once its module has moved
        with self.page.programmatic():
            self.serial.value = serial
            self.position.value = float(self._guess())  # a float: see inputs.number
        self._wiggle(serial)
        self._guided = serial
        self._question = (f"Which chain position moved? `{serial}` was wiggled ({len(todo)} left): set **Chain "
                          "position that moved** and **Confirm position** (or **Wiggle** again).")  # fmt: skip
        self.line.content = self._question

    def _confirm(self, position: int, asked: str | None) -> None:
        """``position`` for the module ``asked`` about when Confirm was clicked; refused when the question has
        changed since (a click while the next module was being found, or another tab's answer first): the ID
        would have gone to a module nobody looked at."""
        serial = self._guided
        if serial is None:
            raise ValueError("start with Number along the chain: it wiggles a module and asks where it sits")
        if asked != serial:
            raise ValueError(f"not numbered: that answer was to an earlier question; `{serial}` is the module asked "
                             "about now (Wiggle it again to see it)")  # fmt: skip
        count = max(self._chain()[0], 1)
        if not 1 <= position <= count:  # checked again here: the robot's modules are known once the list is
            raise ValueError(f"a chain position is a whole number 1..{count} (the robot's modules), not {position}")
        self._renumbered(serial, position)
        self._guided = None  # answered
        self._find()
        self._next()

    def _after_numbering(self, names: list[str]) -> None:
        """Wait (a while) until ``names`` are alive on the robot, then have the roster read again."""
        deadline = time.monotonic() + ALIVE_WAIT
        while not set(names) <= set(self.page.robot.alive_modules()) and time.monotonic() < deadline:
            time.sleep(0.2)
        self.numbered()

    def close(self) -> None:
        self._jobs.put(None)
        self._thread.join(timeout=10)
