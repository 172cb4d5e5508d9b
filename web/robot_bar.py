"""The top of the side panel: E-STOP, its release, the status line, the robots on the network, and what the 3D view
shows — above every tab, so none of it is ever more than one click (or the Escape key) away.

The E-STOP reports what the modules confirmed (web/link.py), never what was merely sent; the line under it says at
once when the robot is lost. The robots of the network are listed (name, simulated or real, modules, real-time
factor, e-stop) by a thread of their own, and choosing one attaches the page to it.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any

from asm_module.feed import RobotStatus
from gaits.calls import DeployError

from .confirm import InlineConfirm, plain
from .page_script import ESTOP_KEY

if TYPE_CHECKING:
    from .page import Page

log = logging.getLogger("asm_studio.robots")
LIST_EVERY = 2.0
"""Seconds between two listings of the robots on the network."""


COMMISSIONING_STOPPED = " · **commissioning stopped by an e-stop** (Release e-stop goes on)"
"""Said while the robot's commissioning latched on an e-stop: boards without an ID cannot latch, so the modules'
e-stop reads clear on an unnumbered batch while wiggles and IDs are refused."""


def describe_robot(status: RobotStatus) -> str:
    """One line about a robot, as the list shows it."""
    rtf = "" if status.real_time_factor is None else f" · real-time factor {status.real_time_factor:.2f}"
    if status.estop is None:
        estop = ""
    else:
        estop = f" · **E-STOP latched on {len(status.estop)}**" if status.estop else " · e-stop clear"
    if status.commissioning_stopped:
        estop += COMMISSIONING_STOPPED
    return f"**{status.robot}**: {status.mode}, {status.modules} modules{rtf}{estop}"


class RobotBar:
    """See the module docstring; ``tick`` is called by the page's refresh (20 Hz)."""

    def __init__(self, page: Page) -> None:
        self.page = page
        gui = page.gui
        self.estop = gui.add_button("E-STOP", color="red", hint=f"stop every module of this robot: gaits stopped, "
                                    f"joints holding (key: {ESTOP_KEY}, from anywhere on the page)")  # fmt: skip
        self.estop.on_click(page.safe(lambda _: self.press_estop()))
        self.release = gui.add_button("Release e-stop", color="green", hint="let every module move again (asks first)")
        self.release.on_click(page.safe(lambda _: self.ask_release()))
        self.confirm = InlineConfirm(gui, page.safe)
        self.status = page.status = gui.add_markdown("Ready.")
        hint = "the robots on this Zenoh network; the page shows and commands this one"
        self.robot = gui.add_dropdown("Robot", [page.robot.robot], initial_value=page.robot.robot, hint=hint)
        self.robot.on_update(page.safe(self._chosen))
        self.robots_md = gui.add_markdown("")
        hint = "the edited gait in the preview simulation, or the robot itself"
        self.source = gui.add_button_group("View", ["Preview", "Live"], hint=hint)
        self.source.on_click(page.safe(lambda e: page.emit("show", e.target.value.lower())))
        self.source_md = gui.add_markdown("Showing: **Preview** (the edited gait, simulated here)")
        self.robots: list[RobotStatus] = []
        self._stop = threading.Event()
        self._lister = threading.Thread(target=self._list_loop, name="studio-robots", daemon=True)
        self._lister.start()

    # -- E-STOP ---------------------------------------------------------------------------------------------------

    def press_estop(self) -> None:
        """Stop every module of the robot shown, and say per module what latched."""
        report = self.page.robot.estop()
        self.page.notify("E-STOP", report.text(), error=True)

    def ask_release(self) -> None:
        modules = self.page.robot.modules()
        self.confirm.ask(f"Release the emergency stop of every module ({len(modules)})? Joints stay where they hold "
                         "and nothing starts until you start or deploy a gait.", "Yes, release",
                         lambda: self._release(modules))  # fmt: skip

    def _release(self, modules: list[str]) -> None:
        commissioning = self.page.robot.release_commissioning()  # the modules' own latches next
        also = " and the robot's commissioning (wiggles, node IDs)" if commissioning else ""
        try:
            released = self.page.robot.release(modules)
        except DeployError as exc:  # some module not released (gone, silent): said, with what was released
            raise ValueError(f"{exc}{'; released' + also if also else ''}") from None
        self.page.notify("E-STOP released", f"released on {len(released)} of {len(modules)} modules{also}")

    # -- the robots of the network --------------------------------------------------------------------------------

    def _list_loop(self) -> None:
        while not self._stop.wait(0.0 if not self.robots else LIST_EVERY):
            try:
                self.robots = self.page.robots()
            except Exception as exc:  # the session closing
                log.debug("listing the robots failed: %s", exc)
                self.robots = self.robots or []
                self._stop.wait(LIST_EVERY)
                continue
            names = [r.robot for r in self.robots]
            shown = self.page.robot.robot
            if shown not in names:
                names.append(shown)
            with self.page.programmatic():
                if list(self.robot.options) != names:
                    self.robot.options = names
                if self.robot.value != shown:
                    self.robot.value = shown
            self.robots_md.content = "  \n".join(describe_robot(r) for r in self.robots) or "no robot answers"

    def _chosen(self, event: Any) -> None:
        if self.page.syncing or event.target.value == self.page.robot.robot:
            return
        self.page.emit("attach", event.target.value)

    # -- each refresh ---------------------------------------------------------------------------------------------

    def tick(self) -> None:
        link = self.page.robot
        lost = link.lost()
        status = link.status
        latched = status.estop if status is not None and lost is None else None
        if lost is not None:
            label = "E-STOP — robot LOST"
        elif latched:
            label = f"E-STOP — LATCHED on {len(latched)} modules"
        elif status is not None and status.commissioning_stopped:
            label = "E-STOP — LATCHED (commissioning)"
        else:
            label = "E-STOP"
        if self.estop.label != label:
            self.estop.label = label
        if self.page.view.source == "live":
            kind = "simulated" if self.page.simulated else "real: no poses, angles only"
            shown = f"Showing: **Live** (robot {link.robot}, {kind})"
        elif self.page.view.source == "replay":
            replay = self.page.view.replay
            shown = f"Showing: **Replay** of {plain(replay.recording.name)} (Replay tab; Live returns)"
            if replay.model is None:  # the 3D view is empty: why, where one looks for what it shows
                shown += f"  \n⚠ Nothing drawn: {plain(replay.error or 'the recording has no robot model')}"
        else:
            shown = "Showing: **Preview** (the edited gait, simulated here)"
        content = shown + self._live_line(lost)
        if self.source_md.content != content:
            self.source_md.content = content
        self.confirm.expire()

    def _live_line(self, lost: str | None) -> str:
        if lost is not None:
            return f"  \n⚠ **ROBOT LOST**: {lost}. Deploy, start and drive refuse until it is back."
        link = self.page.robot
        status = link.status
        if status is None:
            return f"  \nLive: no status from robot {link.robot} yet"
        moved, speed = link.feed.speed()
        rtf = "" if status.real_time_factor is None else f" · real-time factor {status.real_time_factor:.2f}"
        latched = f" · **E-STOP latched** on {len(status.estop)} modules" if status.estop else ""
        if status.commissioning_stopped:
            latched += COMMISSIONING_STOPPED
        behind = " · ⚠ the simulation cannot keep up with real time" if status.behind else ""
        unread = (f" · ⚠ tables not read yet (publications pending): {', '.join(status.unread_tables)}"
                  if status.unread_tables else "")  # fmt: skip
        return (f"  \nLive: {status.mode} robot, {status.modules} modules{rtf} · moved {moved:.3f} m in the last "
                f"10 s ({speed:.3f} m/s){latched}{behind}{unread}")  # fmt: skip

    def close(self) -> None:
        self._stop.set()
        self._lister.join(5)
