"""The Drive tab: switch the running program live — forward, turn left/right, reverse, stop — with buttons and the
arrow keys, on the preview and on the deployed robot alike (whichever the View shows).

The preview's modules get the same ``gait.switch`` a deployed robot gets (through the preview loop, which owns the
simulation); a deployed robot gets one group message and is read back (gaits/drive.py), so the page never says
"left" before the modules did. Driving a gait without left/right gaits says what to add to the file.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from viser._messages import HotkeyKey

from asm_module.names import module_name
from gaits.drive import STOP
from gaits.model import FORWARD, Gait

from .inputs import number, whole

if TYPE_CHECKING:
    from .page import Page

RELEASE_PENDING = "Robot: **stopped**, E-STOP latched"
"""How the robot line begins while an e-stop holds it (sync says when it is released)."""

COMMANDS: dict[str, tuple[str, int]] = {
    "▲ Forward": (FORWARD, 1),
    "◀ Left": ("left", 1),
    "▶ Right": ("right", 1),
    "▼ Reverse": (FORWARD, -1),
    "■ Stop": (STOP, 1),
}
"""Button label → (program gait, direction)."""
KEYS: dict[HotkeyKey, str] = {"arrowup": "▲ Forward", "arrowleft": "◀ Left", "arrowright": "▶ Right",
                        "arrowdown": "▼ Reverse", "S": "■ Stop"}  # fmt: skip


class DrivePanel:
    """The Drive tab's controls; ``command`` is what the buttons and the keys call."""

    def __init__(self, page: Page) -> None:
        self.page = page
        gui = page.gui
        gui.add_markdown("Drive the running program: the modules switch gait together at their next cycle "
                         "boundary, without stopping. Keys: ↑ forward, ← left, → right, ↓ reverse, S stop. "
                         "It drives what the View shows: the Preview, or the deployed robot (Live).")  # fmt: skip
        self.buttons = gui.add_button_group("Drive", list(COMMANDS))
        self.buttons.on_click(page.safe(lambda e: self.command(e.target.value)))
        self.gaits = gui.add_dropdown("Program gait", [FORWARD])
        go = gui.add_button_group("Run gait", ["Run forwards", "Run backwards"])
        go.on_click(page.safe(lambda e: self.run(self.gaits.value, -1 if "back" in e.target.value else 1)))
        self.signal = number(gui, "Signal", initial_value=1, step=1,
                                     hint="broadcast 1..255, for states that wait on it (until = signal)")  # fmt: skip
        send = gui.add_button("Send signal")
        send.on_click(page.safe(lambda _: self.send_signal(whole(self.signal.value, "Signal"))))
        self.state = gui.add_markdown("")
        self.deployed: Gait | None = None
        """The gait last deployed to the robot (the one its modules' programs come from)."""
        page.on("deployed", lambda gait: setattr(self, "deployed", gait))

    def bind_keys(self, add: Callable[[str, HotkeyKey, Any], None]) -> None:
        for key, label in KEYS.items():
            add(f"Drive: {label[2:].lower()}", key, lambda label=label: self.command(label))

    def sync(self, gait: Gait) -> None:
        """The edited gait changed: offer its program's gaits. A robot line that the modules' state contradicts (a
        latched e-stop after "confirmed by 12 of 12") says what the modules are doing now."""
        names = gait.program_gaits()
        if list(self.gaits.options) != names:
            self.gaits.options = names
        status = self.page.robot.status
        latched = status.estop if status is not None else None
        if latched and self.state.content.startswith("Robot:") and "E-STOP" not in self.state.content:
            self.state.content = (f"{RELEASE_PENDING} on {len(latched)} modules — release it and "
                                  "start a gait before driving")  # fmt: skip
        elif status is not None and not latched and self.state.content.startswith(RELEASE_PENDING):
            self.state.content = "Robot: **stopped**, e-stop released — start a gait (Gait tab) before driving"

    def command(self, label: str) -> None:
        gait, direction = COMMANDS[label]
        self.run(gait, direction)

    def send_signal(self, number: int) -> None:
        """Broadcast a signal to what the View shows: the preview's modules, or every module on the robot (one group
        SET of gait.signal, as a module's emitting state sends it)."""
        if not 1 <= number <= 255:
            raise ValueError(f"a signal is numbered 1..255, not {number}")
        if self.page.view.source == "live":
            self.page.robot.signal(number)
            self.state.content = f"Robot: signal **{number}** sent to every module"
        else:
            self.page.loop.request("signal", number)
            self.state.content = f"Preview: signal **{number}** sent to every module"

    def run(self, name: str, direction: int = 1) -> None:
        page = self.page
        live = page.view.source == "live"
        gait = (self.deployed or page.doc.gait()) if live else page.loop.gait
        if name not in (STOP, *gait.program_gaits()):
            raise ValueError(f"{gait.name} has no {name!r} gait: add [gaits.{name}] to the file (see "
                             "steerable_caterpillar in the library)")  # fmt: skip
        what = "stop" if name == STOP else f"{name}{' (backwards)' if direction < 0 else ''}"
        if not live:
            page.loop.request("drive", (name, direction))
            self.state.content = f"Preview: **{what}** at the next cycle boundary"
            return
        names = [module_name(a.id) for a in gait.modules]
        self.state.content = f"Robot: switching to **{what}** …"
        try:
            confirmed = page.robot.drive(gait, name, names, direction)
        except Exception as exc:
            self.state.content = f"Robot: **{what}** refused: {exc}"
            raise
        self.state.content = f"Robot: **{what}**, confirmed by {len(confirmed)} of {len(names)} modules"
        page.notify("Drive", f"{what}: {len(confirmed)} of {len(names)} modules confirmed")
